"""LandSalp: three links in a planar chain, two passive joints, one omni wheel per link; drag-dominated.

Kinematics come from a Pinocchio model built here:

    root:   planar joint (x, y, heading) carrying the MIDDLE link (link 2) — the base frame
    joint1: revolute z at (−L/2, 0) of link 2, carrying link 1 (its centre at (−L/2, 0) of the joint)
    joint2: revolute z at (+L/2, 0) of link 2, carrying link 3 (its centre at (+L/2, 0) of the joint)
    wheel b: operational frame at the centre of link b, rotated by φ_b about z (φ = −57°, −130°, −57°)

So with a straight chain link 1 is the rear link, link 3 the front link, and "forward" is +x of link 2.

Coordinates (velocities, n = 5): v = (x, y, theta, alpha1, alpha2) where (x, y, theta) are the body
velocity of the base frame (vx, vy [m/s], ωz [rad/s], Pinocchio's planar convention, in link 2's
frame) and alpha1, alpha2 [rad/s] the joint rates. Configuration q (nq = 6) is Pinocchio's:
(x, y, cos heading, sin heading, alpha1, alpha2) [m, m, –, –, rad, rad]; the metric depends on the
shape (alpha1, alpha2) only.

Drag in wheel frame b: D_b = diag(longitudinal, lateral, rotational) acting on the wheel-frame
velocity u_b = J_b v (J_b the LOCAL frame Jacobian, rows vx, vy, ωz), plus joint damping c1, c2:

    M(q, θ) = Σ_b J_bᵀ D_b J_b + diag(0, 0, 0, c1, c2),     τ = M(q) v

θ (p = 11): [link1.longitudinal, link1.lateral, link1.rotational, link2.…, link3.…, joint1.damping,
joint2.damping] in [N s/m, N s/m, N m s/rad, …, N m s/rad, N m s/rad].
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import pinocchio as pin

from dualid.errors import DataError
from dualid.model.base import Kind
from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.parameters import ParameterBlock, ParameterSpace

LINK_LENGTH = 0.272  # [m]
WHEEL_RADIUS = 0.041275  # [m] (informational: the model works with wheel-frame forces)
WHEEL_ANGLES_DEG = (-57.0, -130.0, -57.0)  # wheel frame rotation relative to its link, links 1, 2, 3
COORDINATES = ("x", "y", "theta", "alpha1", "alpha2")
NQ = 6  # Pinocchio configuration: x, y, cos, sin, alpha1, alpha2
JOINT_VELOCITY_ROWS = (0, 1, 5)  # (vx, vy, ωz) rows of a 6-D Pinocchio motion Jacobian


def _parameter_space() -> ParameterSpace:
    names, units, blocks = [], [], []
    for b in (1, 2, 3):
        start = len(names)
        names += [f"link{b}.longitudinal", f"link{b}.lateral", f"link{b}.rotational"]
        units += ["N s/m", "N s/m", "N m s/rad"]
        blocks.append(ParameterBlock(f"link{b}", "drag_diagonal", (start, start + 1, start + 2)))
    names += ["joint1.damping", "joint2.damping"]
    units += ["N m s/rad", "N m s/rad"]
    blocks.append(ParameterBlock("joints", "nonnegative", (9, 10)))
    return ParameterSpace(tuple(names), tuple(units), tuple(blocks))


def build_pinocchio_model(
    link_length: float = LINK_LENGTH, wheel_angles_deg: tuple[float, float, float] = WHEEL_ANGLES_DEG
) -> pin.Model:
    """The kinematic chain (massless links) with frames 'link1..3' and 'wheel1..3'."""
    L = link_length
    model = pin.Model()
    model.name = "landsalp"
    root = model.addJoint(0, pin.JointModelPlanar(), pin.SE3.Identity(), "base")
    rear = model.addJoint(root, pin.JointModelRZ(), pin.SE3(np.eye(3), np.array([-L / 2, 0.0, 0.0])), "joint1")
    front = model.addJoint(root, pin.JointModelRZ(), pin.SE3(np.eye(3), np.array([L / 2, 0.0, 0.0])), "joint2")
    centres = {1: (rear, -L / 2), 2: (root, 0.0), 3: (front, L / 2)}
    for b, (joint, offset) in centres.items():
        p = np.array([offset, 0.0, 0.0])
        model.addFrame(pin.Frame(f"link{b}", joint, pin.SE3(np.eye(3), p), pin.FrameType.OP_FRAME))
        R = pin.utils.rotate("z", np.deg2rad(wheel_angles_deg[b - 1]))
        model.addFrame(pin.Frame(f"wheel{b}", joint, pin.SE3(R, p), pin.FrameType.OP_FRAME))
    return model


def configuration(x, y, heading, alpha1, alpha2) -> np.ndarray:
    """Pinocchio configurations q (T, 6) = (x, y, cos heading, sin heading, alpha1, alpha2)."""
    x, y, heading, alpha1, alpha2 = np.broadcast_arrays(*(np.atleast_1d(np.asarray(a, float)) for a in
                                                           (x, y, heading, alpha1, alpha2)))
    return np.stack([x, y, np.cos(heading), np.sin(heading), alpha1, alpha2], axis=1)


def heading(q: np.ndarray) -> np.ndarray:
    """Heading angle (T,) [rad] of the base frame from Pinocchio configurations (T, 6)."""
    q = np.atleast_2d(q)
    return np.arctan2(q[:, 3], q[:, 2])


@dataclass(frozen=True, eq=False)
class LandSalpModel:
    """Drag-dominated LandSalp model, τ = M(q, θ) v (see the module docstring)."""

    link_length: float = LINK_LENGTH  # [m]
    wheel_angles_deg: tuple[float, float, float] = WHEEL_ANGLES_DEG
    kind: ClassVar[Kind] = "drag"
    coordinates = COORDINATES
    parameters = _parameter_space()
    pinocchio_model: pin.Model = field(init=False, repr=False)
    wheel_frames: tuple[int, int, int] = field(init=False, repr=False)
    link_frames: tuple[int, int, int] = field(init=False, repr=False)
    _data: pin.Data = field(init=False, repr=False)  # Pinocchio workspace (reused: createData is costly)

    def __post_init__(self) -> None:
        model = build_pinocchio_model(self.link_length, tuple(self.wheel_angles_deg))
        object.__setattr__(self, "pinocchio_model", model)
        object.__setattr__(self, "wheel_frames", tuple(model.getFrameId(f"wheel{b}") for b in (1, 2, 3)))
        object.__setattr__(self, "link_frames", tuple(model.getFrameId(f"link{b}") for b in (1, 2, 3)))
        object.__setattr__(self, "_data", model.createData())

    # --- kinematics ---------------------------------------------------------------------------
    def check_configuration(self, q) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if q.ndim != 2 or q.shape[1] != NQ:
            raise DataError(
                f"LandSalp configuration: expected q of shape (T, {NQ}) = (x, y, cos heading, sin heading, "
                f"alpha1, alpha2), got {q.shape}"
            )
        if not np.all(np.isfinite(q)):
            raise DataError("LandSalp configuration: q has non-finite values (NaN or inf)")
        return q

    def wheel_jacobians(self, q) -> np.ndarray:
        """J (T, 3, 3, 5): per wheel b, the LOCAL wheel-frame Jacobian (rows vx, vy, ωz) of q."""
        q = self.check_configuration(q)
        model = self.pinocchio_model
        data = self._data
        rows = list(JOINT_VELOCITY_ROWS)
        J = np.empty((q.shape[0], 3, 3, 5))
        for i, qi in enumerate(q):
            qi = qi.copy()
            qi[2:4] /= np.hypot(qi[2], qi[3])  # unit complex number for the planar joint
            pin.computeJointJacobians(model, data, qi)
            pin.updateFramePlacements(model, data)
            for b, fid in enumerate(self.wheel_frames):
                J[i, b] = pin.getFrameJacobian(model, data, fid, pin.LOCAL)[rows]
        return J

    def link_poses(self, q) -> np.ndarray:
        """World poses (T, 3, 3) of the link frames: per link (x [m], y [m], heading [rad])."""
        q = self.check_configuration(q)
        model = self.pinocchio_model
        data = self._data
        out = np.empty((q.shape[0], 3, 3))
        for i, qi in enumerate(q):
            qi = qi.copy()
            qi[2:4] /= np.hypot(qi[2], qi[3])
            pin.framesForwardKinematics(model, data, qi)
            for b, fid in enumerate(self.link_frames):
                oMf = data.oMf[fid]
                out[i, b] = (oMf.translation[0], oMf.translation[1], np.arctan2(oMf.rotation[1, 0], oMf.rotation[0, 0]))
        return out

    def generalized_force(self, q, wheel_forces) -> np.ndarray:
        """τ (T, 5) = Σ_b J_bᵀ [F_b, 0, 0] from wheel drive forces F (T, 3) [N] along each wheel's axis."""
        F = np.atleast_2d(np.asarray(wheel_forces, dtype=float))
        J = self.wheel_jacobians(q)
        if F.shape != (J.shape[0], 3):
            raise DataError(f"LandSalp wheel forces: expected shape ({J.shape[0]}, 3), got {F.shape}")
        return np.einsum("tbj,tb->tj", J[:, :, 0, :], F)

    # --- Model protocol -------------------------------------------------------------------------
    def metric(self, q) -> AffineMetric:
        J = self.wheel_jacobians(q)
        T = J.shape[0]
        E3 = np.eye(3)[:, :, None] * np.eye(3)[:, None, :]  # (3, 3, 3): E_k = e_k e_kᵀ
        terms = [MetricTerm((3 * b, 3 * b + 1, 3 * b + 2), E3, J[:, b]) for b in range(3)]
        for j in range(2):
            Jj = np.zeros((T, 1, 5))
            Jj[:, 0, 3 + j] = 1.0
            terms.append(MetricTerm((9 + j,), np.ones((1, 1, 1)), Jj))
        return AffineMetric(self.parameters.p, tuple(terms))

    def regressor(self, q, v, a=None) -> np.ndarray:
        """Y (T, 5, 11) with τ = Y θ = M(q, θ) v; the acceleration a is ignored (first-order system)."""
        q = self.check_configuration(q)
        v = np.atleast_2d(np.asarray(v, dtype=float))
        if v.shape != (q.shape[0], 5):
            raise DataError(f"LandSalp velocities: expected shape ({q.shape[0]}, 5), got {v.shape}")
        return self.metric(q).apply(v)

    def bias_regressor(self, q, v) -> np.ndarray:
        """Zeros (T, 5, 11): a drag model has no force at zero velocity."""
        q = self.check_configuration(q)
        return np.zeros((q.shape[0], 5, self.parameters.p))
