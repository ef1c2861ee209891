"""The DFKI double pendulum lab's identified parameters (reference_parameters_model_*.yml) as our θ.

The lab's model (double_pendulum/model/plant.py, "UnderactuatedLecture" formulas), q = 0 hanging down:

    M11 = I1 + I2 + m2 l1² + 2 m2 l1 r2 cos q2 + gr² Ir + Ir
    M12 = I2 + m2 l1 r2 cos q2 − gr Ir
    M22 = I2 + gr² Ir
    G   = −(m1 r1 + m2 l1) g sin q1 − m2 r2 g sin(q1 + q2),   −m2 r2 g sin(q1 + q2)   (τ = Ma + Cv − G + F)
    F_j = b_j v_j + cf_j atan(100 v_j)

so I1, I2 are inertias about the joint axes (I_j = I_cj + m_j r_j²): the lab's URDF writes them as
inertias about the centre of mass, which counts m_j r_j² twice; we do not copy that.

Conversion into our θ (Pinocchio joint frames, read from the URDF kinematics at q = 0):
- body j: mass m_j, centre of mass r_j along the downward direction (gravity) in joint j's frame,
  inertia about the centre of mass I_cj = I_j − m_j r_j² about the joint axis (the axes across it
  are not identifiable in planar motion: we put I_cj on the horizontal one and 0.1·I_cj along the
  link so the body is strictly consistent). The link length l1 comes from the URDF (joint 2's
  origin); it is checked against the file's l1.
- rotors: motor 2 rides on link 1, which gives the constant terms gr²Ir + Ir, −gr Ir, gr²Ir in M.
  Exactly representable as: body 2's axial inertia + c (c = −gr Ir, the constant M12 term), and
  armature Ia1 = gr²Ir + Ir − c, Ia2 = gr²Ir − c on the joints.
- friction: viscous b_j; Coulomb cf_j atan(100 v) saturates at cf_j π/2, so fc_j = cf_j π/2 in
  our fc tanh(v / v_c) (the shapes differ only for |v| ≲ 0.05 rad/s).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin

from dualid.errors import ConfigError, DataError
from dualid.model.joint_terms import JointTermsModel
from dualid.model.rigid_body import RigidBodyModel

KEYS = ("m1", "m2", "l1", "l2", "r1", "r2", "I1", "I2", "Ir", "gr", "b1", "b2", "cf1", "cf2", "g")
CROSS_AXIS_RATIO = 0.1  # along-link / across-link central inertia of the invented (unidentifiable) axes


def load_reference(yml_path: str | Path) -> dict[str, float]:
    """The lab's parameters as floats; KeyError-free: missing names raise ValueError."""
    from dualid.data.files import read_mapping

    path = Path(yml_path)
    d = read_mapping(path, "DFKI reference parameters")
    missing = [k for k in KEYS if k not in d]
    if missing:
        raise DataError(f"{path}: missing DFKI parameters {missing}; expected {list(KEYS)}")
    bad = {k: d[k] for k in KEYS if isinstance(d[k], bool) or not isinstance(d[k], (int, float))
           or not np.isfinite(d[k])}
    if bad:
        raise DataError(f"{path}: DFKI parameters must be finite numbers; got {bad}")
    return {k: float(v) for k, v in d.items() if isinstance(v, (int, float))}


def _geometry(rigid: RigidBodyModel) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray, np.ndarray]:
    """Per joint at q = 0: axis and downward unit vector in the joint frame; joint 2's origin in frame 1; world axes."""
    model = rigid.model
    if rigid.base_coordinates or model.nv != 2 or model.njoints != 3:
        raise DataError(
            f"DFKI reference: expected a fixed-base chain of 2 revolute joints, got joints {list(rigid.bodies)} "
            f"(nv = {model.nv})"
        )
    data = model.createData()
    q0 = pin.neutral(model)
    pin.forwardKinematics(model, data, q0)
    pin.computeJointJacobians(model, data, q0)
    g = np.array(model.gravity.linear)
    if np.linalg.norm(g) == 0:
        raise DataError("DFKI reference: the model has zero gravity, so 'down' is undefined")
    down_w = g / np.linalg.norm(g)
    axes, downs, axes_w = [], [], []
    for j in (1, 2):
        J = pin.getJointJacobian(model, data, j, pin.LOCAL)
        axis = J[3:, j - 1]
        if np.linalg.norm(J[:3, j - 1]) > 1e-12 or abs(np.linalg.norm(axis) - 1) > 1e-9:
            raise DataError(f"DFKI reference: joint {model.names[j]!r} is not a revolute joint")
        R = data.oMi[j].rotation
        d = R.T @ down_w
        d = d - axis * (axis @ d)
        if np.linalg.norm(d) < 1e-9:
            raise DataError(f"DFKI reference: joint {model.names[j]!r} rotates about the vertical")
        axes.append(axis)
        downs.append(d / np.linalg.norm(d))
        axes_w.append(R @ axis)
    if axes_w[0] @ axes_w[1] < 1 - 1e-9:
        raise DataError("DFKI reference: the two joint axes are not parallel and equally oriented")
    p12 = model.jointPlacements[2].translation  # joint 2's origin in joint 1's frame
    return axes, downs, p12, np.array(axes_w)


