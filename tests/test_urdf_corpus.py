"""Public URDFs as vendors ship them (example-robot-data, a PyPI package): each loads, a short OLS fit on
simulated logs writes a URDF and an MJCF, and those files load in MuJoCo and in Pinocchio's URDF and MJCF
readers with the identified model's joints and masses.

The robots cover what URDFs in the wild do: package:// mesh URIs (resolved through the config's
model.package_path, or left out of the MJCF with a note), links welded by fixed joints (MuJoCo fuses them
and its writer wraps their children in a <frame>), continuous joints, a <mimic> joint (Franka's fingers),
collision meshes in a format MuJoCo does not read (COLLADA), and a massless frame that carries an inertia.
"""

from __future__ import annotations

import sysconfig
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pandas as pd
import pinocchio as pin
import pytest

from dualid.errors import DualidWarning
from dualid.model.rigid_body import RigidBodyModel
from dualid.report.model_files import write_model_files
from dualid.robot.config import FitConfig
from dualid.robot.fit import fit_robot

SHARE = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share"  # holds the package "example-robot-data"
ROBOTS = SHARE / "example-robot-data" / "robots"
pytestmark = pytest.mark.skipif(not ROBOTS.is_dir(), reason="example-robot-data (the test extra) is not installed")

CORPUS = {  # id: (URDF under robots/, give the package path, what it exercises)
    "panda": ("panda_description/urdf/panda.urdf", True, "mimic fingers, fixed massless frames, STL meshes"),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", False, "package:// meshes not found: MJCF without them"),
    "kinova": ("kinova_description/robots/kinova.urdf", True, "continuous joints, COLLADA collision meshes"),
    "double_pendulum": ("double_pendulum_description/urdf/double_pendulum_continuous.urdf", True, "continuous joints"),
    "z1": ("z1_description/urdf/z1.urdf", True, "a moving body below a fused link (<frame> in MuJoCo's MJCF)"),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", True, "7-DoF arm"),
    "solo": ("solo_description/robots/solo.urdf", True, "legged robot on a fixed base, OBJ meshes"),
    "so100": ("so_arm_description/urdf/so100.urdf", True, "hobby arm"),
}


def _massless_inertia(tmp: Path) -> Path:
    """Franka's panda with panda_link8 a massless frame that carries an inertia (as franka_description has)."""
    text = (ROBOTS / CORPUS["panda"][0]).read_text()
    link8 = text.index('<link name="panda_link8">')
    end = text.index("</link>", link8)
    body = text[link8:end].replace('ixx="0"', 'ixx="0.001"').replace('iyy="0"', 'iyy="0.001"').replace('izz="0"', 'izz="0.001"')
    assert 'ixx="0.001"' in body
    path = tmp / "panda_massless_inertia.urdf"
    path.write_text(text[:link8] + body + text[end:])
    return path


def _simulated_log(rigid: RigidBodyModel, path: Path, T: int = 300, rate: float = 100.0) -> None:
    """A log in the default column layout: smooth motion inside each joint's URDF range (1.5 rad amplitude
    for a continuous joint), τ from Pinocchio's RNEA with the URDF's inertials."""
    model, data = rigid.model, rigid.model.createData()
    n = rigid.nv
    lo, hi = model.lowerPositionLimit, model.upperPositionLimit
    t = np.arange(T) / rate
    rng = np.random.default_rng(0)
    w = rng.uniform(0.6, 2.0, size=(n, 2)) * 2 * np.pi
    phase = rng.uniform(0, 2 * np.pi, size=(n, 2))
    q, v, a = (np.zeros((T, n)) for _ in range(3))
    for j in range(1, model.njoints):
        joint = model.joints[j]
        k = joint.idx_v
        bounded = joint.nq == joint.nv and np.isfinite(hi[joint.idx_q]) and hi[joint.idx_q] < 1e10
        mid = 0.5 * (lo[joint.idx_q] + hi[joint.idx_q]) if bounded else 0.0
        amp = 0.2 * (hi[joint.idx_q] - lo[joint.idx_q]) if bounded else 1.5
        for h in range(2):
            s = amp / 2 * np.sin(w[k, h] * t + phase[k, h])
            q[:, k] += s
            v[:, k] += amp / 2 * w[k, h] * np.cos(w[k, h] * t + phase[k, h])
            a[:, k] -= w[k, h] ** 2 * s
        q[:, k] += mid
    qp = rigid.configuration(q)
    tau = np.stack([pin.rnea(model, data, qp[i], v[i], a[i]) for i in range(T)])
    columns = {"time": t}
    for k in range(n):
        columns.update({f"pos_meas{k + 1}": q[:, k], f"vel_meas{k + 1}": v[:, k], f"tau_meas{k + 1}": tau[:, k]})
    pd.DataFrame(columns).to_csv(path, index=False)


