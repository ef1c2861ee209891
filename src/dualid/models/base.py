"""What a model is to dualid: a regressor and an affine metric over a parameter space.

A model maps a trajectory (q, v, a, τ) to an identification problem. Rigid-body models come from
Pinocchio (any URDF), drag models from body Jacobians and drag blocks; both satisfy ``Model``.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from dualid.problem.metric import AffineMetric
from dualid.problem.parameters import ParameterSpace
from dualid.problem.problem import IdentificationProblem, Kind
from dualid.trajectories.trajectory import Trajectory


@runtime_checkable
class Model(Protocol):
    kind: Kind  # "inertia": τ = M(q)a + h(q, v); "drag": τ = M(q)v
    parameters: ParameterSpace
    coordinates: tuple[str, ...]  # names of the n velocity coordinates

    def regressor(self, q: np.ndarray, v: np.ndarray, a: np.ndarray | None) -> np.ndarray:
        """Y (T, n, p) with τ = Y θ."""

    def bias_regressor(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Y_h (T, n, p) with h(q, v) = Y_h θ: the force at zero acceleration (zeros for drag models)."""

    def metric(self, q: np.ndarray) -> AffineMetric:
        """M(q, θ) at T configurations."""


def build_problem(model: Model, trajectories: list[Trajectory] | Trajectory) -> IdentificationProblem:
    """The identification problem of a model over one or several trajectories."""
    if isinstance(trajectories, Trajectory):
        trajectories = [trajectories]
    problems = []
    for traj in trajectories:
        if model.kind == "inertia" and traj.a is None:
            raise ValueError(
                f"trajectory {traj.name!r} has no accelerations; an inertia-dominated model needs them "
                "(differentiate the velocities first, see dualid.trajectories.preprocessing)"
            )
        problems.append(
            IdentificationProblem(
                Y=model.regressor(traj.q, traj.v, traj.a),
                tau=traj.tau,
                metric=model.metric(traj.q),
                v=traj.v,
                parameters=model.parameters,
                kind=model.kind,
                coordinates=model.coordinates,
            )
        )
    return IdentificationProblem.concatenate(problems)
