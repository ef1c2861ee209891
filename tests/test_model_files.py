"""The written URDF and MJCF load in Pinocchio and MuJoCo and give dualid's own dynamics.

Reference: dualid's model (``with_joint_terms(RigidBodyModel)``: M(q) from the metric, τ = Y θ). The
loaders are independent: Pinocchio's URDF and MJCF parsers (crba, rnea, which add model.armature)
and MuJoCo's compiler (mj_fullM, mj_inverse; constraints disabled so frictionloss and joint limits
do not enter, qfrc_inverse = M a + bias − qfrc_passive with qfrc_passive = −damping·v).
What each file keeps is asserted too: the URDF loses armature in both loaders (no URDF field for it).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from dualid.errors import ModelError, OutputError
from dualid.model.joint_terms import with_joint_terms
from dualid.model.mjcf import FULL_PRECISION, identified_mjcf
from dualid.model.rigid_body import RigidBodyModel
from dualid.report.mjcf import write_mjcf
from dualid.report.urdf import write_urdf

PENDUBOT = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data" / "pendubot_model_2.1.urdf"
CUBE = "\n".join([f"v {x} {y} {z}" for x in (-0.05, 0.05) for y in (-0.05, 0.05) for z in (-0.05, 0.05)]
                 + ["f 1 2 4 3", "f 5 7 8 6", "f 1 5 6 2", "f 3 4 8 7", "f 1 3 7 5", "f 2 6 8 4"])
ARM = """<robot name="arm">
  <link name="base"><inertial><mass value="2"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" iyz="0" izz="0.1"/></inertial></link>
  <link name="l1"><inertial><origin xyz="0.02 0.01 0.15" rpy="0.2 0.1 0"/><mass value="1.5"/>
    <inertia ixx="0.02" ixy="0.001" ixz="0" iyy="0.025" iyz="0" izz="0.01"/></inertial>
    <collision><geometry><mesh filename="meshes/cube.obj"/></geometry></collision></link>
  <link name="l2"><inertial><origin xyz="0 0.1 0"/><mass value="0.8"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.004" iyz="0" izz="0.01"/></inertial></link>
  <link name="l3"><inertial><origin xyz="0.05 0 0"/><mass value="0.3"/>
    <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.002" iyz="0" izz="0.002"/></inertial></link>
  <link name="tool"><inertial><origin xyz="0 0 0.05"/><mass value="0.2"/>
    <inertia ixx="0.0005" ixy="0" ixz="0" iyy="0.0005" iyz="0" izz="0.0003"/></inertial></link>
  <joint name="a1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.1" rpy="0 0.1 0"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
  <joint name="a2" type="prismatic"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.3" rpy="0.4 0 0.2"/>
    <axis xyz="0 1 0"/><limit lower="-0.5" upper="0.5" effort="10" velocity="2"/></joint>
  <joint name="a3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0 0.2 0" rpy="0 0 0.3"/>
    <axis xyz="0.6 0 0.8"/><limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
  <joint name="weld" type="fixed"><parent link="l3"/><child link="tool"/><origin xyz="0.1 0 0" rpy="0.3 0 0"/></joint>
