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

from dualid.errors import ConfigError, ConsistencyError, DataError, SolverError
from dualid.estimators.base import (
    SOLVERS,
    captured_warnings,
    check_covariance,
    check_identifiable,
    check_nominal,
    freeze_options,
    is_problem_property,
    parameter_scale,
    solve_cvxpy,
)
from dualid.estimators.metric_guard import DEFAULT_BOUND, check_guard_options, given_reference, reference_guard
from dualid.estimators.quadratic_chart import signal_scale
from dualid.estimators.result import IdentificationResult
from dualid.estimators.statistics import Statistics, energy_statistics, statistics
from dualid.linalg import gram_eigh, gram_rank
from dualid.model.consistency import cvxpy_constraints, prior_blocks, pullback_metric, regularizer_value
from dualid.model.prior_lift import DEFAULT_FLOOR as PRIOR_FLOOR
from dualid.model.prior_lift import lift_prior
from dualid.problem import IdentificationProblem, sample_blocks


def fit_quadratic(
    problem: IdentificationProblem,
    stats: Statistics,
    *,
    method: str,
    constrained: bool,
    solver: str,
    solver_options: dict | None,
    allow_unidentifiable: bool,
    regularizer: tuple[str, np.ndarray, float] | None = None,
    info: dict | None = None,
    closure: bool = False,  # Newton polish / fallback on the closed feasible set (estimators.newton.closure; dm)
) -> IdentificationResult:
    """min θᵀHθ − 2gᵀθ + c (+ γ R(θ)) under the problem's constraints, in scaled variables θ = s ⊙ φ."""
    import cvxpy as cp

    p = problem.p
    info = dict(info or {})
    rank = gram_rank(stats.H)
    info["rank"] = rank
    if regularizer is None and not allow_unidentifiable:
        check_identifiable(problem, rank=rank, what=f"{method} weighted regressor")

    if stats.W is None and not stats.energy:  # H = Σ YᵀY: its diagonal holds the squared column norms (no pass)
        s = np.sqrt(np.clip(np.diag(stats.H), 0.0, None))
        s[s > 0] = 1.0 / s[s > 0]
        s[s == 0] = 1.0
    elif constrained or regularizer is not None:  # weighted or energy conic fit: the chart of its own statistics,
        # invariant to units and noise level (estimators.quadratic_chart; the column norms of Y are neither)
        s = signal_scale(stats.H, stats.c, problem.parameters, regularizer)
    else:
        s = parameter_scale(problem)
    Hs = s[:, None] * stats.H * s[None, :]
    gs = s * stats.g

    if not constrained and regularizer is None:
        import time

        t0 = time.perf_counter()
        phi = np.linalg.lstsq(Hs, gs, rcond=None)[0]  # minimum-norm minimiser (in scaled variables)
        theta = s * phi
        return IdentificationResult(
            method, theta, problem.parameters, stats.objective(problem, theta), "optimal", "lstsq",
            time.perf_counter() - t0, None, False, info,
        )

    w, U, keep = gram_eigh(Hs)
    R = np.sqrt(w[keep])[:, None] * U[:, keep].T
    b = (U[:, keep].T @ gs) / np.sqrt(w[keep])
    # f(θ) = ‖Rφ − b‖² + f_min with f_min the unconstrained minimum; normalise by f_min so the
    # solver's tolerances are relative to the attainable fit even when the data fit exactly
    f_min = max(stats.c - float(b @ b), 0.0)
    gamma = regularizer[2] if regularizer is not None else 0.0  # R is O(1) per block near θ₀
    norm = max(f_min, gamma, 1e-10 * stats.c, 1e-300)
    phi = cp.Variable(p)
    theta = cp.multiply(s, phi)
    if regularizer is None:
        objective = cp.norm(R @ phi - b) / np.sqrt(norm)  # same minimiser, better conditioned
    else:
        objective = cp.sum_squares(R @ phi - b) / norm
    if regularizer is not None:
        kind, theta0, gamma = regularizer
        terms = prior_blocks(kind, problem.parameters, theta0)
        reg = 0
        for idx, V, C0 in terms:
            th = theta[idx]
            k, m, _ = V.shape
            if kind == "logdet":
                # whitened block L⁻¹ C L⁻ᵀ with C0 = L Lᵀ (the prior's own chart, I at θ₀): the cone sees O(1)
                # entries even for an ill-conditioned C0, and −log det C + tr(C0⁻¹C) changes only by a constant
                Li = np.linalg.inv(np.linalg.cholesky(0.5 * (C0 + C0.T)))
                VS = np.einsum("ab,kbc,dc->kad", Li, V, Li)
                C = cp.reshape(VS.reshape(k, m * m).T @ th, (m, m), order="C")
                reg = reg - cp.log_det(0.5 * (C + C.T)) + cp.trace(C)
            else:
                G = pullback_metric(V, C0)
                # G = F Fᵀ exactly (eigen-factor): a ridge added for a Cholesky factor (1e-12·tr G) changes the
                # objective by ~1e-4 relative on thin links, where tr G is dominated by a near-null direction of C0
                w, U = np.linalg.eigh(0.5 * (G + G.T))
                F = U * np.sqrt(np.maximum(w, 0.0))
                reg = reg + cp.sum_squares(F.T @ (th - theta0[idx]))
        objective = objective + (gamma / norm) * reg
    constraints = cvxpy_constraints(theta, problem.parameters) if constrained else []
    cvx = cp.Problem(cp.Minimize(objective), constraints)
    theta_hat, status, used, iterations, solve_time = _solve_with_fallback(
        cvx, phi, s, stats, problem, method, constrained, solver, solver_options, regularizer, info, closure
    )
    value = stats.objective(problem, theta_hat)
    if regularizer is not None:
        kind, theta0, gamma = regularizer
        info["data_objective"] = value
        value += gamma * regularizer_value(kind, problem.parameters, theta_hat, theta0)
    return IdentificationResult(
        method, theta_hat, problem.parameters, value, status, used, solve_time, iterations, constrained, info,
    )