def _body(m: float, r: float, I_axis: float, axis: np.ndarray, down: np.ndarray, name: str) -> np.ndarray:
    Ic = I_axis - m * r * r
    if not (m > 0 and Ic > 0):
        raise DataError(
            f"DFKI reference: body {name!r} has m = {m}, inertia about the axis {I_axis} and m r² = {m * r * r}: "
            "the inertia about the centre of mass would not be positive"
        )
    side = np.cross(axis, down)
    I_com = Ic * (np.outer(axis, axis) + np.outer(side, side)) + CROSS_AXIS_RATIO * Ic * np.outer(down, down)
    return pin.Inertia(m, r * down, I_com).toDynamicParameters()


def reference_theta(yml_path: str | Path, model: JointTermsModel | RigidBodyModel) -> np.ndarray:
    """θ (model.parameters.p,) of the lab's model in ``model``'s parameter space (see the module docstring).

    ``model``: the DFKI URDF's RigidBodyModel, or it with joint terms (viscous, Coulomb and/or
    armature on both joints). A nonzero lab quantity the model has no parameter for raises.
    """
    P = load_reference(yml_path)
    rigid = model.base if isinstance(model, JointTermsModel) else model
    if not isinstance(rigid, RigidBodyModel):
        raise ConfigError(f"DFKI reference: expected a RigidBodyModel (or with joint terms), got {type(rigid).__name__}")
    axes, downs, p12, _ = _geometry(rigid)
    l1_urdf = float(np.linalg.norm(p12 - axes[0] * (axes[0] @ p12)))
    if abs(l1_urdf - P["l1"]) > 1e-3:
        raise DataError(f"DFKI reference: l1 = {P['l1']} m but the URDF puts joint 2 at {l1_urdf:.4f} m from joint 1")
    if abs(np.linalg.norm(rigid.gravity) - P["g"]) > 1e-2:
        raise DataError(f"DFKI reference: g = {P['g']} but the model's gravity is {np.linalg.norm(rigid.gravity):.4g} m/s²")
    c = -P["gr"] * P["Ir"]  # the constant M12 term of motor 2's rotor
    theta_rigid = np.concatenate([
        _body(P["m1"], P["r1"], P["I1"], axes[0], downs[0], rigid.bodies[0]),
        _body(P["m2"], P["r2"], P["I2"] + c, axes[1], downs[1], rigid.bodies[1]),
    ])
    if not isinstance(model, JointTermsModel):
        extra = {k: P[k] for k in ("Ir", "b1", "b2", "cf1", "cf2") if P[k] != 0}
        if extra:
            raise DataError(f"DFKI reference: the model has no joint terms for the nonzero lab parameters {extra}")
        return theta_rigid
    theta = np.zeros(model.parameters.p)
    theta[: rigid.parameters.p] = theta_rigid
    values = {
        "b": {rigid.coordinates[0]: P["b1"], rigid.coordinates[1]: P["b2"]},
        "fc": {rigid.coordinates[0]: P["cf1"] * np.pi / 2, rigid.coordinates[1]: P["cf2"] * np.pi / 2},
        "Ia": {
            rigid.coordinates[0]: P["gr"] ** 2 * P["Ir"] + P["Ir"] - c,
            rigid.coordinates[1]: P["gr"] ** 2 * P["Ir"] - c,
        },
    }
    names = model.parameters.names
    for suffix, per_joint in values.items():
        for joint, value in per_joint.items():
            name = f"{joint}.{suffix}"
            if name in names:
                theta[names.index(name)] = value
            elif value != 0:
                raise DataError(f"DFKI reference: the model has no parameter {name!r} for the lab's value {value:.6g}")
    return theta


def reference_mass_matrix(P: dict[str, float], q2: np.ndarray) -> np.ndarray:
    """The lab's closed-form M(q) (T, 2, 2) (for tests and documentation)."""
    h = P["m2"] * P["l1"] * P["r2"] * np.cos(q2)
    M = np.empty((len(q2), 2, 2))
    M[:, 0, 0] = P["I1"] + P["I2"] + P["m2"] * P["l1"] ** 2 + 2 * h + P["gr"] ** 2 * P["Ir"] + P["Ir"]
    M[:, 0, 1] = M[:, 1, 0] = P["I2"] + h - P["gr"] * P["Ir"]
    M[:, 1, 1] = P["I2"] + P["gr"] ** 2 * P["Ir"]
    return M