</robot>"""


def _setup(urdf: Path, seed: int):
    """(rigid, joint-terms model, θ with random positive friction and armature)."""
    rigid = RigidBodyModel.from_urdf(urdf)
    model = with_joint_terms(rigid)
    rng = np.random.default_rng(seed)
    n = rigid.nv
    theta = np.concatenate([rigid.nominal, rng.uniform(0.01, 0.2, n), rng.uniform(0.05, 0.5, n),
                            rng.uniform(0.001, 0.05, n)])
    return rigid, model, theta


def _write_both(urdf: Path, out: Path, rigid, model, theta) -> tuple[Path, Path]:
    p0 = rigid.parameters.p
    friction, armature = model.friction(theta), model.armature_values(theta)
    u = write_urdf(urdf, rigid, theta[:p0], out / "m.urdf", friction=friction, armature=armature)
    x, _ = write_mjcf(urdf, rigid, theta[:p0], out / "m.xml", friction=friction, armature=armature)
    return u, x


def _without(model, theta, *groups) -> np.ndarray:
    th = np.array(theta)
    for g in groups:
        th[model.index(g)] = 0.0
    return th


def _states(rigid, rng, T=6):
    lo = np.maximum(rigid.model.lowerPositionLimit, -2.5)
    hi = np.minimum(rigid.model.upperPositionLimit, 2.5)
    q = rng.uniform(lo, hi, (T, rigid.nq)) * 0.9
    return q, rng.normal(size=(T, rigid.nv)), rng.normal(size=(T, rigid.nv))


def _pin_dynamics(pm: pin.Model, names, q, v, a, vc):
    """(M, τ = rnea + damping v + friction tanh(v/v_c)) of a loaded Pinocchio model, in dualid's joint order."""
    order = [pm.joints[pm.getJointId(n)].idx_v for n in names]
    pd = pm.createData()
    M = pin.crba(pm, pd, q)
    M = np.triu(M) + np.triu(M, 1).T
    tau = pin.rnea(pm, pd, q, v, a) + pm.damping * v + pm.friction * np.tanh(v / vc)
    return M[np.ix_(order, order)], tau[order]


def _mujoco_model(path: Path) -> mujoco.MjModel:
    """MuJoCo's model of a file, with constraints (frictionloss, limits) disabled."""
    mm = mujoco.MjModel.from_xml_path(str(path))
    mm.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    return mm


def _mujoco_dynamics(path, names, q, v, a):
    """(M, qfrc_inverse, model) of MuJoCo (a file or a loaded model), in dualid's joint order."""
    mm = path if isinstance(path, mujoco.MjModel) else _mujoco_model(path)
    md = mujoco.MjData(mm)
    dofs = [mm.jnt_dofadr[mm.joint(n).id] for n in names]
    md.qpos[:], md.qvel[:], md.qacc[:] = q, v, a
    mujoco.mj_inverse(mm, md)
    M = np.zeros((mm.nv, mm.nv))
    mujoco.mj_fullM(mm, md, M)
    return M[np.ix_(dofs, dofs)], md.qfrc_inverse[dofs].copy(), mm


@pytest.mark.parametrize("source", ["pendubot", "arm"])
def test_files_reproduce_dualid_dynamics(tmp_path, source, monkeypatch):
    urdf = PENDUBOT if source == "pendubot" else tmp_path / "arm.urdf"
    if source == "arm":  # a collision mesh: both files must find it from their own folder, whatever the cwd
        urdf.write_text(ARM)
        (tmp_path / "meshes").mkdir()
        (tmp_path / "meshes" / "cube.obj").write_text(CUBE)
        monkeypatch.chdir("/")
    rigid, model, theta = _setup(urdf, seed=1)
    u, x = _write_both(urdf, tmp_path / "out", rigid, model, theta)
    names, vc = model.coordinates, model.coulomb_velocity
    no_coulomb = _without(model, theta, "coulomb")
    no_arm = _without(model, theta, "coulomb", "armature")
    pin_mjcf, pin_urdf = pin.buildModelFromMJCF(str(x)), pin.buildModelFromUrdf(str(u))
    rng = np.random.default_rng(2)
    for q, v, a in zip(*_states(rigid, rng)):
        M_ref = model.metric(q[None]).evaluate(theta)[0]
        M_noarm = model.metric(q[None]).evaluate(no_arm)[0]
        scale = max(1.0, np.abs(M_ref).max())
        # MJCF in Pinocchio: armature, damping and Coulomb friction all kept
        M, tau = _pin_dynamics(pin_mjcf, names, q, v, a, vc)
        np.testing.assert_allclose(M, M_ref, atol=1e-9 * scale, rtol=0)
        np.testing.assert_allclose(tau, (model.regressor(q, v, a) @ theta)[0], atol=1e-9 * scale, rtol=0)
        # MJCF in MuJoCo: armature and damping in M and qfrc_inverse (Coulomb is a constraint there)
        M, tau, mm = _mujoco_dynamics(x, names, q, v, a)
        np.testing.assert_allclose(M, M_ref, atol=1e-9 * scale, rtol=0)
        np.testing.assert_allclose(tau, (model.regressor(q, v, a) @ no_coulomb)[0], atol=1e-9 * scale, rtol=0)
        np.testing.assert_allclose(mm.dof_frictionloss, [model.friction(theta)[n][1] for n in names], rtol=1e-15)
        # URDF in Pinocchio and MuJoCo: inertials, damping and friction kept; armature lost
        M, tau = _pin_dynamics(pin_urdf, names, q, v, a, vc)
        np.testing.assert_allclose(M, M_noarm, atol=1e-9 * scale, rtol=0)
        np.testing.assert_allclose(tau, (model.regressor(q, v, a) @ _without(model, theta, "armature"))[0],
                                   atol=1e-9 * scale, rtol=0)
        M, tau, mm = _mujoco_dynamics(u, names, q, v, a)
        np.testing.assert_allclose(M, M_noarm, atol=1e-9 * scale, rtol=0)
        np.testing.assert_allclose(tau, (model.regressor(q, v, a) @ no_arm)[0], atol=1e-9 * scale, rtol=0)
        assert not np.allclose(M, M_ref, atol=1e-6)  # the armature is what the URDF loses
    assert pin_urdf.armature.tolist() == [0.0] * rigid.nv
    if source == "arm":
        assert 'file="../meshes/cube.obj"' in x.read_text() and 'filename="../meshes/cube.obj"' in u.read_text()
        assert mujoco.MjModel.from_xml_path(str(x)).nmesh == 1


