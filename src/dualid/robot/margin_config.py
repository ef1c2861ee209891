"""The fit config's ``margin: {epsilon: 0.1, reference: wls | prior}`` (off when absent; CLI ``--margin EPS``).

Every method of the fit is then constrained by C_b(θ) ⪰ ε·C_b(θ_ref) on every body, drag block and non-negative
row (dualid.model.margin): M_i(θ̂) ⪰ ε·M_i(θ_ref) at every configuration. θ_ref is a constrained WLS pilot on the
training data ("wls", the default) or the prior (``prior.source``: the URDF's inertials with the joint terms
from OLS, or a previous fit).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from dualid.errors import ConfigError
from dualid.estimators.least_squares import REFERENCES, with_margin
from dualid.model.margin import check_margin
from dualid.model.parameters import ParameterSpace

_KEYS = ("epsilon", "reference")


@dataclass(frozen=True)
class MarginConfig:
    epsilon: float
    reference: str = "wls"  # "wls" | "prior"

    def __post_init__(self) -> None:
        check_margin(ParameterSpace((), ()), (), self.epsilon)
        if self.reference not in REFERENCES:
            raise ConfigError(f"margin.reference: expected one of {list(REFERENCES)}, got {self.reference!r}")

    def as_dict(self) -> dict:
        return {"epsilon": self.epsilon, "reference": self.reference}


def margin_option(d: Any) -> MarginConfig | None:
    """The config's ``margin`` value (None or absent: off; a bare number: ε against a WLS pilot)."""
    if d is None:
        return None
    if isinstance(d, (int, float)) and not isinstance(d, bool):
        return MarginConfig(float(d))
    if not isinstance(d, dict):
        raise ConfigError(f"margin: expected a mapping {{epsilon: 0.1, reference: wls}}, got {d!r}")
    unknown = [k for k in d if k not in _KEYS]
    if unknown:
        raise ConfigError(f"margin: unknown keys {unknown}; known keys: {list(_KEYS)}")
    if "epsilon" not in d:
        raise ConfigError("margin: 'epsilon' is required (a number in [0, 1))")
    return MarginConfig(d["epsilon"], str(d.get("reference", "wls")))


def with_epsilon(margin: MarginConfig | None, epsilon: float | None) -> MarginConfig | None:
    """The CLI's --margin EPS over the config's margin (its reference kept; default wls)."""
    if epsilon is None:
        return margin
    return MarginConfig(float(epsilon), "wls") if margin is None else dataclasses.replace(margin, epsilon=float(epsilon))


def apply_margin(problem, margin: MarginConfig | None, prior=None):
    """The training problem with the margin on (unchanged when off); prior: a callable giving θ₀ (only called
    for reference: prior)."""
    if margin is None:
        return problem
    return with_margin(problem, margin.epsilon, margin.reference, prior() if margin.reference == "prior" else None)
