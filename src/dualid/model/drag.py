"""A generic drag-dominated model: τ = D(q, θ) v, built from a URDF or a planar chain and a ``DragSpec``.

Kinematics come from Pinocchio (a URDF through ``pin.buildModelFromUrdf``, or a planar serial chain
built here). Each drag body b (``model.drag_spec.DragBody``) contributes J_bᵀ C_b(θ_b) J_b, J_b the
LOCAL Jacobian of its drag frame restricted to its components ((vx, vy, wz) or all six), and each
damped joint j contributes θ_j e_j e_jᵀ:

    D(q, θ) = Σ_b J_b(q)ᵀ C_b(θ_b) J_b(q) + Σ_j θ_j e_j e_jᵀ          (affine in θ: an AffineMetric)

The regressor is DERIVED from the metric, Y(q, v) θ = D(q, θ) v (``AffineMetric.apply``), so the
model states the physics once. Consistency: diagonal bodies have θ_b ≥ 0 (``drag_diagonal``), full
bodies C_b(θ_b) ⪰ 0 (``drag_matrix``, an LMI for every estimator), damping ≥ 0 (``nonnegative``).

Coordinates (the chart of the logs): one position per velocity coordinate, v = dq/dt. A 1-DOF joint
is its angle [rad] or displacement [m] (a continuous joint's angle is unwrapped). A planar joint
(``base: planar``) is (x, y, theta): its position in the parent frame [m] and heading [rad], so its
velocities are world-frame rates (ẋ, ẏ, θ̇) and its generalized forces the world-frame force and
torque; Pinocchio's body velocity is B(q) v with B = blockdiag(R(θ)ᵀ, 1).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
import pinocchio as pin

from dualid.errors import DataError, MissingFileError, ModelError
from dualid.model.base import Kind
from dualid.model.drag_spec import MOTION_ROWS, DragSpec
from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.parameters import ParameterBlock, ParameterSpace, diagonal_basis, symmetric_basis
from dualid.model.urdf_check import urdf_for_pinocchio

_ONE_DOF = ("JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned", "JointModelPX",
            "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned")
_UNBOUNDED = ("JointModelRUBX", "JointModelRUBY", "JointModelRUBZ", "JointModelRevoluteUnboundedUnaligned")
_PRISMATIC = ("JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned")
PLANAR_COORDINATES = ("x", "y", "theta")


def chain_model(lengths: tuple[float, ...], base: str = "fixed") -> pin.Model:
    """A planar serial chain: link i spans [0, L_i] along x of its joint frame; joint i (revolute z, i ≥ 1)
    sits at the end of link i and carries link i+1. Frames 'link<i>' at the link centres and 'joint<i>'
    at the joints. base "planar": a planar root joint carries link 1 (its pose: the rear end of link 1);
    "fixed": link 1 is welded to the world at the origin."""
    model = pin.Model()
    model.name = "chain"
    parent = 0
    if base == "planar":
        parent = model.addJoint(0, pin.JointModelPlanar(), pin.SE3.Identity(), "root_joint")
    for i, L in enumerate(lengths, start=1):
        if i > 1:
            offset = pin.SE3(np.eye(3), np.array([lengths[i - 2], 0.0, 0.0]))
            parent = model.addJoint(parent, pin.JointModelRZ(), offset, f"joint{i - 1}")
            model.addFrame(pin.Frame(f"joint{i - 1}", parent, pin.SE3.Identity(), pin.FrameType.JOINT))
        centre = pin.SE3(np.eye(3), np.array([L / 2, 0.0, 0.0]))
        model.addFrame(pin.Frame(f"link{i}", parent, centre, pin.FrameType.OP_FRAME))
    return model


def _joint_layout(model: pin.Model, where: str):
    """Per moving joint: (name, shortname, idx_q, idx_v, coordinate names)."""
    out = []
    for j in range(1, model.njoints):
        joint, name = model.joints[j], model.names[j]
        short = joint.shortname()
        if short == "JointModelPlanar":
            coords = PLANAR_COORDINATES if name == "root_joint" else tuple(f"{name}.{c}" for c in PLANAR_COORDINATES)
        elif short in _ONE_DOF or short in _UNBOUNDED:
            coords = (name,)
        else:
            raise ModelError(f"{where}: joint {name!r} is a {short}; a drag model supports revolute, continuous, "
                             "prismatic and planar joints (base: planar)")
        out.append((name, short, joint.idx_q, joint.idx_v, coords))
    return tuple(out)


@dataclass(frozen=True, eq=False)
class DragModel:
    """A drag-dominated model τ = D(q, θ) v (see the module docstring); build it with ``from_urdf``,
    ``from_chain`` or ``build``."""

    kinematics: pin.Model  # Pinocchio's model (not modified: drag frames are added to a copy)
    spec: DragSpec
    source: str = ""  # where the kinematics came from, for messages
    kind: ClassVar[Kind] = "drag"
    coordinates: tuple[str, ...] = field(init=False)
    parameters: ParameterSpace = field(init=False)
    nominal: np.ndarray | None = field(init=False)  # θ₀ from the spec's nominal values, or None
    pinocchio_model: pin.Model = field(init=False, repr=False)
    _layout: tuple = field(init=False, repr=False)
    _frames: tuple[int, ...] = field(init=False, repr=False)  # drag frame ids, per body
    _damped: tuple[int, ...] = field(init=False, repr=False)  # velocity index per damped joint
    _data: pin.Data = field(init=False, repr=False)

    def __post_init__(self) -> None:
        where = self.source or "drag model"
        model = pin.Model(self.kinematics)
        layout = _joint_layout(model, where)
        coords = tuple(c for *_, cs in layout for c in cs)
        frames = []
        for b in self.spec.bodies:
            if not model.existFrame(b.frame):
                known = [f.name for f in model.frames if f.name != "universe"]
                raise ModelError(f"{where}: model.drag.bodies.{b.name}.frame: no frame named {b.frame!r}; "
                                 f"frames: {known}")
            f = model.frames[model.getFrameId(b.frame)]
            offset = pin.SE3(pin.rpy.rpyToMatrix(*b.rpy), np.array(b.xyz))
            frames.append(model.addFrame(pin.Frame(f"drag:{b.name}", f.parentJoint, f.placement * offset,
                                                   pin.FrameType.OP_FRAME)))
        joints = {name: (short, iv) for name, short, _, iv, cs in layout if len(cs) == 1}
        damped, names, units, blocks = [], [], [], []
        for b in self.spec.bodies:
            start = len(names)
            names += b.parameter_names
            units += b.parameter_units
            kind = "drag_diagonal" if b.form == "diagonal" else "drag_matrix"
            blocks.append(ParameterBlock(b.name, kind, tuple(range(start, len(names)))))
        for j, _ in self.spec.damping:
            if j not in joints:
                raise ModelError(f"{where}: model.drag.damping: no 1-DOF joint named {j!r}; joints: {list(joints)}")
            damped.append(joints[j][1])
            names.append(f"{j}.damping")
            units.append("N s/m" if joints[j][0] in _PRISMATIC else "N m s/rad")
        if self.spec.damping:
            blocks.append(ParameterBlock("damping", "nonnegative", tuple(range(len(names) - len(damped), len(names)))))
        try:
            parameters = ParameterSpace(tuple(names), tuple(units), tuple(blocks))
        except ModelError as exc:
            raise ModelError(f"{where}: model.drag: {exc}") from None
        for key, value in (("pinocchio_model", model), ("_layout", layout), ("coordinates", coords),
                           ("_frames", tuple(frames)), ("_damped", tuple(damped)), ("parameters", parameters),
                           ("nominal", self.spec.nominal_theta()), ("_data", model.createData())):
            object.__setattr__(self, key, value)

    # --- construction ------------------------------------------------------------------------
    @classmethod
    def from_urdf(cls, path: str | Path, spec: DragSpec) -> "DragModel":
        """The URDF's kinematic tree (inertials ignored) with a planar root joint when spec.base is planar."""
        path = Path(path)
        if not path.is_file():
            raise MissingFileError(f"URDF not found: {path}")
        xml = urdf_for_pinocchio(path)  # values checked before Pinocchio sees them; an undeclared "world" added
        try:
            root = (pin.JointModelPlanar(),) if spec.base == "planar" else ()
            model = pin.buildModelFromUrdf(str(path), *root) if xml is None else pin.buildModelFromXML(xml, *root)
        except (RuntimeError, ValueError) as exc:
            raise ModelError(f"{path}: Pinocchio could not build a model from this URDF: {exc}") from None
        return cls(model, spec, str(path))

    @classmethod
    def from_chain(cls, spec: DragSpec) -> "DragModel":
        if spec.chain is None:
            raise ModelError("model.drag.chain: a drag model needs a URDF (model.urdf) or a chain of link lengths")
        return cls(chain_model(spec.chain, spec.base), spec, "chain")

    @classmethod
    def build(cls, spec: DragSpec, urdf: str | Path | None = None) -> "DragModel":
        """From the URDF when given, else from the spec's chain (exactly one of the two)."""
        if urdf is not None and spec.chain is not None:
            raise ModelError("model: give either a URDF (model.urdf) or model.drag.chain, not both")
        return cls.from_chain(spec) if urdf is None else cls.from_urdf(urdf, spec)

    # --- kinematics ---------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return len(self.coordinates)

    @property
    def linear_coordinates(self) -> tuple[str, ...]:
        """The coordinates measured in metres (a planar joint's x, y; prismatic joints); the others are angles."""
        return tuple(cs[k] for _, short, _, _, cs in self._layout for k in range(len(cs))
                     if short in _PRISMATIC or (short == "JointModelPlanar" and k < 2))

    def check_configuration(self, q) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if q.ndim != 2 or q.shape[1] != self.n:
            raise DataError(f"drag model configuration: expected q of shape (T, {self.n}) = {self.coordinates}, "
                            f"got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise DataError("drag model configuration: q has non-finite values (NaN or inf)")
        return q

    def configuration(self, q) -> np.ndarray:
        """Pinocchio configurations (T, nq) of chart positions q (T, n)."""
        q = self.check_configuration(q)
        out = np.zeros((q.shape[0], self.pinocchio_model.nq))
        for _, short, iq, iv, _ in self._layout:
            if short == "JointModelPlanar":
                out[:, iq:iq + 2] = q[:, iv:iv + 2]
                out[:, iq + 2], out[:, iq + 3] = np.cos(q[:, iv + 2]), np.sin(q[:, iv + 2])
            elif short in _UNBOUNDED:
                out[:, iq], out[:, iq + 1] = np.cos(q[:, iv]), np.sin(q[:, iv])
            else:
                out[:, iq] = q[:, iv]
        return out

    def chart_jacobian(self, q) -> np.ndarray:
        """B (T, n, n): Pinocchio's velocity = B(q) v (identity but for planar joints' rotation)."""
        q = self.check_configuration(q)
        B = np.broadcast_to(np.eye(self.n), (q.shape[0], self.n, self.n)).copy()
        for _, short, _, iv, _ in self._layout:
            if short == "JointModelPlanar":
                c, s = np.cos(q[:, iv + 2]), np.sin(q[:, iv + 2])
                B[:, iv, iv], B[:, iv, iv + 1], B[:, iv + 1, iv], B[:, iv + 1, iv + 1] = c, s, -s, c
        return B

    def body_jacobians(self, q) -> tuple[np.ndarray, ...]:
        """Per drag body: J_b (T, size, n), its drag frame's LOCAL velocity components of v."""
        qp = self.configuration(q)
        B = self.chart_jacobian(q)
        model, data = self.pinocchio_model, self._data
        out = [np.empty((qp.shape[0], b.size, self.n)) for b in self.spec.bodies]
        rows = [list(MOTION_ROWS[b.size]) for b in self.spec.bodies]
        for i, qi in enumerate(qp):
            pin.computeJointJacobians(model, data, qi)
            pin.updateFramePlacements(model, data)
            for k, fid in enumerate(self._frames):
                out[k][i] = pin.getFrameJacobian(model, data, fid, pin.LOCAL)[rows[k]] @ B[i]
        return tuple(out)

    def frame_poses(self, q, frames: tuple[str, ...]) -> np.ndarray:
        """World placements (T, len(frames), 4, 4) of named frames (for plots and simulators)."""
        qp = self.configuration(q)
        model, data = self.pinocchio_model, self._data
        ids = [model.getFrameId(f) for f in frames]
        out = np.empty((qp.shape[0], len(ids), 4, 4))
        for i, qi in enumerate(qp):
            pin.framesForwardKinematics(model, data, qi)
            for k, fid in enumerate(ids):
                out[i, k] = data.oMf[fid].homogeneous
        return out

    # --- Model protocol -------------------------------------------------------------------------
    def metric(self, q) -> AffineMetric:
        """D(q, θ) at T configurations, in factored form."""
        J = self.body_jacobians(q)
        T = self.check_configuration(q).shape[0]
        terms, start = [], 0
        for b, Jb in zip(self.spec.bodies, J):
            k = len(b.pairs)
            E = diagonal_basis(b.size) if b.form == "diagonal" else symmetric_basis(b.size)
            terms.append(MetricTerm(tuple(range(start, start + k)), E, Jb))
            start += k
        for iv in self._damped:
            Jj = np.zeros((T, 1, self.n))
            Jj[:, 0, iv] = 1.0
            terms.append(MetricTerm((start,), np.ones((1, 1, 1)), Jj))
            start += 1
        return AffineMetric(self.parameters.p, tuple(terms))

    def regressor(self, q, v, a=None) -> np.ndarray:
        """Y (T, n, p) with Y θ = D(q, θ) v: the columns D_k(q) v of the metric; a is ignored."""
        q = self.check_configuration(q)
        v = np.atleast_2d(np.asarray(v, dtype=float))
        if v.shape != q.shape:
            raise DataError(f"drag model velocities: expected shape {q.shape}, got {v.shape}")
        return self.metric(q).apply(v)

    def bias_regressor(self, q, v) -> np.ndarray:
        """Zeros (T, n, p): no force at zero velocity."""
        q = self.check_configuration(q)
        return np.zeros((q.shape[0], self.n, self.parameters.p))

    def drag_matrices(self, theta) -> dict[str, np.ndarray]:
        """C_b(θ_b) per body, (size, size) in its frame's components."""
        theta = np.asarray(theta, dtype=float)
        out = {}
        for blk, b in zip(self.parameters.blocks, self.spec.bodies):
            C = np.zeros((b.size, b.size))
            for k, (i, j) in zip(blk.indices, b.pairs):
                C[i, j] = C[j, i] = theta[k]
            out[b.name] = C
        return out
