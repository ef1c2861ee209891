"""Model error the user can model: extra affine terms in the inverse dynamics, metric unchanged.

    τ = Y_base(q, v, a) θ_base + Σ_t F_t(q, v) θ_t          M(q, θ) = M_base(q, θ_base)

Each term contributes columns F_t (T, n, k_t) with its own parameter block (constraint kind as in
``dualid.model.parameters``); terms depend on the state only (no acceleration), so they belong
to the bias force h too, and the metric — the kinetic energy — is the base model's.

``LinearBaseDrag``: a floating base's linear drag, the force −d ⊙ v_lin acting on the base body
(its velocity rows vx, vy, vz are the body-frame linear velocity, Pinocchio's LOCAL free-flyer
convention). In the inverse dynamics the actuators must also overcome it, so τ_lin gains +d ⊙ v_lin:
3 parameters d ≥ 0 [N s/m]. The Crazyflie's rotor drag is of this form (systems/crazyflie.py
applies exactly −drag ⊙ v_lin on the base).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from dualid.errors import ModelError
from dualid.model.base import Model
from dualid.model.metric import AffineMetric
from dualid.model.parameters import ParameterBlock, ParameterSpace


class ExtraTerm(Protocol):
    names: tuple[str, ...]  # parameter names (k,)
    units: tuple[str, ...]  # (k,)
    block_kind: str  # "nonnegative", "free", ...

    def bind(self, coordinates: tuple[str, ...]) -> None:
        """Check the term applies to a model with these coordinates (raise ValueError if not)."""

    def columns(self, q: np.ndarray, v: np.ndarray, coordinates: tuple[str, ...]) -> np.ndarray:
        """F (T, n, k): the term's regressor columns."""


@dataclass(frozen=True)
class LinearBaseDrag:
    """τ[vx, vy, vz] += d ⊙ v_lin on a free-flyer base (d ≥ 0 [N s/m], the drag force is −d ⊙ v_lin)."""

    rows: tuple[str, str, str] = ("vx", "vy", "vz")  # the base's linear velocity coordinates
    prefix: str = "base_drag"
    block_kind = "nonnegative"

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(f"{self.prefix}.d_{c}" for c in self.rows)

    @property
    def units(self) -> tuple[str, ...]:
        return ("N s/m",) * len(self.rows)

    def bind(self, coordinates: tuple[str, ...]) -> None:
        missing = [c for c in self.rows if c not in coordinates]
        if missing:
            raise ModelError(
                f"LinearBaseDrag: expected a floating-base model with linear velocity coordinates {self.rows}, "
                f"but {missing} are not among the model's coordinates {list(coordinates)}"
            )

    def columns(self, q: np.ndarray, v: np.ndarray, coordinates: tuple[str, ...]) -> np.ndarray:
        T, n = v.shape
        F = np.zeros((T, n, len(self.rows)))
        for k, c in enumerate(self.rows):
            j = coordinates.index(c)
            F[:, j, k] = v[:, j]
        return F


@dataclass(frozen=True, eq=False)
class ExtraTermsModel:
    """``base`` with extra affine terms in its inverse dynamics (module docstring); metric unchanged."""

    base: Model
    terms: tuple
    parameters: ParameterSpace = field(init=False)
    coordinates: tuple[str, ...] = field(init=False)
    kind: str = field(init=False)

    def __post_init__(self) -> None:
        if self.base.kind != "inertia":
            raise ModelError(
                f"ExtraTermsModel: expected an inertia-dominated model, got kind {self.base.kind!r} "
                "(a drag model's extra dissipation belongs in its drag matrix)"
            )
        terms = tuple(self.terms)
        if not terms:
            raise ModelError("ExtraTermsModel: expected at least one extra term, got none")
        coords = tuple(self.base.coordinates)
        names, units, blocks, k0 = [], [], [], 0
        for t in terms:
            t.bind(coords)
            k = len(t.names)
            names += list(t.names)
            units += list(t.units)
            blocks.append(ParameterBlock(t.names[0].split(".")[0], t.block_kind, tuple(range(k0, k0 + k))))
            k0 += k
        extra = ParameterSpace(tuple(names), tuple(units), tuple(blocks))
        object.__setattr__(self, "terms", terms)
        object.__setattr__(self, "parameters", self.base.parameters.concatenate(extra))
        object.__setattr__(self, "coordinates", coords)
        object.__setattr__(self, "kind", self.base.kind)
        if hasattr(self.base, "base_coordinates"):
            object.__setattr__(self, "base_coordinates", self.base.base_coordinates)

    @property
    def extra_indices(self) -> np.ndarray:
        """Indices in θ of the extra terms' parameters."""
        return np.arange(self.base.parameters.p, self.parameters.p)

    def _columns(self, q, v, T: int) -> np.ndarray:
        v2 = np.asarray(v, dtype=float).reshape(T, -1)
        q2 = np.asarray(q, dtype=float).reshape(T, -1)
        return np.concatenate([t.columns(q2, v2, self.coordinates) for t in self.terms], axis=2)

    def regressor(self, q: np.ndarray, v: np.ndarray, a: np.ndarray | None) -> np.ndarray:
        Y0 = self.base.regressor(q, v, a)
        return np.concatenate([Y0, self._columns(q, v, Y0.shape[0])], axis=2)

    def bias_regressor(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        Y0 = self.base.bias_regressor(q, v)
        return np.concatenate([Y0, self._columns(q, v, Y0.shape[0])], axis=2)

    def metric(self, q: np.ndarray) -> AffineMetric:
        return self.base.metric(q).with_n_params(self.parameters.p)

    def __getattr__(self, name):  # nominal, nq, nv, … of the base model
        if name in ("base", "terms", "parameters", "coordinates", "kind", "nominal") or name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.base, name)


def with_base_drag(model: Model, rows: tuple[str, str, str] = ("vx", "vy", "vz")) -> ExtraTermsModel:
    """``model`` (a floating-base rigid-body model) with 3 linear base-drag parameters d ≥ 0 appended to θ."""
    return ExtraTermsModel(model, (LinearBaseDrag(tuple(rows)),))
