"""The quadratic estimators: OLS, covariance-weighted LS, energy LS and regularized WLS.

Each minimises Σ r_iᵀ W_i r_i (+ γ R(θ)) with r_i = Y_i θ − τ_i. The data enter only through the
sufficient statistics H = Σ Y_iᵀ W_i Y_i, g = Σ Y_iᵀ W_i τ_i, c = Σ τ_iᵀ W_i τ_i (one pass over
the samples), so the conic problem handed to the solver has the size of θ, not of the data.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dualid.errors import ConfigError, ConsistencyError, DataError
from dualid.estimators.base import (
    SOLVERS,
    check_covariance,
    check_nominal,
    freeze_options,
)
from dualid.estimators.metric_guard import DEFAULT_BOUND, check_guard_options, given_reference, reference_guard
from dualid.estimators.quadratic_fit import closed_fit, fit_quadratic
from dualid.estimators.result import IdentificationResult
from dualid.estimators.statistics import energy_statistics, statistics
from dualid.model.prior_lift import DEFAULT_FLOOR as PRIOR_FLOOR
from dualid.model.prior_lift import lift_prior
from dualid.problem import IdentificationProblem, additive, sample_blocks


@dataclass(frozen=True)
class _Common:
    """Hyperparameters every quadratic estimator shares, checked at construction. Estimators are
    values: arrays and option mappings are stored as tuples, so equality and hashing work."""

    constrained: bool = True  # physical-consistency constraints (pseudo-inertia ⪰ 0, drag ⪰ 0, bounds)
    solver: str = "CLARABEL"  # or "SCS"
    solver_options: Mapping[str, Any] | None = None
    allow_unidentifiable: bool = False  # accept one minimiser when the data do not determine θ
    # metric guard recorded in every result (estimators.guards): against this θ_ref (e.g. a prior), else the
    # estimator's own pilot or prior when it has one (WLS: its OLS fit; RegularizedWLS: θ₀)
    guard_reference: tuple | None = field(default=None, kw_only=True)
    guard_bound: float = field(default=DEFAULT_BOUND, kw_only=True)
    # a class constant, not a field: fitted (with its Σ̂'s OLS) on the closed feasible set where the infimum is not
    # attained (quadratic_fit.closed_fit); WLS only: OLS, energy and the priors keep the original set (estimators.md)
    closed_set = False

    def __post_init__(self) -> None:
        name = type(self).__name__
        ref, bound = check_guard_options(self.guard_reference, self.guard_bound, name)
        object.__setattr__(self, "guard_reference", ref)
        object.__setattr__(self, "guard_bound", bound)
        for flag in ("constrained", "allow_unidentifiable"):
            if not isinstance(getattr(self, flag), (bool, np.bool_)):
                raise ConfigError(f"{name}: {flag} must be True or False, got {getattr(self, flag)!r}")
        if self.solver not in SOLVERS:
            raise ConfigError(f"{name}: solver must be one of {', '.join(SOLVERS)}, got {self.solver!r}")
        object.__setattr__(self, "solver_options", freeze_options(self.solver_options, f"{name}: solver_options"))

    def _guarded(self, result: IdentificationResult, problem: IdentificationProblem, own=None,
                 own_label: str = "") -> IdentificationResult:
        """result with the metric guard against guard_reference, else against ``own`` (a pilot or prior)."""
        ref = given_reference(problem, self.guard_reference, type(self).__name__)
        label = "given guard_reference"
        if ref is None:
            ref, label = own, own_label
        if ref is None:
            label = "no prior or pilot; give guard_reference"
        guard = reference_guard(problem, result.theta, ref, label, self.guard_bound)
        return dataclasses.replace(result, info={**result.info, **guard})


@dataclass(frozen=True)
class OLS(_Common):
    """Ordinary least squares: Σ ‖Y_i θ − τ_i‖²."""

    name = "ols"

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        return self._guarded(fit_quadratic(
            problem, statistics(problem), method=self.name, constrained=self.constrained, solver=self.solver,
            solver_options=self.solver_options, allow_unidentifiable=self.allow_unidentifiable,
        ), problem)


def residual_covariance(problem: IdentificationProblem, theta: np.ndarray, floor: float = 1e-9) -> np.ndarray:
    """Σ̂ = (1/N) Σ r_i r_iᵀ, with eigenvalues floored at floor·tr(Σ̂)/n (and an absolute 1e-300).

    The floor keeps W = Σ̂⁻¹ finite when a coordinate fits exactly (noiseless data, or a passive
    joint whose modelled torque is identically zero).
    """
    S = _residual_products(problem, theta) / problem.N
    w, U = np.linalg.eigh(0.5 * (S + S.T))
    w = np.maximum(w, max(floor * np.trace(S) / problem.n, 1e-300))
    return (U * w) @ U.T


@additive
def _residual_products(problem, theta: np.ndarray) -> np.ndarray:
    """Σ r_i r_iᵀ (n, n)."""
    S = np.zeros((problem.n, problem.n))
    for block, rows, _ in sample_blocks(problem, 16384):
        r = block.Y[rows] @ theta - block.tau[rows]
        S += r.T @ r
    return S


def covariance_weight(problem: IdentificationProblem, covariance, reference: _Common) -> tuple[np.ndarray, dict]:
    """W = Σ̂⁻¹ from a given covariance, or from the residuals of OLS under the same constraints (for an estimator
    with ``closed_set``, that OLS fit as ``closed_fit``: on the closed feasible set where its infimum is not attained,
    as the WLS fit that follows)."""
    theta_ols = None
    if covariance is None:
        if reference.closed_set:
            theta_ols = closed_fit(problem, statistics(problem), np.eye(problem.n), "ols", reference).theta
        else:
            ols = OLS(reference.constrained, reference.solver, reference.solver_options,
                      reference.allow_unidentifiable)
            theta_ols = ols.fit(problem).theta
        covariance = residual_covariance(problem, theta_ols)
        source = "ols residuals"
    else:
        covariance = np.asarray(covariance, dtype=float)
        source = "given"
        if covariance.shape != (problem.n, problem.n):
            raise DataError(f"covariance: expected shape ({problem.n}, {problem.n}) for this problem's "
                            f"{problem.n} coordinates, got {covariance.shape}")
    W = np.linalg.inv(covariance)
    return 0.5 * (W + W.T), {"covariance": source, "covariance_diag": covariance.diagonal().tolist(),
                             "covariance_matrix": covariance.tolist(), "theta_ols": theta_ols}


@dataclass(frozen=True)
class WLS(_Common):
    """Covariance-weighted least squares: Σ r_iᵀ Σ̂⁻¹ r_i, Σ̂ given or from the OLS residuals."""

    covariance: np.ndarray | None = None  # (n, n) symmetric positive definite; None: from OLS residuals
    name = "wls"
    closed_set = True  # its fit and its Σ̂'s OLS fit by quadratic_fit.closed_fit

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "covariance", check_covariance(self.covariance, "WLS"))

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        W, info = covariance_weight(problem, self.covariance, self)
        S = np.asarray(info["covariance_matrix"])
        return self._guarded(closed_fit(problem, statistics(problem, W), S, self.name, self, info={
            k: v for k, v in info.items() if k in ("covariance", "covariance_matrix")}), problem, info["theta_ols"],
            "pilot (ols)")


@dataclass(frozen=True)
class EnergyLS(_Common):
    """Energy (power) residual: Σ (v_iᵀ r_i)²; rank one per sample."""

    name = "energy"

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        return self._guarded(fit_quadratic(
            problem, energy_statistics(problem), method=self.name, constrained=self.constrained, solver=self.solver,
            solver_options=self.solver_options, allow_unidentifiable=self.allow_unidentifiable,
        ), problem)


@dataclass(frozen=True)
class RegularizedWLS(_Common):
    """WLS + γ R(θ) with a geometric prior around a nominal θ₀ (Lee, Wensing & Park 2020).

    regularizer = "logdet": R = Σ_b −log det C_b(θ) + log det C_b0 + tr(C_b0⁻¹ C_b(θ)) − m_b
    regularizer = "pullback": R = Σ_b (θ_b − θ_b0)ᵀ g_b (θ_b − θ_b0), g_kl = tr(C_b0⁻¹V_k C_b0⁻¹V_l)
    C_b is each block's constraint matrix (pseudo-inertia for rigid bodies, drag matrix for drag).
    """

    theta0: np.ndarray | None = None  # (p,) nominal parameters (e.g. CAD), physically consistent
    gamma: float = 0.1  # weight of the prior: per equation (γ·N·n) by default, else in units of the data objective
    regularizer: str = "logdet"  # "logdet" | "pullback"
    covariance: np.ndarray | None = None  # (n, n); None: from the unregularized (OLS) residuals
    per_equation: bool = True  # γ_eff = γ·N·n: with W = Σ̂⁻¹ the data term is ≈ N·n at its optimum,
    # so a per-equation γ weighs the prior the same against 20 samples as against 20,000
    # each body's principal second moments in θ₀ lifted to ≥ prior_floor · m_b ℓ² (model.prior_lift; 0: off),
    # recorded in info["prior_lifted"]: a prior on the consistency boundary (e.g. a constrained fit) is not solvable
    prior_floor: float = PRIOR_FLOOR

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.regularizer not in ("logdet", "pullback"):
            raise ConfigError(f"RegularizedWLS: regularizer must be 'logdet' or 'pullback', got {self.regularizer!r}")
        if self.theta0 is None:
            raise ConfigError("RegularizedWLS: needs a nominal θ₀ (theta0=...)")
        theta0 = np.asarray(self.theta0, dtype=float)
        if theta0.ndim != 1 or not np.all(np.isfinite(theta0)):
            raise ConfigError(f"RegularizedWLS: theta0 must be a finite vector, got {self.theta0!r}")
        object.__setattr__(self, "theta0", tuple(theta0.tolist()))
        if not isinstance(self.gamma, (int, float, np.number)) or not (np.isfinite(self.gamma) and self.gamma >= 0):
            raise ConfigError(f"RegularizedWLS: gamma must be a finite number ≥ 0, got {self.gamma!r}")
        object.__setattr__(self, "covariance", check_covariance(self.covariance, "RegularizedWLS"))
        if not isinstance(self.prior_floor, (int, float, np.number)) or not 0 <= self.prior_floor < 1:
            raise ConfigError(f"RegularizedWLS: prior_floor must be a number in [0, 1), got {self.prior_floor!r}")

    @property
    def name(self) -> str:
        return f"{self.regularizer}_wls"

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        try:  # a body on the boundary (margin 0) is lifted below; one outside the cone is refused as before …
            theta0 = check_nominal(problem.parameters, self.theta0, strict=False)
        except ConsistencyError:
            # … unless it is consistent to the library's tolerance (a constrained fit's rounding, margin ~ −1e-12)
            # and the lift is on: then the lift (recorded) moves it inside, and the strict check below confirms it
            given = np.asarray(self.theta0, dtype=float)
            if not (self.prior_floor > 0 and given.shape == (problem.parameters.p,) and np.all(np.isfinite(given))
                    and problem.parameters.is_consistent(given)):
                check_nominal(problem.parameters, self.theta0, strict=True)
                raise
            theta0 = given
        theta0, lifted = lift_prior(problem.parameters, theta0, float(self.prior_floor))
        theta0 = check_nominal(problem.parameters, theta0, strict=True)
        W, info = covariance_weight(problem, self.covariance, self)
        gamma = float(self.gamma) * (problem.N * problem.n if self.per_equation else 1.0)
        return self._guarded(fit_quadratic(
            problem, statistics(problem, W), method=self.name, constrained=self.constrained, solver=self.solver,
            solver_options=self.solver_options, allow_unidentifiable=self.allow_unidentifiable,
            regularizer=(self.regularizer, theta0, gamma),
            info={"covariance": info["covariance"], "covariance_matrix": info["covariance_matrix"], "gamma": gamma,
                  "prior_floor": float(self.prior_floor), "prior_lifted": lifted},
        ), problem, theta0, "prior θ₀")
