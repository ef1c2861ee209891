"""Put the chart-invariant margin C_b(θ) ⪰ ε·C_b(θ_ref) on a problem (see dualid.model.margin).

The margin lives in the problem's ParameterSpace, so every estimator fitted on the returned problem (OLS, WLS,
energy, logdet, pullback, dm, dm-paper with either solver, dm-bfp) applies it alike and records it in its
result's info (``margin_epsilon``, ``margin_reference``, ``margin_min_ratio``, ``margin_active``).

    problem = with_margin(problem, 0.1)                       # θ_ref: a constrained WLS pilot
    problem = with_margin(problem, 0.1, "prior", prior=θ0)    # θ_ref: the prior
"""

from __future__ import annotations

import dataclasses

import numpy as np

from dualid.errors import ConfigError, DualidError
from dualid.model.margin import check_margin
from dualid.problem import IdentificationProblem

REFERENCES = ("wls", "prior")


def margin_reference(problem: IdentificationProblem, reference="wls", prior=None) -> tuple[np.ndarray, str]:
    """(θ_ref, label): "wls" — a constrained WLS pilot on the problem without its margin (null space allowed);
    "prior" — the given prior θ₀; an array — that θ_ref."""
    if isinstance(reference, str):
        if reference == "prior":
            if prior is None:
                raise ConfigError("margin.reference: 'prior' needs a prior θ₀, and this fit has none")
            return np.asarray(prior, dtype=float), "prior"
        if reference != "wls":
            raise ConfigError(f"margin.reference: expected one of {REFERENCES} or a vector θ_ref, got {reference!r}")
        from dualid.estimators.least_squares import WLS

        plain = dataclasses.replace(problem, parameters=problem.parameters.without_margin())
        try:
            pilot = WLS(allow_unidentifiable=True).fit(plain)
        except DualidError as exc:
            raise ConfigError(f"margin.reference: the WLS pilot failed ({type(exc).__name__}: {exc})") from exc
        return pilot.theta, "wls pilot"
    return np.asarray(reference, dtype=float), "given θ_ref"


def with_margin(problem: IdentificationProblem, epsilon: float, reference="wls", prior=None) -> IdentificationProblem:
    """The problem with the margin C_b(θ) ⪰ ε·C_b(θ_ref) on every constrained block (ConfigError on bad input)."""
    check_margin(problem.parameters, np.zeros(problem.p), epsilon)  # ε first: before any pilot fit
    theta_ref, label = margin_reference(problem, reference, prior)
    parameters = problem.parameters.with_margin(theta_ref, epsilon, label)
    return dataclasses.replace(problem, parameters=parameters)
