"""A real-arm-like case through ``dualid fit`` with the default config: the Franka Panda of example-robot-data.

The truth is the public URDF's inertials with joint friction, a near-zero armature, 2 % torque noise and 16-bit
encoders (v and a differentiated from them); the URDF the user gives is a CAD-like prior, every link's mass,
centre of mass and inertia 0.7–1.3× the truth's (``dualid.bench.urdf_arm``). On such data the constrained fits
put links at tens to thousands of kg (10 s runs, seed 0: 53.7 kg and 1,903 kg where the prior says 3.5 and 0.7 kg)
and armatures at their bound; the model files must carry physically sensible values nonetheless. Specifications: exit 0 without a traceback; a URDF and an MJCF per
method, both loadable (Pinocchio, MuJoCo) and carrying the plausible parameters; the total moving mass within
[0.5, 2]× the prior's and every link mass the data do not determine within [0.3, 3]× its prior; the held-out τ
RMSE of the written model at most 1.02× the raw fit's; every parameter the data do not determine named on the
console and in parameters.yaml.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

pytest.importorskip("mujoco")

from dualid.bench.urdf_arm import arm_runs, arm_urdf, example_robot_urdf, log_arrays, prior_urdf, urdf_arm  # noqa: E402
from dualid.cli import app  # noqa: E402

SECONDS = 3.0  # per run: two training runs and one held-out run


@pytest.fixture(scope="module")
def panda_fit(tmp_path_factory):
    try:
        source = example_robot_urdf()
    except FileNotFoundError:
        pytest.skip("example-robot-data is not installed (pip install dualid[test])")
    tmp = tmp_path_factory.mktemp("panda")
    rng = np.random.default_rng(0)
    truth = arm_urdf(source)
    prior = prior_urdf(truth, rng)
    (tmp / "panda.urdf").write_text(prior)
    arm = urdf_arm(truth, prior, rng)
    logs = []
    for k, run in enumerate(arm_runs(arm, truth, rng, 3, SECONDS)):
        np.savez(tmp / f"run{k}.npz", **log_arrays(run))
        logs.append(tmp / f"run{k}.npz")
    out = tmp / "out"
    result = CliRunner().invoke(app, ["fit", "--model", str(tmp / "panda.urdf"), "--data", str(logs[0]),
                                      "--data", str(logs[1]), "--test", str(logs[2]), "--out", str(out)])
    return result, out, tmp / "panda.urdf", logs


def test_no_absurd_link_is_written_without_the_plausible_step(panda_fit, tmp_path):
    """prior.plausible: false: the raw dm fit puts a link at thousands of kg (the pathology above); its model files are
    not written, and the console's last line, the warnings, report.md and parameters.yaml name the link and its mass."""
    *_, prior_file, logs = panda_fit
    config = tmp_path / "fit.yaml"
    config.write_text(yaml.safe_dump({"model": {"urdf": str(prior_file)}, "train": [str(p) for p in logs[:2]],
                                      "test": [str(logs[2])], "methods": ["dm"], "prior": {"plausible": False}}))
    result = CliRunner().invoke(app, ["fit", "--config", str(config), "--out", str(tmp_path / "out")])
    assert result.exit_code == 1 and result.exception is not None and "Traceback" not in result.output
    last = result.output.rstrip().splitlines()[-1]
    assert "not written: dm.urdf and dm.xml (the raw fit θ̂ puts link 'panda_link" in last, last
    assert "keep prior.plausible on (the default)" in last
    assert not (tmp_path / "out" / "dm.urdf").exists() and not (tmp_path / "out" / "dm.xml").exists()
    record = yaml.safe_load((tmp_path / "out" / "parameters.yaml").read_text())
    assert record["methods"]["dm"]["urdf"].startswith("not written: the raw fit θ̂ puts link 'panda_link")
    assert any(w.startswith("dm: model files not written") for w in record["warnings"])
    assert "dm.xml not written: the raw fit θ̂ puts link" in (tmp_path / "out" / "report.md").read_text()


def test_no_absurd_link_is_written_when_the_exact_plausible_choice_fails(panda_fit, tmp_path):
    """prior.plausible.level: 0 (θ̂'s training predictions exactly): on noisy data that slice holds no θ near the
    prior; whether the step fails or ends far from the prior, no file with an absurd link is written."""
    *_, prior_file, logs = panda_fit
    config = tmp_path / "fit.yaml"
    config.write_text(yaml.safe_dump({"model": {"urdf": str(prior_file)}, "train": [str(p) for p in logs[:2]],
                                      "methods": ["dm"], "prior": {"plausible": {"level": 0}}}))
    result = CliRunner().invoke(app, ["fit", "--config", str(config), "--out", str(tmp_path / "out")])
    assert result.exit_code == 1 and "Traceback" not in result.output
    last = result.output.rstrip().splitlines()[-1]
    assert "not written: dm.urdf and dm.xml (" in last and "above 2 × the prior's whole moving mass" in last