def test_mjcf_is_written_at_full_precision(tmp_path):
    rigid, model, theta = _setup(PENDUBOT, seed=3)
    mjcf = identified_mjcf(PENDUBOT, rigid, theta[: rigid.parameters.p], armature=model.armature_values(theta))
    assert mjcf.precision == FULL_PRECISION
    spec = mujoco.MjSpec.from_string(mjcf.xml)
    joint = spec.joint("Joint2")
    assert joint.armature == model.armature_values(theta)["Joint2"]  # bit for bit: 17 digits round-trip
    assert "visual geoms dropped (MuJoCo's URDF import discards them)" in mjcf.notes


def test_mjcf_refuses_existing_file_and_unknown_joint(tmp_path):
    rigid, model, theta = _setup(PENDUBOT, seed=4)
    th = theta[: rigid.parameters.p]
    (tmp_path / "m.xml").write_text("mine")
    with pytest.raises(OutputError, match=r"write_mjcf: .*m\.xml already exists; pass overwrite=True to replace it"):
        write_mjcf(PENDUBOT, rigid, th, tmp_path / "m.xml")
    assert (tmp_path / "m.xml").read_text() == "mine"
    with pytest.raises(ModelError) as err:
        identified_mjcf(PENDUBOT, rigid, th, armature={"Elbow": 0.1})
    assert str(err.value) == "write_mjcf: armature for unknown joint 'Elbow'; MuJoCo's joints are ['Joint1', 'Joint2']"


def _file_tau(path: Path, names, runs, vc: float, loader: str) -> list[np.ndarray]:
    """τ on each held-out run from a written file, as a user would compute it: Pinocchio rnea (armature
    included) or MuJoCo's mj_inverse (constraints off), plus the file's damping·v (Pinocchio) and its
    Coulomb level · tanh(v / v_c) (dualid's smooth sign; MuJoCo's frictionloss is a constraint)."""
    out = []
    if loader == "mujoco":
        mm = _mujoco_model(path)
        fc = mm.dof_frictionloss[[mm.jnt_dofadr[mm.joint(n).id] for n in names]]
    else:
        pm = pin.buildModelFromMJCF(str(path)) if path.suffix == ".xml" else pin.buildModelFromUrdf(str(path))
    for run in runs:
        tau = np.empty_like(run.tau)
        for t, (q, v, a) in enumerate(zip(run.q, run.v, run.a)):
            if loader == "mujoco":
                tau[t] = _mujoco_dynamics(mm, names, q, v, a)[1] + fc * np.tanh(v / vc)
            else:
                tau[t] = _pin_dynamics(pm, names, q, v, a, vc)[1]
        out.append(tau)
    return out


