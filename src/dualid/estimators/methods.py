"""The one table of identification methods: key → estimator factory, result name, label, colour and
a one-line description. The CLI, the fit config, the paper's study, the reports and the benchmark
all read it; nothing else names methods."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from dualid.errors import ConfigError
from dualid.estimators.dual_metric import DualMetric
from dualid.estimators.least_squares import OLS, WLS, EnergyLS, RegularizedWLS
from dualid.estimators.noise_dm import NoiseModelDM


@dataclass(frozen=True)
class Method:
    key: str  # what users type: "dm", "wls", …
    result_name: str  # IdentificationResult.method of its fits
    label: str  # short label in tables and figures
    color: str  # one colour per method in every figure
    description: str  # one line
    factory: Callable[..., Any]  # (common kwargs, theta0, gamma, per_equation) -> estimator
    needs_prior: bool = False  # needs a nominal θ₀ (logdet, pullback)


def _common(kw: dict) -> dict:
    """The shared hyperparameters plus the caller's estimator options (solver, tol, ...)."""
    return {**{k: kw[k] for k in ("constrained", "allow_unidentifiable")}, **dict(kw.get("options") or {})}


def _regularized(name: str) -> Callable[..., Any]:
    def make(**kw):
        return RegularizedWLS(theta0=kw["theta0"], gamma=kw["gamma"], per_equation=kw["per_equation"],
                              regularizer=name, **_common(kw))

    return make


_TABLE = (
    Method("ols", "ols", "OLS", "#8c564b", "ordinary least squares", lambda **kw: OLS(**_common(kw))),
    Method("ols_unconstrained", "ols", "OLS (unconstrained)", "#7f7f7f",
           "ordinary least squares without physical-consistency constraints",
           lambda **kw: OLS(**{**_common(kw), "constrained": False})),
    Method("wls", "wls", "WLS", "#1f77b4", "covariance-weighted least squares", lambda **kw: WLS(**_common(kw))),
    Method("energy", "energy", "energy", "#2ca02c", "energy (power) residual least squares",
           lambda **kw: EnergyLS(**_common(kw))),
    Method("logdet", "logdet_wls", "log-det WLS", "#9467bd", "WLS + log-det prior", _regularized("logdet"), True),
    Method("pullback", "pullback_wls", "pullback WLS", "#ff7f0e", "WLS + constant pullback prior",
           _regularized("pullback"), True),
    Method("dm", "dm", "DM", "#d62728",
           "dual-metric fit with a physical noise model Σ_τ + M(θ)Σ_aM(θ), its levels estimated from the data "
           "(the default)", lambda **kw: NoiseModelDM(**_common(kw))),
    Method("dm-paper", "dual_metric", "DM (paper)", "#17becf",
           "the paper's dual-metric objective Σ rᵀ M(θ)⁻¹ r (biased under torque noise; see docs/estimators.md)",
           lambda **kw: DualMetric(**_common(kw))),
)
METHODS: dict[str, Method] = {m.key: m for m in _TABLE}
TRUTH = Method("truth", "fixed", "true θ", "#000000", "the true parameters (simulation only)", lambda **kw: None)


def method(key: str) -> Method:
    """The table entry of ``key`` (also accepts the result name, e.g. "dual_metric", and "truth")."""
    if key == "truth":
        return TRUTH
    if key in METHODS:
        return METHODS[key]
    for m in _TABLE:
        if m.result_name == key:
            return m
    raise ConfigError(f"unknown method {key!r}; known methods: {', '.join(METHODS)}")


def label(key: str) -> str:
    """The method's label, or the key itself for names outside the table (user-supplied estimators)."""
    try:
        return method(key).label
    except ConfigError:
        return key


def color(key: str) -> str | None:
    try:
        return method(key).color
    except ConfigError:
        return None


def make_estimator(
    key: str,
    *,
    theta0: np.ndarray | None = None,
    gamma: float = 0.1,
    per_equation: bool = True,
    constrained: bool = True,
    allow_unidentifiable: bool = False,
    options: Mapping[str, Any] | None = None,
):
    """The estimator behind ``key``; logdet/pullback need the nominal θ₀ and the prior weight γ
    (absolute, or per equation when per_equation=True, see RegularizedWLS). ``options`` are further
    constructor arguments of the estimator (e.g. {"solver": "cvxpy", "tol": 1e-8} for dm-paper), checked by it."""
    m = method(key)
    if m is TRUTH:
        raise ConfigError("method 'truth' is the simulator's reference, not an estimator")
    options = dict(options or {})
    try:
        return m.factory(theta0=theta0, gamma=gamma, per_equation=per_equation, constrained=constrained,
                         allow_unidentifiable=allow_unidentifiable, options=options)
    except TypeError as exc:  # an option the estimator has no field for
        cls = type(m.factory(theta0=theta0, gamma=gamma, per_equation=per_equation, constrained=constrained,
                             allow_unidentifiable=allow_unidentifiable))
        known = [f.name for f in fields(cls) if f.name not in ("constrained", "allow_unidentifiable")]
        raise ConfigError(f"method {key!r}: unknown estimator options {sorted(set(options) - set(known))}; "
                          f"{cls.__name__} accepts {known}") from exc