def test_the_default_fit_finishes_and_writes_every_model_file(panda_fit):
    result, out, *_ = panda_fit
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output and result.exception is None
    record = yaml.safe_load((out / "parameters.yaml").read_text())
    methods = record["methods"]
    assert set(methods) == {"ols", "dm"}
    for m, entry in methods.items():
        assert entry["urdf"] == f"{m}.urdf" and entry["mjcf"] == f"{m}.xml"
        assert entry["model_files_theta"].startswith("θ_plausible")
        assert f"{m}: the model files carry the parameters closest to the prior" in result.output
        named = entry["plausible"]["not_determined_by_data"]
        assert named and all(n in result.output for n in named)  # every one named on the console
    assert result.output.rstrip().splitlines()[-1].startswith(
        "wrote parameters.yaml, parameters.json, ols.urdf, ols.xml, dm.urdf, dm.xml, identifiability.txt")


def test_the_written_masses_make_physical_sense(panda_fit):
    import mujoco

    from dualid.model.rigid_body import RigidBodyModel

    result, out, prior_file, _ = panda_fit
    prior = RigidBodyModel.from_urdf(prior_file).nominal[::10]
    record = yaml.safe_load((out / "parameters.yaml").read_text())
    for m, entry in record["methods"].items():
        p = entry["plausible"]
        values = {e["name"]: e["value"] for e in p["parameters"]}
        by = {e["name"]: e["determined_by"] for e in p["parameters"]}
        masses = np.array([v for n, v in values.items() if n.endswith(".m")])
        assert 0.5 <= masses.sum() / prior.sum() <= 2.0, (m, masses, prior)
        for k, name in enumerate(n for n in values if n.endswith(".m")):
            if by[name] == "prior":
                assert 0.3 <= masses[k] / prior[k] <= 3.0, (m, name, masses[k], prior[k])
        # the files carry them: Pinocchio's URDF reader and MuJoCo's MJCF compiler agree
        np.testing.assert_allclose(RigidBodyModel.from_urdf(out / f"{m}.urdf").nominal[::10], masses, rtol=1e-6)
        spec = mujoco.MjModel.from_xml_path(str(out / f"{m}.xml"))
        assert spec.body_mass.sum() >= masses.sum() - 1e-6  # the fixed base link is in the MJCF too
        raw = np.array([e["value"] for e in entry["parameters"] if e["name"].endswith(".m")])
        assert raw.max() > 3 * prior.max()  # the pathology the step repairs: an absurd raw link mass


def test_the_written_model_predicts_held_out_torque_as_well_as_the_raw_fit(panda_fit):
    _, out, *_ = panda_fit
    record = yaml.safe_load((out / "parameters.yaml").read_text())
    for m, entry in record["methods"].items():
        raw = np.mean(list(entry["validation"]["mean"]["tau_rmse"].values()))
        written = np.mean(entry["plausible"]["held_out_tau_rmse"])
        assert written <= 1.02 * raw, (m, written, raw)


def test_a_urdf_without_inertials_gets_a_regularised_prior(panda_fit, tmp_path):
    """No <inertial> anywhere: every body's prior is the same ball fitted to the torques (a PlausibleWarning says its
    mass and radius); the fit exits 0 and writes model files whose arm weighs what the true one does (±50 %)."""
    import xml.etree.ElementTree as ET

    import pinocchio as pin

    from dualid.model.rigid_body import RigidBodyModel

    *_, prior_file, logs = panda_fit
    root = ET.fromstring(prior_file.read_text())
    for link in root.findall("link"):
        for inertial in link.findall("inertial"):
            link.remove(inertial)
    bare = tmp_path / "bare.urdf"
    bare.write_text(ET.tostring(root, encoding="unicode"))
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["fit", "--model", str(bare), "--data", str(logs[0]), "--data", str(logs[1]),
                                      "--test", str(logs[2]), "--method", "dm", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "the URDF has no inertials: every body's prior is the same ball" in result.output
    true_mass = RigidBodyModel(pin.buildModelFromXML(arm_urdf(example_robot_urdf()))).nominal[::10]
    written = RigidBodyModel.from_urdf(out / "dm.urdf").nominal[::10]
    assert 0.5 <= written.sum() / true_mass.sum() <= 1.5, (written, true_mass)
    assert written.max() < true_mass.sum()  # no link heavier than the whole true arm
