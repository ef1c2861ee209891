"""Joint friction and armature added to any model: τ_j += b_j v_j + fc_j tanh(v_j / v_c) + Ia_j a_j.

θ = [θ_model, b (viscous, N m s/rad), fc (Coulomb, N m), Ia (armature / reflected rotor inertia,
kg m²)] for the chosen joint coordinates j (each group present only when asked for). The smooth sign
tanh(v / v_c) with v_c = ``coulomb_velocity`` [rad/s] stands in for sign(v). Armature adds Ia_j to the
diagonal of the mass matrix: one metric term J = e_jᵀ (d = 1) per joint.

Inertia models only: in a drag model τ = M(q) v has no acceleration or Coulomb term to carry these.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from dualid.errors import ModelError
from dualid.model.base import Kind, Model
from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.parameters import ParameterBlock, ParameterSpace


@dataclass(frozen=True, eq=False)
class JointTermsModel:
    """``base`` plus per-joint viscous/Coulomb friction and armature (see the module docstring)."""

    base: Model
    dofs: tuple[int, ...]  # indices into base.coordinates of the joints that get the terms
    viscous: bool = True
    coulomb: bool = True
    armature: bool = True  # the same default as the fit config (reflected rotor inertia of geared joints)
    coulomb_velocity: float = 0.01  # v_c [rad/s or m/s] of the smooth sign tanh(v / v_c)
    kind: ClassVar[Kind] = "inertia"
    parameters: ParameterSpace = field(init=False)
    coordinates: tuple[str, ...] = field(init=False)
    _offsets: dict = field(init=False, repr=False)  # group name -> first index in θ

    def __post_init__(self) -> None:
        if self.base.kind != "inertia":
            raise ModelError(
                f"with_joint_terms: expected an inertia-dominated model, got kind {self.base.kind!r} "
                "(a drag model's joint damping belongs in its drag matrix)"
            )
        if not (self.viscous or self.coulomb or self.armature):
            raise ModelError("with_joint_terms: choose at least one of viscous, coulomb, armature")
        if not (np.isfinite(self.coulomb_velocity) and self.coulomb_velocity > 0):
            raise ModelError(f"with_joint_terms: coulomb_velocity must be > 0, got {self.coulomb_velocity!r}")
        n = len(self.base.coordinates)
        dofs = tuple(int(j) for j in self.dofs)
        if not dofs:
            raise ModelError("with_joint_terms: no joint selected")
        if len(set(dofs)) != len(dofs) or any(not 0 <= j < n for j in dofs):
            raise ModelError(f"with_joint_terms: dofs must be distinct indices in 0..{n - 1}, got {dofs}")
        names = [self.base.coordinates[j] for j in dofs]
        p0 = self.base.parameters.p
        groups = [
            (flag, label, suffix, unit)
            for flag, label, suffix, unit in (
                (self.viscous, "viscous", "b", "N m s/rad"),
                (self.coulomb, "coulomb", "fc", "N m"),
                (self.armature, "armature", "Ia", "kg m^2"),
            )
            if flag
        ]
        extra_names, extra_units, blocks = [], [], []
        for g, (_, label, suffix, unit) in enumerate(groups):
            extra_names += [f"{c}.{suffix}" for c in names]
            extra_units += [unit] * len(names)
            blocks.append(ParameterBlock(label, "nonnegative", tuple(range(g * len(names), (g + 1) * len(names)))))
        extra = ParameterSpace(tuple(extra_names), tuple(extra_units), tuple(blocks))
        object.__setattr__(self, "dofs", dofs)
        object.__setattr__(self, "parameters", self.base.parameters.concatenate(extra))
        object.__setattr__(self, "coordinates", tuple(self.base.coordinates))
        object.__setattr__(self, "_offsets", {label: p0 + g * len(dofs) for g, (_, label, _, _) in enumerate(groups)})

    def index(self, group: str) -> np.ndarray:
        """Indices in θ of one group ("viscous", "coulomb", "armature"), in the order of ``dofs``."""
        if group not in self._offsets:
            raise ModelError(f"no {group!r} parameters in this model; it has {list(self._offsets)}")
        return self._offsets[group] + np.arange(len(self.dofs))

    def _group_values(self, theta: np.ndarray, group: str) -> np.ndarray:
        """A group's values; a constrained fit may sit a rounding error (1e-9 relative) below 0,
        which reads as 0; anything more negative is returned as it is (and the URDF writer refuses it)."""
        x = np.asarray(theta, dtype=float)[self.index(group)]
        tol = 1e-9 * max(1.0, float(np.max(np.abs(x))) if x.size else 1.0)
        return np.where((x < 0) & (x >= -tol), 0.0, x)

    def friction(self, theta: np.ndarray) -> dict[str, tuple[float, float]]:
        """{joint: (viscous b [N m s/rad], Coulomb fc [N m])} from θ (0 for a term the model lacks)."""
        zero = np.zeros(len(self.dofs))
        b = self._group_values(theta, "viscous") if self.viscous else zero
        fc = self._group_values(theta, "coulomb") if self.coulomb else zero
        return {self.coordinates[j]: (float(b[k]), float(fc[k])) for k, j in enumerate(self.dofs)}

    def armature_values(self, theta: np.ndarray) -> dict[str, float]:
        """{joint: armature Ia [kg m²]} from θ (empty when the model has no armature terms)."""
        if not self.armature:
            return {}
        Ia = self._group_values(theta, "armature")
        return {self.coordinates[j]: float(Ia[k]) for k, j in enumerate(self.dofs)}

    def _joint_columns(self, v: np.ndarray, a: np.ndarray | None) -> np.ndarray:
        """(T, n, p_extra): the friction (and armature when a is given) regressor columns."""
        T, n = v.shape
        k = len(self.dofs)
        p0 = self.base.parameters.p
        Y = np.zeros((T, n, self.parameters.p - p0))
        rows = np.asarray(self.dofs)
        cols = np.arange(k)
        if self.viscous:
            Y[:, rows, self._offsets["viscous"] - p0 + cols] = v[:, rows]
        if self.coulomb:
            Y[:, rows, self._offsets["coulomb"] - p0 + cols] = np.tanh(v[:, rows] / self.coulomb_velocity)
        if self.armature and a is not None:
            Y[:, rows, self._offsets["armature"] - p0 + cols] = a[:, rows]
        return Y

    def regressor(self, q: np.ndarray, v: np.ndarray, a: np.ndarray | None) -> np.ndarray:
        """Y (T, n, p) = [Y_base, v_j, tanh(v_j / v_c), a_j]."""
        Y0 = self.base.regressor(q, v, a)
        v2 = np.asarray(v, dtype=float).reshape(Y0.shape[0], -1)
        a2 = None if a is None else np.asarray(a, dtype=float).reshape(Y0.shape[0], -1)
        return np.concatenate([Y0, self._joint_columns(v2, a2)], axis=2)

    def bias_regressor(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Y_h (T, n, p): h includes the friction forces; armature multiplies a, so its columns are 0."""
        Y0 = self.base.bias_regressor(q, v)
        v2 = np.asarray(v, dtype=float).reshape(Y0.shape[0], -1)
        return np.concatenate([Y0, self._joint_columns(v2, None)], axis=2)

    def metric(self, q: np.ndarray) -> AffineMetric:
        """M(q, θ) = M_base(q, θ_base) + diag(Ia) on the selected joints."""
        M = self.base.metric(q).with_n_params(self.parameters.p)
        if not self.armature:
            return M
        N, n = M.shape
        eye = np.eye(n)
        terms = tuple(
            MetricTerm((int(i),), np.ones((1, 1, 1)), np.broadcast_to(eye[j][None, None, :], (N, 1, n)))
            for i, j in zip(self.index("armature"), self.dofs)
        )
        return M.plus(AffineMetric(self.parameters.p, terms))


def with_joint_terms(
    model: Model,
    viscous: bool = True,
    coulomb: bool = True,
    armature: bool = True,
    joints: list[str] | tuple[str, ...] | None = None,
    coulomb_velocity: float = 0.01,
) -> JointTermsModel:
    """``model`` with per-joint friction (and armature) parameters appended to θ.

    ``joints`` selects coordinates by name (``model.coordinates``); by default every coordinate that
    is not part of a floating base (``model.base_coordinates`` when the model has it, e.g. a
    RigidBodyModel with a free-flyer root).
    """
    coordinates = tuple(model.coordinates)
    if joints is None:
        base = set(getattr(model, "base_coordinates", ()))
        dofs = tuple(j for j, c in enumerate(coordinates) if c not in base)
    else:
        if isinstance(joints, str):
            joints = [joints]
        unknown = [name for name in joints if name not in coordinates]
        if unknown:
            raise ModelError(f"with_joint_terms: unknown joints {unknown}; valid joints are {list(coordinates)}")
        dofs = tuple(coordinates.index(name) for name in joints)
    return JointTermsModel(model, dofs, viscous, coulomb, armature, coulomb_velocity)
