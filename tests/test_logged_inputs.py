"""Inputs people log, end to end: (T, n) arrays in NPZ/Parquet without a column map, URDF continuous
joints (Pinocchio's (cos, sin) configuration), per-joint and linear units against the joint types."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pinocchio as pin
import pytest
import yaml
from typer.testing import CliRunner

from dualid.cli import app
from dualid.errors import DataError
from dualid.model.rigid_body import RigidBodyModel
from tests.test_bad_inputs import GOOD, URDF, _text, write_log, write_urdf

runner = CliRunner()
CONTINUOUS = URDF.replace('type="revolute"', 'type="continuous"')


def test_continuous_joints_take_logged_angles(tmp_path):
    revolute = RigidBodyModel.from_urdf(write_urdf(tmp_path, URDF, "r.urdf"))
    continuous = RigidBodyModel.from_urdf(write_urdf(tmp_path, CONTINUOUS, "c.urdf"))
    assert continuous.nq == 4 and continuous.nv == 2 and revolute.nq == 2
    rng = np.random.default_rng(0)
    q, v, a = (rng.normal(size=(5, 2)) for _ in range(3))
    # the same robot: angles in, the same regressor and Jacobians out as with revolute joints
    np.testing.assert_allclose(continuous.regressor(q, v, a), revolute.regressor(q, v, a), atol=1e-12)
    np.testing.assert_allclose(continuous.jacobians(q), revolute.jacobians(q), atol=1e-12)
    # Pinocchio's own (cos, sin) configuration is accepted too
    qc = np.stack([np.cos(q[:, 0]), np.sin(q[:, 0]), np.cos(q[:, 1]), np.sin(q[:, 1])], axis=1)
    np.testing.assert_allclose(continuous.configuration(qc), qc)
    np.testing.assert_allclose(continuous.configuration(q), qc)
    with pytest.raises(DataError, match=r"q: expected shape \(T, 4\) \(Pinocchio's configuration\) or \(T, 2\) "
                                        r"\(one angle per continuous joint\), got \(5, 3\)"):
        continuous.regressor(np.zeros((5, 3)), v, a)


def test_fit_a_urdf_with_continuous_joints_from_the_cli(tmp_path):
    out = tmp_path / "out"
    result = runner.invoke(app, ["fit", "--model", str(write_urdf(tmp_path, CONTINUOUS)), "--data",
                                 str(write_log(tmp_path)), "--method", "ols", "--out", str(out)])
    assert result.exit_code == 0, _text(result)
    assert (out / "ols.urdf").is_file()


@pytest.mark.parametrize("suffix", [".npz", ".parquet"])
def test_fit_a_log_of_arrays_without_a_column_map(tmp_path, suffix):
    q = GOOD[["pos_meas1", "pos_meas2"]].to_numpy()
    v = GOOD[["vel_meas1", "vel_meas2"]].to_numpy()
    tau = GOOD[["tau_meas1", "tau_meas2"]].to_numpy()
    log = tmp_path / f"run{suffix}"
    if suffix == ".npz":
        np.savez(log, t=GOOD["time"].to_numpy(), q=q, v=v, tau=tau)
    else:
        pd.DataFrame({"t": GOOD["time"], "q": list(q), "v": list(v), "tau": list(tau)}).to_parquet(log)
    out = tmp_path / "out"
    result = runner.invoke(app, ["fit", "--model", str(write_urdf(tmp_path)), "--data", str(log),
                                 "--method", "ols", "--out", str(out)])
    assert result.exit_code == 0, _text(result)
    record = yaml.safe_load((out / "parameters.yaml").read_text())
    assert record["data"]["columns"]["joints"]["Joint2"] == {"position": "q[1]", "velocity": "v[1]", "effort": "tau[1]"}
    # noise-free torques from pin.rnea: OLS recovers the URDF's identifiable combinations (τ exact)
    model = pin.buildModelFromXML(URDF)
    theta = np.array([p["value"] for p in record["methods"]["ols"]["parameters"]])[: 20]
    data = model.createData()
    Y = pin.computeJointTorqueRegressor(model, data, q[300], v[300], np.zeros(2))
    ref = np.concatenate([model.inertias[j].toDynamicParameters() for j in (1, 2)])
    np.testing.assert_allclose(Y @ theta, Y @ ref, rtol=0.05, atol=0.05)


def test_a_linear_unit_on_a_revolute_joint_is_refused(tmp_path):
    cfg = {"model": {"urdf": str(write_urdf(tmp_path))}, "train": [str(write_log(tmp_path))], "methods": ["ols"],
           "columns": {"joints": {f"Joint{i}": {"position": f"pos_meas{i}", "velocity": f"vel_meas{i}",
                                                "effort": f"tau_meas{i}"} for i in (1, 2)},
                       "units": {"position": {"Joint2": "mm"}}}}
    path = tmp_path / "fit.yaml"
    path.write_text(yaml.safe_dump(cfg))
    result = runner.invoke(app, ["fit", "--config", str(path), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert "column map: joint 'Joint2' is revolute but its position unit is 'mm' (linear)" in _text(result)


def test_the_prior_weight_is_per_equation_by_default(tmp_path):
    from dualid.robot.config import FitConfig
    from dualid.robot.fit import estimator

    cfg = FitConfig.from_dict({"model": "r.urdf", "train": ["a.csv"]})
    assert (cfg.prior.gamma, cfg.prior.per_equation) == (0.1, True)
    assert FitConfig.from_dict({"model": "r.urdf", "train": ["a.csv"], "prior": {"per_equation": False}}).prior.per_equation is False
    est = estimator("logdet", np.ones(3), cfg.prior.gamma, cfg.prior.per_equation)
    assert est.per_equation is True and est.gamma == 0.1


def _without_default_additional_properties(schema):
    """The schema without ``"additionalProperties": true``, JSON Schema's default for an object: pydantic 2.11 writes
    it for a dict[str, Any], 2.10 leaves it out; the two schemas accept the same documents."""
    if isinstance(schema, dict):
        return {k: _without_default_additional_properties(v) for k, v in schema.items()
                if not (k == "additionalProperties" and v is True)}
    if isinstance(schema, list):
        return [_without_default_additional_properties(v) for v in schema]
    return schema


def test_the_json_schema_in_docs_is_current_and_accepts_the_example():
    import json
    from pathlib import Path

    from dualid.robot.config import _TOP_KEYS, FitConfig
    from dualid.robot.schema import FitConfigSchema, check_shape, json_schema

    root = Path(__file__).resolve().parents[1]
    documented = json.loads((root / "docs" / "fit-config.schema.json").read_text())
    assert (_without_default_additional_properties(documented) == _without_default_additional_properties(json_schema())), \
        "regenerate: dualid schema > docs/fit-config.schema.json"
    assert tuple(FitConfigSchema.model_fields) == _TOP_KEYS  # the schema and FitConfig know the same keys
    example = root / "examples" / "dfki" / "fit.yaml"
    check_shape(yaml.safe_load(example.read_text()))
    if (root.parent / "shared" / "datasets" / "dfki-double-pendulum").is_dir():
        FitConfig.from_yaml(example)


def test_schema_errors_name_the_key_path():
    from dualid.errors import ConfigError
    from dualid.robot.schema import check_shape

    with pytest.raises(ConfigError, match=r"config: joint_terms.coulomb_velocity: Input should be a valid number"):
        check_shape({"model": "r.urdf", "train": "a.csv", "joint_terms": {"coulomb_velocity": "fast"}})
    with pytest.raises(ConfigError, match=r"model.gravity: List should have at least 3 items after validation, not 2 "
                                          r"\(got \[0, 1\]\)$"):  # the union's other member (a string) is not reported
        check_shape({"model": {"urdf": "r", "gravity": [0, 1]}, "train": ["a"]})


def test_fit_robot_records_each_warning_once(tmp_path):
    import warnings

    from dualid.errors import DualidWarning
    from dualid.robot.config import FitConfig
    from dualid.robot.fit import fit_robot

    deg = GOOD.assign(vel_meas1=GOOD["vel_meas1"] * 180 / np.pi)
    log = write_log(tmp_path, deg, "deg.csv")
    cfg = FitConfig.from_dict({"model": str(write_urdf(tmp_path)), "train": [str(log)], "test": [str(log)],
                               "methods": ["ols"]})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        outcome = fit_robot(cfg)
    ours = [str(w.message) for w in caught if issubclass(w.category, DualidWarning)]
    assert len(ours) == len(set(ours)) == len(outcome.warnings) == 2
    assert "the logged velocity is 57.3 × dq/dt" in outcome.warnings[0] or "57.3" in outcome.warnings[1]
    assert any("is the same data as training log" in w for w in outcome.warnings)