def _fit_and_load(urdf: Path, tmp: Path, package_path: bool) -> tuple[RigidBodyModel, object, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DualidWarning)
        rigid = RigidBodyModel.from_urdf(urdf)
        _simulated_log(rigid, tmp / "run.csv")
        config = FitConfig.from_dict({
            "model": {"urdf": str(urdf), **({"package_path": [str(SHARE)]} if package_path else {})},
            "train": [str(tmp / "run.csv")], "methods": ["ols"],
            "joint_terms": {"viscous": True, "coulomb": False, "armature": True},
            "uncertainty": {"method": "sandwich"},  # the default plausible step: files carry no absurd link
        })
        outcome = fit_robot(config)
    (tmp / "out").mkdir()
    files = write_model_files(outcome, tmp / "out")
    return rigid, files, [str(w.message) for w in caught if issubclass(w.category, DualidWarning)]


def _mass_matrix(pm: pin.Model, angles: dict[str, float]) -> np.ndarray:
    """Pinocchio's M(q) (upper triangle completed) at one angle per joint (cos, sin for a continuous one)."""
    q = pin.neutral(pm)
    for j in range(1, pm.njoints):
        k, x = pm.joints[j].idx_q, angles[pm.names[j]]
        q[k:k + pm.joints[j].nq] = (np.cos(x), np.sin(x)) if pm.joints[j].nq == 2 else (x,)
    M = pin.crba(pm, pm.createData(), q)
    return np.triu(M) + np.triu(M, 1).T


def _same_mass_matrix(mj: mujoco.MjModel, from_mjcf: pin.Model, from_urdf: pin.Model, rng) -> None:
    """M(q) at a random q: MuJoCo's and Pinocchio's MJCF reader's (both with the armature; crba adds it) agree
    with that of Pinocchio's URDF reader on the written URDF (which has no armature), joint by joint name."""
    names = [from_urdf.names[j] for j in range(1, from_urdf.njoints)]
    angles = dict(zip(names, rng.uniform(-1, 1, len(names))))
    md = mujoco.MjData(mj)
    for n in names:
        md.qpos[mj.jnt_qposadr[mj.joint(n).id]] = angles[n]
    mujoco.mj_forward(mj, md)
    M = np.zeros((mj.nv, mj.nv))
    mujoco.mj_fullM(mj, md, M)
    dofs = [mj.jnt_dofadr[mj.joint(n).id] for n in names]
    M = M[np.ix_(dofs, dofs)]
    armature = np.diag(mj.dof_armature[dofs])
    tol = {"rtol": 1e-7, "atol": 1e-9 * np.abs(M).max()}
    np.testing.assert_allclose(_mass_matrix(from_urdf, angles) + armature, M, **tol)
    order = [from_mjcf.getJointId(n) - 1 for n in names]
    np.testing.assert_allclose(_mass_matrix(from_mjcf, angles)[np.ix_(order, order)], M, **tol)


@pytest.mark.parametrize("robot", sorted(CORPUS))
def test_public_urdf_fits_and_its_files_load_everywhere(robot, tmp_path):
    rel, package_path, _ = CORPUS[robot]
    rigid, files, warned = _fit_and_load(ROBOTS / rel, tmp_path, package_path)
    assert not files.not_written, [(f.kind, f.reason) for f in files.not_written]
    record = files.record()["ols"]
    urdf, xml = tmp_path / "out" / record["urdf"], tmp_path / "out" / record["mjcf"]
    # MuJoCo: the written MJCF compiles, with one dof per model coordinate and the identified moving mass
    mj = mujoco.MjModel.from_xml_path(str(xml))
    assert mj.nv == rigid.nv
    from_urdf = pin.buildModelFromUrdf(str(urdf))
    from_mjcf = pin.buildModelFromMJCF(str(xml))
    assert from_urdf.nv == rigid.nv
    assert from_mjcf.nv == rigid.nv  # every body, also those MuJoCo wrote under a <frame>
    assert "<frame" not in xml.read_text()
    _same_mass_matrix(mj, from_mjcf, from_urdf, np.random.default_rng(1))
    moving = sum(from_urdf.inertias[j].mass for j in range(1, from_urdf.njoints))
    assert moving > 0
    np.testing.assert_allclose(mj.body_mass[mj.body_weldid != 0].sum(), moving, rtol=1e-9)  # bodies not welded to the world
    notes = record["mjcf_notes"]
    if not package_path:
        assert "collision meshes not found and left out of the MJCF" in notes
    else:
        assert "not found" not in notes
    if robot == "kinova":
        assert "in a format MuJoCo does not read" in notes


def test_mimic_joint_is_said(tmp_path):
    with pytest.warns(DualidWarning, match="joint 'panda_finger_joint2' mimics joint 'panda_finger_joint1'"):
        RigidBodyModel.from_urdf(ROBOTS / CORPUS["panda"][0])


def test_massless_frame_with_an_inertia_loads_with_a_warning_and_no_inertia(tmp_path):
    urdf = _massless_inertia(tmp_path)
    with pytest.warns(DualidWarning, match="link 'panda_link8' <inertial>: a mass of 0 kg with a non-zero inertia"):
        rigid = RigidBodyModel.from_urdf(urdf)
    reference = RigidBodyModel.from_urdf(ROBOTS / CORPUS["panda"][0])  # the same robot, link8 without inertia
    np.testing.assert_array_equal(rigid.nominal, reference.nominal)
    _, files, _ = _fit_and_load(urdf, tmp_path, True)
    assert not files.not_written
