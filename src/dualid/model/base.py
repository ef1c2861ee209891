"""What a model is to dualid: a regressor and an affine metric over a parameter space.

A model maps a trajectory (q, v, a, τ) to an identification problem. Rigid-body models come from
Pinocchio (any URDF), drag models from body Jacobians and drag blocks; both satisfy ``Model``.
"""

from __future__ import annotations

from typing import Literal, Protocol, runtime_checkable

import numpy as np

from dualid.model.metric import AffineMetric
from dualid.model.parameters import ParameterSpace

Kind = Literal["inertia", "drag"]


@runtime_checkable
class Model(Protocol):
    @property
    def kind(self) -> Kind:
        """"inertia": τ = M(q)a + h(q, v); "drag": τ = M(q)v."""

    @property
    def parameters(self) -> ParameterSpace: ...

    @property
    def coordinates(self) -> tuple[str, ...]:
        """Names of the n velocity coordinates."""

    def regressor(self, q: np.ndarray, v: np.ndarray, a: np.ndarray | None) -> np.ndarray:
        """Y (T, n, p) with τ = Y θ."""

    def bias_regressor(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Y_h (T, n, p) with h(q, v) = Y_h θ: the force at zero acceleration (zeros for drag models)."""

    def metric(self, q: np.ndarray) -> AffineMetric:
        """M(q, θ) at T configurations."""