def test_dfki_files_give_dualids_held_out_scores(tmp_path):
    """The DFKI example's dm.xml, loaded unchanged in Pinocchio and MuJoCo, gives
    the held-out τ RMSE of dualid's own validation to 1e-6 N m; dm.urdf loses the armature, and with it
    the joint-2 score."""
    from dualid.report.model_files import write_model_files, written_theta
    from dualid.robot.config import FitConfig
    from dualid.robot.fit import fit_robot

    example = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "fit.yaml"
    config = FitConfig.from_yaml(example).with_overrides(methods=("dm",), references=())
    outcome = fit_robot(config)
    (tmp_path / "out").mkdir()
    record = write_model_files(outcome, tmp_path / "out").record()  # what dualid fit writes (without the figures)
    fit = outcome.fits["dm"]
    assert record["dm"] == {"theta": written_theta(fit)[1], "urdf": "dm.urdf", "mjcf": "dm.xml",
                            "mjcf_notes": record["dm"]["mjcf_notes"]}
    assert fit.plausible is not None and fit.plausible.form == "confidence"  # the default: θ_plausible in the region
    names, vc = outcome.model.coordinates, outcome.model.coulomb_velocity
    # the MJCF simulates what was logged: no joint range that a logged run leaves (MuJoCo would add limit forces)
    mj = mujoco.MjModel.from_xml_path(str(tmp_path / "out" / "dm.xml"))
    for k, name in enumerate(names):
        j, q = mj.joint(name).id, np.concatenate([r.q[:, k] for r in (*outcome.train, *outcome.test)])
        assert not mj.jnt_limited[j] or mj.jnt_range[j][0] <= q.min() <= q.max() <= mj.jnt_range[j][1], name
    assert not mj.jnt_limited[mj.joint("Joint2").id] and "joint 'Joint2': the logs reach" in record["dm"]["mjcf_notes"]
    ours = np.array([r.tau_rmse for r in fit.plausible_validation.runs])  # dualid's validation of the written θ
    scores = {}
    for label, path, loader in (("xml pinocchio", "dm.xml", "pinocchio"), ("xml mujoco", "dm.xml", "mujoco"),
                                ("urdf pinocchio", "dm.urdf", "pinocchio"), ("urdf mujoco", "dm.urdf", "mujoco")):
        taus = _file_tau(tmp_path / "out" / path, names, outcome.test, vc, loader)
        scores[label] = np.array([np.sqrt(np.mean((tau - run.tau) ** 2, axis=0)) for tau, run in zip(taus, outcome.test)])
    np.testing.assert_allclose(scores["xml pinocchio"], ours, atol=1e-6, rtol=0)
    np.testing.assert_allclose(scores["xml mujoco"], ours, atol=1e-6, rtol=0)
    # the URDF: the same inertials and friction, no armature (no loader reads it): joint 2 is off
    np.testing.assert_allclose(scores["urdf pinocchio"], scores["urdf mujoco"], atol=1e-6, rtol=0)
    assert np.all(np.abs(scores["urdf pinocchio"][:, 1] - ours[:, 1]) > 1e-3)
    # dualid validate reads both files whole (the URDF's armature from dualid's own attribute)
    from dualid.robot.validate import validate_urdf

    for path in ("dm.xml", "dm.urdf"):
        _, _, val = validate_urdf(tmp_path / "out" / path, config.test, columns=config.columns,
                                  preprocessing=config.preprocessing, coulomb_velocity=vc)
        np.testing.assert_allclose([r.tau_rmse for r in val.runs], ours, atol=1e-6, rtol=0)


def test_validate_names_a_missing_mjcf(tmp_path):
    from dualid.errors import MissingFileError
    from dualid.robot.validate import validate_urdf

    with pytest.raises(MissingFileError) as err:
        validate_urdf(tmp_path / "dm.xml", [tmp_path / "run.csv"])
    assert str(err.value) == f"validate: no MJCF file at {tmp_path / 'dm.xml'}"
