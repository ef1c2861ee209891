"""Metric guards attached to a finished fit: ``with_guard`` and the ``Guarded`` wrapper.

The measure itself (generalised eigenvalues of M_i(θ̂) against M_i(θ_ref), ``guard_info``) lives in
``dualid.metric_guard``, which every estimator uses to record its own guard during its fit.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from dualid.errors import ConfigError
from dualid.estimators.result import IdentificationResult
from dualid.metric_guard import DEFAULT_BOUND, check_bound, guard_info
from dualid.problem import IdentificationProblem


def with_guard(
    result: IdentificationResult,
    problem: IdentificationProblem,
    theta_ref: np.ndarray,
    bound: float = DEFAULT_BOUND,
    reference: str = "",
) -> IdentificationResult:
    """A copy of ``result`` whose info carries the metric guard against θ_ref (see ``guard_info``)."""
    info = dict(result.info)
    info.update(guard_info(problem, result.theta, theta_ref, bound, reference))
    return dataclasses.replace(result, info=info)


@dataclass(frozen=True)
class Guarded:
    """Any estimator, with its result carrying the metric guard against a reference fit.

    reference: an estimator whose fit is the reference θ (default: covariance WLS under the same
    constraints), or a fixed θ_ref given as a tuple (e.g. the prior). The reference's own fit is
    recorded in the result (``metric_guard_reference``).
    """

    estimator: object
    reference: object = None  # an estimator with .fit, a tuple θ_ref, or None (WLS)
    bound: float = DEFAULT_BOUND

    def __post_init__(self) -> None:
        if not hasattr(self.estimator, "fit"):
            raise ConfigError(f"Guarded: estimator must have a fit(problem) method, got {type(self.estimator).__name__}")
        check_bound(self.bound)
        ref = self.reference
        if ref is not None and not hasattr(ref, "fit"):
            ref = tuple(float(x) for x in np.asarray(ref, dtype=float).ravel())
            object.__setattr__(self, "reference", ref)

    @property
    def name(self) -> str:
        return getattr(self.estimator, "name", type(self.estimator).__name__)

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        result = self.estimator.fit(problem)
        if isinstance(self.reference, tuple):
            theta_ref, label = np.array(self.reference), "given θ_ref"
        else:
            from dualid.estimators.least_squares import WLS

            ref = self.reference if self.reference is not None else WLS(
                constrained=getattr(self.estimator, "constrained", True),
                allow_unidentifiable=getattr(self.estimator, "allow_unidentifiable", False),
            )
            theta_ref, label = ref.fit(problem).theta, getattr(ref, "name", type(ref).__name__)
        return with_guard(result, problem, theta_ref, self.bound, label)
