"""Rigid-body trees from Pinocchio (any URDF): τ = Y(q, v, a) θ and M(q, θ) = Σ_b J_bᵀ G_b(θ_b) J_b.

θ holds 10 inertial parameters per moving joint's body (Pinocchio merges links welded by fixed
joints into their parent joint's body), in Pinocchio's order [m, mc_x, mc_y, mc_z, Ixx, Ixy, Iyy,
Ixz, Iyz, Izz], expressed in the joint frame (inertia about the joint-frame origin).

- Y is Pinocchio's joint-torque regressor (``computeJointTorqueRegressor``), stacked over samples.
- J_b is the body's 6×nv Jacobian in its own (LOCAL) frame, G_b = Σ_k θ_bk E_k its 6×6 spatial
  inertia in the [linear; angular] order Pinocchio uses; E (10, 6, 6) is ``spatial_inertia_basis()``.
- A free-flyer root has velocity coordinates (vx, vy, vz, wx, wy, wz): the body velocity of the root
  (Pinocchio's LOCAL free-flyer convention); its generalized forces are the body wrench.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import ClassVar

import numpy as np
import pinocchio as pin

from dualid.data.lie import BASE_COORDINATES
from dualid.errors import DataError, MissingFileError, ModelError
from dualid.model.base import Kind
from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.parameters import ParameterSpace, rigid_body_space
from dualid.model.urdf_check import urdf_for_pinocchio

FREE_FLYER_COORDINATES = BASE_COORDINATES  # one home: data.lie


@lru_cache(maxsize=1)
def spatial_inertia_basis() -> np.ndarray:
    """E (10, 6, 6): the spatial inertia G(θ) = Σ_k θ_k E_k, [linear; angular] order, θ in Pinocchio's order.

    Derived from Pinocchio itself by linearity (G is linear in the dynamic parameters), around a
    valid inertia, and rounded to the exact entries (0, ±1), checked against the derivation.
    """
    theta0 = np.array([1.0, 0.1, -0.2, 0.3, 2.0, 0.1, 2.5, -0.2, 0.15, 3.0])  # a valid body
    G0 = pin.Inertia.FromDynamicParameters(theta0).matrix()
    E = np.empty((10, 6, 6))
    for k in range(10):
        Gk = pin.Inertia.FromDynamicParameters(theta0 + np.eye(10)[k]).matrix()
        E[k] = Gk - G0
    exact = np.round(E)
    if np.abs(exact - E).max() > 1e-9:  # pragma: no cover - guards a change in Pinocchio's conventions
        raise ModelError("spatial_inertia_basis: Pinocchio's spatial inertia is not linear in the parameters")
    exact.setflags(write=False)
    return exact


def _joint_coordinates(model: pin.Model) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(velocity coordinate names, the free-flyer root's names or ())."""
    names: list[str] = []
    base: tuple[str, ...] = ()
    for j in range(1, model.njoints):
        joint = model.joints[j]
        name = model.names[j]
        if j == 1 and joint.shortname() == "JointModelFreeFlyer":
            names += FREE_FLYER_COORDINATES
            base = FREE_FLYER_COORDINATES
        elif joint.nv == 1:
            names.append(name)
        else:
            names += [f"{name}_{k}" for k in range(joint.nv)]
    return tuple(names), base


def _as_samples(x, width: int, label: str) -> np.ndarray:
    """(T, width) float array from (T, width) or a single sample (width,)."""
    arr = np.asarray(x, dtype=float)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != width:
        raise DataError(f"{label}: expected shape (T, {width}) or ({width},), got {np.shape(x)}")
    if not np.all(np.isfinite(arr)):
        raise DataError(f"{label}: contains non-finite values")
    return arr


