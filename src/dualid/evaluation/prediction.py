"""Forward dynamics from an identified model, from measured states and inputs.

inertia-dominated:  a = M̂(q)⁻¹ (τ − ĥ(q, v)),  ĥ = Y(q, v, 0) θ̂
drag-dominated:     v = M̂(q)⁻¹ τ
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.data.trajectory import Trajectory
from dualid.errors import DataError, MetricError
from dualid.model.base import Model
from dualid.model.metric import AffineMetric


@dataclass(frozen=True, eq=False)
class PredictionData:
    """What forward dynamics needs from a run that does not depend on θ: M(q, ·), Y_h(q, v) and τ.

    Build it once per run (``of``), then ``predict(θ)`` for every identified model: the Pinocchio
    passes behind the metric and the bias regressor are not repeated per fit.
    """

    kind: str  # "inertia" | "drag"
    metric: AffineMetric  # M(q_i, θ), T samples
    Y_h: np.ndarray | None  # (T, n, p) bias regressor (inertia), None for drag
    tau: np.ndarray  # (T, n)

    @staticmethod
    def of(model: Model, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> "PredictionData":
        Y_h = model.bias_regressor(q, v) if model.kind == "inertia" else None
        return PredictionData(model.kind, model.metric(q), Y_h, np.asarray(tau, dtype=float))

    def predict(self, theta: np.ndarray) -> np.ndarray:
        """Predicted accelerations (inertia) or velocities (drag), (T, n)."""
        theta = np.asarray(theta, dtype=float)
        M = self.metric.evaluate(theta)
        rhs = self.tau if self.Y_h is None else self.tau - self.Y_h @ theta
        try:
            L = np.linalg.cholesky(M)
        except np.linalg.LinAlgError:
            lam = np.linalg.eigvalsh(M)[:, 0]
            raise MetricError(
                f"forward dynamics: M(q, θ) is not positive definite at {int(np.sum(lam <= 0))} of {len(lam)} "
                f"samples (smallest eigenvalue {lam.min():.3g}); the identified model cannot be simulated there"
            ) from None
        z = np.linalg.solve(L, rhs[..., None])
        return np.linalg.solve(np.swapaxes(L, 1, 2), z)[..., 0]


def forward_dynamics(model: Model, theta: np.ndarray, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Predicted accelerations (inertia) or velocities (drag), (T, n)."""
    return PredictionData.of(model, q, v, tau).predict(theta)


def predict(model: Model, theta: np.ndarray, trajectory: Trajectory) -> np.ndarray:
    """The model's prediction of the measured signal of a run: a for inertia, v for drag models."""
    return forward_dynamics(model, theta, trajectory.q, trajectory.v, trajectory.tau)


def measured_signal(model: Model, trajectory: Trajectory) -> np.ndarray:
    """The signal forward dynamics predicts: accelerations (inertia) or velocities (drag)."""
    if model.kind == "inertia":
        if trajectory.a is None:
            raise DataError(f"trajectory {trajectory.name!r} has no accelerations to compare with")
        return trajectory.a
    return trajectory.v