def _solve_with_fallback(cvx, phi, s, stats, problem, method, constrained, solver, solver_options, regularizer, info,
                         closure=False):
    """cvxpy first; when it fails or returns only optimal_inaccurate, dualid's own interior-point method
    (estimators.quadratic_newton). What happened is recorded in info (solver_chain, fallback_used,
    solver_warnings); an inaccurate cvxpy result is returned only, and labelled, if that fails too."""
    import time

    from dualid.estimators.certify import polish
    from dualid.estimators.quadratic_newton import fit_quadratic_newton

    solved, failure, claim = None, None, None
    with captured_warnings() as notes:  # cvxpy's warnings go into the result, not the terminal
        try:
            solved = solve_cvxpy(cvx, phi, solver, solver_options, what=f"{method} fit")
        except SolverError as exc:
            if not is_problem_property(exc):
                failure = f"{solver} failed ({exc.status}): {exc}"
            elif "infeasible" in exc.status:  # checked: a badly scaled conic problem can be called infeasible
                claim, failure = exc, f"{solver} claimed {exc.status}"
            else:
                raise
    if notes:
        info["solver_warnings"] = " | ".join(notes)
    if solved is not None and solved.status == "optimal":  # certified (or polished) by dualid's interior point
        t0 = time.perf_counter()
        theta, label, polished, certified, checked = polish(s * solved.value, stats, problem.parameters,
                                                            constrained, regularizer, solver, closure=closure)
        info.update(checked, solver_chain=label, fallback_used=polished)
        if polished:
            info["fallback_reason"] = label
            return theta, "optimal", "newton", checked["certify_iterations"], time.perf_counter() - t0
        status = "optimal" if certified else "optimal_inaccurate"
        return theta, status, solved.solver, solved.iterations, solved.solve_time
    first = failure or f"{solver} returned {solved.status}"
    t0 = time.perf_counter()
    try:
        try:  # cold start first (the same path whatever rounding cvxpy's end point has), then from that end point
            theta, ipm = fit_quadratic_newton(stats.H, stats.g, stats.c, problem.parameters, constrained=constrained,
                                              regularizer=regularizer, closure=closure)
        except SolverError:
            if solved is None:
                raise
            theta, ipm = fit_quadratic_newton(stats.H, stats.g, stats.c, problem.parameters, constrained=constrained,
                                              regularizer=regularizer, start=s * solved.value, closure=closure)
    except SolverError as exc:
        if claim is not None and exc.status == "no_start":  # no strictly feasible θ either: the claim stands
            raise claim from exc
        if claim is not None:
            raise SolverError(f"{method} fit: {first}; dualid's interior-point method could not check it (it failed: "
                              f"{exc})", status="all_solvers_failed") from exc
        if solved is None:
            raise SolverError(f"{method} fit: {first}; then dualid's interior-point method failed: {exc}",
                              status="all_solvers_failed") from exc
        info.update(solver_chain=f"{first} → newton failed ({exc.status}) → {solver} {solved.status}",
                    fallback_used=False, fallback_reason=first)
        return s * solved.value, solved.status, solved.solver, solved.iterations, solved.solve_time
    info.update(solver_chain=f"{first} → newton optimal", fallback_used=True, fallback_reason=first,
                relative_gap=ipm["relative_gap"])
    info.update({k: v for k, v in ipm.items() if k.startswith("projected_")})  # newton.closure's completion
    return theta, "optimal", "newton", ipm["iterations"], time.perf_counter() - t0


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
    S = np.zeros((problem.n, problem.n))
    for block, rows, _ in sample_blocks(problem, 16384):
        r = block.Y[rows] @ theta - block.tau[rows]
        S += r.T @ r
    S /= problem.N
    w, U = np.linalg.eigh(0.5 * (S + S.T))
    w = np.maximum(w, max(floor * np.trace(S) / problem.n, 1e-300))
    return (U * w) @ U.T


def covariance_weight(problem: IdentificationProblem, covariance, reference: _Common) -> tuple[np.ndarray, dict]:
    """W = Σ̂⁻¹ from a given covariance, or from the residuals of OLS under the same constraints."""
    theta_ols = None
    if covariance is None:
        ols = OLS(reference.constrained, reference.solver, reference.solver_options, reference.allow_unidentifiable)
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

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "covariance", check_covariance(self.covariance, "WLS"))

    def fit(self, problem: IdentificationProblem) -> IdentificationResult:
        W, info = covariance_weight(problem, self.covariance, self)
        return self._guarded(fit_quadratic(
            problem, statistics(problem, W), method=self.name, constrained=self.constrained, solver=self.solver,
            solver_options=self.solver_options, allow_unidentifiable=self.allow_unidentifiable,
            info={k: v for k, v in info.items() if k in ("covariance", "covariance_matrix")},
        ), problem, info["theta_ols"], "pilot (ols)")


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
