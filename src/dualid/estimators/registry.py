"""Estimators by name, as the CLI, the config files and the studies spell them."""

from __future__ import annotations

import numpy as np

from dualid.estimators.dual_metric import DualMetric
from dualid.estimators.least_squares import OLS, WLS, EnergyLS, RegularizedWLS

METHODS = ("ols", "wls", "energy", "logdet", "pullback", "dm", "dm-paper", "dm-gls", "dm-bfp")
# "dm" is still the paper's objective here; issue 11 will map it to "dm-gls" once the statistical
# benchmark has chosen the default. "dm-paper" keeps the paper's objective by name either way.


def make_estimator(
    method: str,
    *,
    theta0: np.ndarray | None = None,
    gamma: float = 1.0,
    per_equation: bool = False,
    constrained: bool = True,
    allow_unidentifiable: bool = False,
):
    """The estimator called ``method``; logdet/pullback need the nominal θ₀ and the prior weight γ
    (absolute, or per equation when per_equation=True, see RegularizedWLS)."""
    common = {"constrained": constrained, "allow_unidentifiable": allow_unidentifiable}
    if method == "ols":
        return OLS(**common)
    if method == "wls":
        return WLS(**common)
    if method == "energy":
        return EnergyLS(**common)
    if method in ("logdet", "pullback"):
        return RegularizedWLS(theta0=theta0, gamma=gamma, regularizer=method, per_equation=per_equation, **common)
    if method in ("dm", "dm-paper"):
        return DualMetric(**common)
    if method == "dm-gls":
        from dualid.estimators.gls import FeasibleGLS

        return FeasibleGLS(**common)
    if method == "dm-bfp":
        from dualid.estimators.fixed_point import BoundedFixedPoint

        return BoundedFixedPoint(**common)
    raise ValueError(f"unknown method {method!r}; known methods: {', '.join(METHODS)}")
