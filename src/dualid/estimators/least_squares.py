"""The quadratic estimators: OLS, covariance-weighted LS, energy LS and regularized WLS.

Each minimises Σ r_iᵀ W_i r_i (+ γ R(θ)) with r_i = Y_i θ − τ_i. The data enter only through the
sufficient statistics H = Σ Y_iᵀ W_i Y_i, g = Σ Y_iᵀ W_i τ_i, c = Σ τ_iᵀ W_i τ_i (one pass over
the samples), so the conic problem handed to the solver has the size of θ, not of the data.

Also the WLS references: of the dual-metric fit's metric guard (``wls_reference``) and of the chart-invariant
margin (``with_margin``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dualid.errors import ConfigError, ConsistencyError, DataError, DualidError, SolverError
from dualid.estimators.base import check_covariance, check_solver, freeze_options
from dualid.estimators.newton.objective import ROUNDING, energy_statistics, statistics
from dualid.estimators.quadratic_fit import closed_fit, fit_quadratic
from dualid.estimators.quadratic_newton import fit_quadratic_newton
from dualid.estimators.result import IdentificationResult
from dualid.metric_guard import DEFAULT_BOUND, check_guard_options, given_reference, reference_guard
from dualid.model.consistency import check_nominal
from dualid.model.margin import check_margin
from dualid.model.prior_lift import DEFAULT_FLOOR as PRIOR_FLOOR
from dualid.model.prior_lift import lift_prior
from dualid.problem import IdentificationProblem, additive, sample_blocks


@dataclass(frozen=True)
class _Common:
    """Hyperparameters every quadratic estimator shares, checked at construction. Estimators are
    values: arrays and option mappings are stored as tuples, so equality and hashing work."""

    constrained: bool = True  # physical-consistency constraints (pseudo-inertia ⪰ 0, drag ⪰ 0, bounds)
    # "newton": dualid's interior point (Clarabel when it fails, recorded in info); "cvxpy": the conic reference by
    # cvxpy_solver, certified or polished by the interior point (quadratic_newton.polish), which takes over on failure
    solver: str = "newton"
    solver_options: Mapping[str, Any] | None = None  # cvxpy_solver's options; for "newton": tol, max_iter
    allow_unidentifiable: bool = False  # accept one minimiser when the data do not determine θ
    cvxpy_solver: str = field(default="CLARABEL", kw_only=True)  # or "SCS"
    # metric guard recorded in every result (dualid.metric_guard): against this θ_ref (e.g. a prior), else the
    # estimator's own pilot or prior when it has one (WLS: its OLS fit; RegularizedWLS: θ₀)
    guard_reference: tuple | None = field(default=None, kw_only=True)
    guard_bound: float = field(default=DEFAULT_BOUND, kw_only=True)

    def __post_init__(self) -> None:
        name = type(self).__name__
        ref, bound = check_guard_options(self.guard_reference, self.guard_bound, name)
        object.__setattr__(self, "guard_reference", ref)
        object.__setattr__(self, "guard_bound", bound)
        for flag in ("constrained", "allow_unidentifiable"):
            if not isinstance(getattr(self, flag), (bool, np.bool_)):
                raise ConfigError(f"{name}: {flag} must be True or False, got {getattr(self, flag)!r}")
        check_solver(self.solver, self.cvxpy_solver, name)
        object.__setattr__(self, "solver_options", freeze_options(self.solver_options, f"{name}: solver_options"))
        unknown = sorted(set(dict(self.solver_options or ())) - {"tol", "max_iter"}) if self.solver == "newton" else []
        if unknown:
            raise ConfigError(f"{name}: solver 'newton' accepts the solver_options tol and max_iter, got {unknown}")

    @property
    def engine(self) -> str:
        """What solves the fit: "newton", or the cvxpy solver's name."""
        return "newton" if self.solver == "newton" else self.cvxpy_solver

    def _fit(self, problem: IdentificationProblem, stats, **extra) -> IdentificationResult:
        """``fit_quadratic`` of these statistics with this estimator's hyperparameters."""
        return fit_quadratic(problem, stats, method=self.name, constrained=self.constrained, solver=self.engine,
                             solver_options=self.solver_options, allow_unidentifiable=self.allow_unidentifiable,
                             **extra)

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
    """Ordinary least squares Σ ‖Y_i θ − τ_i‖². Default: the conic path, whose end point on unseen directions makes a
    better-conditioned prior (logdet, pullback) and plausible-step input than the interior point's (docs/estimators.md)."""

    solver: str = "cvxpy"
    name = "ols"

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        return self._guarded(self._fit(problem, statistics(problem)), problem)