@dataclass(frozen=True, eq=False)
class RigidBodyModel:
    """A Pinocchio kinematic tree as a dualid ``Model`` (kind "inertia").

    The wrapped ``pin.Model`` is copied; ``gravity`` (3,) [m/s²] overrides its gravity when given
    (Pinocchio's default is (0, 0, −9.81)); use ``with_gravity`` for a copy with another one.
    """

    model: pin.Model
    gravity: tuple[float, float, float] | None = None
    kind: ClassVar[Kind] = "inertia"
    parameters: ParameterSpace = field(init=False)
    coordinates: tuple[str, ...] = field(init=False)  # n = nv velocity coordinate names
    base_coordinates: tuple[str, ...] = field(init=False)  # the free-flyer root's, or ()
    bodies: tuple[str, ...] = field(init=False)  # one per moving joint (joint names)
    _data: pin.Data = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.model, pin.Model):
            raise ModelError(f"RigidBodyModel: expected a pinocchio.Model, got {type(self.model).__name__}")
        model = pin.Model(self.model)  # our own copy: the caller's model may change later
        if self.gravity is not None:
            g = np.asarray(self.gravity, dtype=float)
            if g.shape != (3,) or not np.all(np.isfinite(g)):
                raise ModelError(f"RigidBodyModel: gravity must be 3 finite numbers [m/s²], got {self.gravity!r}")
            model.gravity = pin.Motion(g, np.zeros(3))
            object.__setattr__(self, "gravity", tuple(float(x) for x in g))
        else:
            object.__setattr__(self, "gravity", tuple(float(x) for x in model.gravity.linear))
        if model.njoints < 2:
            raise ModelError("RigidBodyModel: the model has no moving joint, so nothing to identify")
        bodies = tuple(model.names[j] for j in range(1, model.njoints))
        coordinates, base = _joint_coordinates(model)
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "bodies", bodies)
        object.__setattr__(self, "coordinates", coordinates)
        object.__setattr__(self, "base_coordinates", base)
        object.__setattr__(self, "parameters", rigid_body_space(bodies))
        object.__setattr__(self, "_data", model.createData())

    # --- construction -----------------------------------------------------------------------
    @classmethod
    def from_urdf(cls, path: str | Path, floating_base: bool = False, gravity=None) -> "RigidBodyModel":
        """The rigid-body model of a URDF; ``floating_base`` adds a free-flyer root joint."""
        path = Path(path)
        if not path.is_file():
            raise MissingFileError(f"RigidBodyModel.from_urdf: no URDF file at {path}")
        root_joint = (pin.JointModelFreeFlyer(),) if floating_base else ()
        xml = urdf_for_pinocchio(path)  # values checked first; an implicit world declared, massless frames
        try:
            if xml is None:
                model = pin.buildModelFromUrdf(str(path), *root_joint)
            elif floating_base:
                model = pin.buildModelFromXML(xml, pin.JointModelFreeFlyer())
            else:
                model = pin.buildModelFromXML(xml)
        except (RuntimeError, ValueError) as exc:  # urdfdom / Pinocchio refuse what read_urdf let through
            raise ModelError(f"{path}: Pinocchio could not build a model from this URDF: {exc}") from None
        return cls(model, gravity)

    def with_gravity(self, gravity) -> "RigidBodyModel":
        """A copy with gravity (3,) [m/s²]."""
        return dataclasses.replace(self, gravity=gravity)

    # --- sizes and nominal values -----------------------------------------------------------
    @property
    def nq(self) -> int:
        return self.model.nq

    @property
    def nv(self) -> int:
        return self.model.nv

    def configuration(self, q) -> np.ndarray:
        """Pinocchio's configuration (T, nq) from q as logged: either already (T, nq), or the angle form
        (T, nq − k) with one angle [rad] per continuous joint (Pinocchio stores those k joints as
        (cos, sin) pairs, so nq = nv + k without a free flyer)."""
        q = np.asarray(q, dtype=float)
        unbounded = [j for j in range(1, self.model.njoints) if "RUB" in self.model.joints[j].shortname()
                     or "RevoluteUnbounded" in self.model.joints[j].shortname()]
        width = q.shape[-1] if q.ndim in (1, 2) else None
        if not unbounded or width == self.nq:
            return _as_samples(q, self.nq, "q")
        angle_width = self.nq - len(unbounded)
        if width != angle_width:
            raise DataError(
                f"q: expected shape (T, {self.nq}) (Pinocchio's configuration) or (T, {angle_width}) (one angle per "
                f"continuous joint), got {np.shape(q)}")
        q = _as_samples(q, angle_width, "q")
        out = np.empty((q.shape[0], self.nq))
        src = 0
        for j in range(1, self.model.njoints):
            joint = self.model.joints[j]
            if j in unbounded:
                out[:, joint.idx_q] = np.cos(q[:, src])
                out[:, joint.idx_q + 1] = np.sin(q[:, src])
                src += 1
            else:
                out[:, joint.idx_q:joint.idx_q + joint.nq] = q[:, src:src + joint.nq]
                src += joint.nq
        return out

    @property
    def nominal(self) -> np.ndarray:
        """θ (10·nbodies,) from the model's inertias (e.g. the URDF's)."""
        return np.concatenate(
            [self.model.inertias[j].toDynamicParameters() for j in range(1, self.model.njoints)]
        )

    # --- Model protocol ---------------------------------------------------------------------
    def regressor(self, q: np.ndarray, v: np.ndarray, a: np.ndarray | None) -> np.ndarray:
        """Y (T, nv, 10·nbodies) with τ = Y θ [N or N m per unit parameter]."""
        if a is None:
            raise DataError(
                "RigidBodyModel.regressor: accelerations a are required (use bias_regressor for a = 0)"
            )
        q = self.configuration(q)
        v = _as_samples(v, self.nv, "v")
        a = _as_samples(a, self.nv, "a")
        if not q.shape[0] == v.shape[0] == a.shape[0]:
            raise DataError(f"regressor: q, v, a have {q.shape[0]}, {v.shape[0]}, {a.shape[0]} samples")
        Y = np.empty((q.shape[0], self.nv, self.parameters.p))
        model, data = self.model, self._data
        for t in range(q.shape[0]):
            Y[t] = pin.computeJointTorqueRegressor(model, data, q[t], v[t], a[t])
        return Y

    def bias_regressor(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Y_h (T, nv, p): h(q, v) = Y(q, v, 0) θ (Coriolis, centrifugal and gravity forces)."""
        v = _as_samples(v, self.nv, "v")
        return self.regressor(q, v, np.zeros_like(v))

    def jacobians(self, q: np.ndarray) -> np.ndarray:
        """J (T, nbodies, 6, nv): each body's Jacobian in its own frame (LOCAL), [linear; angular]."""
        q = self.configuration(q)
        model, data = self.model, self._data
        nb = model.njoints - 1
        J = np.empty((q.shape[0], nb, 6, self.nv))
        for t in range(q.shape[0]):
            pin.computeJointJacobians(model, data, q[t])
            for b in range(nb):
                J[t, b] = pin.getJointJacobian(model, data, b + 1, pin.LOCAL)
        return J

    def metric(self, q: np.ndarray) -> AffineMetric:
        """M(q, θ) = Σ_b J_bᵀ G_b(θ_b) J_b at T configurations (one term per body)."""
        J = self.jacobians(q)
        E = spatial_inertia_basis()
        terms = tuple(
            MetricTerm(block.indices, E, J[:, b]) for b, block in enumerate(self.parameters.blocks)
        )
        return AffineMetric(self.parameters.p, terms)
