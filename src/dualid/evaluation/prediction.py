"""Forward dynamics from an identified model, from measured states and inputs.

inertia-dominated:  a = M̂(q)⁻¹ (τ − ĥ(q, v)),  ĥ = Y(q, v, 0) θ̂
drag-dominated:     v = M̂(q)⁻¹ τ
"""

from __future__ import annotations

import numpy as np

from dualid.errors import MetricError
from dualid.models.base import Model
from dualid.trajectories.trajectory import Trajectory


def forward_dynamics(model: Model, theta: np.ndarray, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Predicted accelerations (inertia) or velocities (drag), (T, n)."""
    theta = np.asarray(theta, dtype=float)
    M = model.metric(q).evaluate(theta)
    rhs = np.array(tau, dtype=float)
    if model.kind == "inertia":
        rhs = rhs - model.bias_regressor(q, v) @ theta
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


def predict(model: Model, theta: np.ndarray, trajectory: Trajectory) -> np.ndarray:
    """The model's prediction of the measured signal of a run: a for inertia, v for drag models."""
    return forward_dynamics(model, theta, trajectory.q, trajectory.v, trajectory.tau)


def measured_signal(model: Model, trajectory: Trajectory) -> np.ndarray:
    """The signal forward dynamics predicts: accelerations (inertia) or velocities (drag)."""
    if model.kind == "inertia":
        if trajectory.a is None:
            raise ValueError(f"trajectory {trajectory.name!r} has no accelerations to compare with")
        return trajectory.a
    return trajectory.v