def residual_covariance(problem, theta: np.ndarray, floor: float = 1e-9) -> tuple[np.ndarray, str | None]:
    """(Σ̂, fallback): Σ̂ = (1/N) Σ r_i r_iᵀ with eigenvalues floored at floor·tr(Σ̂)/n (and 1e-300), so that W = Σ̂⁻¹ is
    finite where a coordinate fits exactly (a passive joint). A residual at rounding (N tr Σ̂ ≤ ROUNDING Σ‖τ_i‖²: exact
    data) estimates no noise: Σ̂ is then ROUNDING diag(mean τ_j²), unit-free per coordinate, and ``fallback`` says so."""
    R, T = _residual_products(problem, theta)
    exact = np.trace(R) <= ROUNDING * np.trace(T)
    w, U = np.linalg.eigh((T if exact else R) / problem.N)
    S = (U * np.maximum(w, max(floor * np.sum(w) / problem.n, 1e-300))) @ U.T
    return (ROUNDING * np.diag(np.diag(S)), "exact data (rounding residual): Σ̂ = 1e-12 mean τ_j²") if exact else (S, None)


@additive
def _residual_products(problem, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Σ r_i r_iᵀ, Σ τ_i τ_iᵀ), each (n, n)."""
    S, T = np.zeros((2, problem.n, problem.n))
    for block, rows, _ in sample_blocks(problem, 16384):
        tau = block.tau[rows]
        r = block.Y[rows] @ theta - tau
        S, T = S + r.T @ r, T + tau.T @ tau
    return S, T


def covariance_weight(problem: IdentificationProblem, covariance, reference: _Common) -> tuple[np.ndarray, dict]:
    """W = Σ̂⁻¹ from a given covariance, or from the residuals of OLS under the same constraints, fitted as
    ``closed_fit`` (on the closed feasible set where its infimum is not attained, as the WLS fit that follows)."""
    theta_ols, extra = None, {}
    if covariance is None:
        theta_ols = closed_fit(problem, statistics(problem), np.eye(problem.n), "ols", reference, null_step=False).theta
        covariance, fallback = residual_covariance(problem, theta_ols)
        source, extra = ("ols residuals", {}) if fallback is None else ("rounding floor", {"fallback": fallback})
    else:
        covariance, source = np.asarray(covariance, dtype=float), "given"
        if covariance.shape != (problem.n, problem.n):
            raise DataError(f"covariance: expected shape ({problem.n}, {problem.n}) for this problem's "
                            f"{problem.n} coordinates, got {covariance.shape}")
    W = np.linalg.inv(covariance)
    return 0.5 * (W + W.T), {"covariance": source, "covariance_matrix": covariance.tolist(), **extra,
                             "theta_ols": theta_ols}


@dataclass(frozen=True)
class WLS(_Common):
    """Covariance-weighted least squares: Σ r_iᵀ Σ̂⁻¹ r_i, Σ̂ given or from the OLS residuals."""

    covariance: np.ndarray | None = None  # (n, n) symmetric positive definite; None: from OLS residuals
    name = "wls"

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "covariance", check_covariance(self.covariance, "WLS"))

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        W, info = covariance_weight(problem, self.covariance, self)
        theta_ols = info.pop("theta_ols")
        return self._guarded(closed_fit(problem, statistics(problem, W), np.asarray(info["covariance_matrix"]), self.name,
                                        self, info=info), problem, theta_ols, "pilot (ols)")


@dataclass(frozen=True)
class EnergyLS(_Common):
    """Energy (power) residual Σ (v_iᵀ r_i)², rank one per sample; on the closed set (``model.closure``), as WLS."""

    name = "energy"

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        return self._guarded(self._fit(problem, energy_statistics(problem), closure=self.constrained), problem)


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
        info.pop("theta_ols")  # the guard's reference here is θ₀
        gamma = float(self.gamma) * (problem.N * problem.n if self.per_equation else 1.0)
        return self._guarded(self._fit(
            problem, statistics(problem, W), regularizer=(self.regularizer, theta0, gamma),
            info={**info, "gamma": gamma, "prior_floor": float(self.prior_floor), "prior_lifted": lifted},
        ), problem, theta0, "prior θ₀")


REFERENCE_TOL = 1e-6  # relative: the guard compares eigenvalue ratios against [1/100, 100], far coarser than this …
REFERENCE_MAX_ITER = 30  # … and a jam (rank-deficient arm7 at N = 100) costs at most this many cheap iterations


def wls_reference(problem: IdentificationProblem, constrained: bool) -> tuple[np.ndarray, str]:
    """(θ_wls, how): OLS → Σ̂ of its residuals → WLS, W = Σ̂⁻¹, by the interior point to REFERENCE_TOL (the guard of
    ``DualMetric.fit``), else by the WLS estimator (recorded in the second element); SolverError when both fail."""
    try:
        ols = statistics(problem)
        theta_ols, _ = fit_quadratic_newton(ols.H, ols.g, ols.c, problem.parameters, constrained=constrained,
                                            tol=REFERENCE_TOL, max_iter=REFERENCE_MAX_ITER)
        S, fallback = residual_covariance(problem, theta_ols)
        W = np.linalg.inv(S)
        wls = statistics(problem, 0.5 * (W + W.T))
        theta, _ = fit_quadratic_newton(wls.H, wls.g, wls.c, problem.parameters, constrained=constrained,
                                        tol=REFERENCE_TOL, max_iter=REFERENCE_MAX_ITER)
        return theta, f"newton (tol {REFERENCE_TOL:g})" + ("" if fallback is None else f"; {fallback}")
    except (SolverError, np.linalg.LinAlgError) as exc:
        theta = WLS(constrained=constrained, allow_unidentifiable=True).fit(problem).theta
        return theta, f"the WLS estimator (the interior point to {REFERENCE_TOL:g} failed: {str(exc)[:120]})"


REFERENCES = ("wls", "prior")  # the margin's θ_ref (``with_margin``)


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
        plain = dataclasses.replace(problem, parameters=problem.parameters.without_margin())
        try:
            pilot = WLS(allow_unidentifiable=True).fit(plain)
        except DualidError as exc:
            raise ConfigError(f"margin.reference: the WLS pilot failed ({type(exc).__name__}: {exc})") from exc
        return pilot.theta, "wls pilot"
    return np.asarray(reference, dtype=float), "given θ_ref"


def with_margin(problem: IdentificationProblem, epsilon: float, reference="wls", prior=None) -> IdentificationProblem:
    """The problem with the margin C_b(θ) ⪰ ε·C_b(θ_ref) on every constrained block (ConfigError on bad input), θ_ref
    from ``margin_reference``; it lives in the problem's ParameterSpace, so every estimator applies it alike and
    records it in its result's info (``margin_epsilon``, ``margin_reference``, ``margin_min_ratio``, …)."""
    check_margin(problem.parameters, np.zeros(problem.p), epsilon)  # ε first: before any pilot fit
    theta_ref, label = margin_reference(problem, reference, prior)
    parameters = problem.parameters.with_margin(theta_ref, epsilon, label)
    return dataclasses.replace(problem, parameters=parameters)
