"""Noise-aware plausible parameters: the θ closest to a prior θ₀ among those the data do not reject.

``plausible_parameters`` (evaluation.plausible) keeps θ̂'s training predictions exactly. On noisy data
that is too strict: directions the rank rule counts as determined may be determined only to far below
the noise, and the fit's absurd values along them (a 60× link mass) cannot be touched. Here the slice
is widened to the fit's confidence region of the base parameters β = C θ (dualid.identifiability):

    θ_p = argmin_θ  R(θ)   subject to   (Cθ − β̂)ᵀ Σ_β⁻¹ (Cθ − β̂) ≤ c²,   C_b(θ) ⪰ 0, bounds,

with Σ_β the method's covariance of β̂ (evaluation.uncertainty: the sandwich, or a bootstrap's) and R the
scale-aware prior term of ``evaluation.plausible_newton`` (the log-det divergence of the pseudo-inertias,
torque-weighted squares on joint terms), which also solves it. The radius:
c² = χ²₁(level) by default — the ellipsoid is then exactly the set of β for which *every* linear
combination aᵀβ (each base parameter, each predicted torque) stays within its own ``level`` interval
aᵀβ̂ ± z·√(aᵀΣa); ``joint=True``: c² = χ²_r(level), the joint confidence region of all r base
parameters (much wider for r ≈ 60: it lets single combinations move by ~8σ; benchmarks/plausible_arm.md).
Both the ellipsoid and R are invariant under a change of units or body frame, so θ_p is too. level → 0
shrinks the ellipsoid onto θ̂'s slice; level = 0 *is* the exact-prediction choice (``plausible_parameters``
is called), and so is noise-free data (a training residual below EXACT_RTOL of the torque: Σ_β is roundoff).

Which parameters the prior determined: with μ the multiplier of the ellipsoid (from stationarity) and
F = CᵀΣ_β⁻¹C, the quadratic model of the problem at θ₀ gives ∂θ_p/∂θ₀ = (G + λF)⁻¹G, λ = 2μ (μ for
the pullback objective, whose Hessian is 2G), where no consistency constraint is active; its diagonal
is the prior share (unchanged by a unit scaling of any parameter), evaluated as
I − G⁻¹Cᵀ(Σ_β/λ + CG⁻¹Cᵀ)⁻¹C so that λ → ∞ (a tiny Σ_β, exact data) gives the exact form's
G-orthogonal projector onto the null space. "prior" from a share of PRIOR_SHARE on, as there.

What it costs: the training τ RMSE of θ_p against θ̂'s is recorded; when Σ_β matches the noise the
ellipsoid lets the fit's objective grow by about c² noise variances over the N·n residuals, a relative
RMSE change of the order of c²/(2 N n).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.linalg
import scipy.special

from dualid.errors import ConfigError, DataError, SolverError
from dualid.evaluation.plausible import (
    DATA,
    PREDICTION_RTOL,
    PRIOR,
    PRIOR_SHARE,
    PlausibleParameters,
    clear_boundary,
    checked_prior,
    plausible_parameters,
)
from dualid.evaluation.plausible_newton import prior_divergence, solve_region
from dualid.evaluation.uncertainty import BaseUncertainty
from dualid.problem import IdentificationProblem

LEVEL = 0.95  # default confidence level of the region (chosen in benchmarks/plausible_arm.md)
EXACT, CONFIDENCE = "exact", "confidence"
EXACT_RTOL = 1e-9  # a training τ RMSE below this × the τ RMS: noise-free data (the exact-prediction choice)
SIGMA_RTOL = 1e-12  # eigenvalues of the scaled Σ_β below this × its largest: directions the data fix exactly


def check_level(level, where: str = "plausible parameters: level") -> float:
    """level as a float in [0, 1) (0: θ̂'s predictions exactly), or a ConfigError naming ``where``."""
    if isinstance(level, bool) or not isinstance(level, (int, float, np.integer, np.floating)) \
            or not 0 <= float(level) < 1:
        raise ConfigError(f"{where}: expected a probability in [0, 1) (0: keep the training predictions exactly), "
                          f"got {level!r}")
    return float(level)


def training_rmse(problem: IdentificationProblem, theta: np.ndarray) -> float:
    """τ RMSE of θ on the problem's samples, all joints together."""
    return float(np.sqrt(np.mean((problem.Y @ theta - problem.tau) ** 2)))


def _whitening(unc: BaseUncertainty, s_ind: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R (r, k) with Σ_β = R Rᵀ on its numerical range, Σ_β⁺ (r, r)), computed in the column-scaled chart
    (β̃ = s_ind β) so that the threshold does not depend on units."""
    S = np.asarray(unc.covariance, dtype=float) * np.outer(s_ind, s_ind)
    w, U = np.linalg.eigh(0.5 * (S + S.T))
    keep = w > SIGMA_RTOL * max(float(w.max(initial=0.0)), 1e-300)
    R = U[:, keep] * np.sqrt(w[keep]) / s_ind[:, None]
    pinv = (U[:, keep] / w[keep]) @ U[:, keep].T * np.outer(s_ind, s_ind)
    return R, pinv


def _prior_share(G, C, Sigma, lam: float, scale, s_ind) -> np.ndarray:
    """diag((G + λCᵀΣ⁻¹C)⁻¹G) (p,) written as I − G⁻¹Cᵀ(Σ/λ + CG⁻¹Cᵀ)⁻¹C (Woodbury): no Σ⁻¹, so a tiny Σ (exact
    data) gives the G-orthogonal projector onto C's null space instead of roundoff; in the column-scaled chart
    (a diagonal rescaling leaves the diagonal unchanged)."""
    if lam <= 0:
        return np.ones(G.shape[0])
    Gs = G / np.outer(scale, scale)
    Cs = C * s_ind[:, None] / scale[None, :]
    Ginv_Ct = np.linalg.solve(Gs, Cs.T)
    inner = Sigma * np.outer(s_ind, s_ind) / lam + Cs @ Ginv_Ct
    return np.clip(1.0 - np.einsum("kr,rk->k", Ginv_Ct, np.linalg.solve(inner, Cs)), 0.0, 1.0)


def plausible_in_region(problem: IdentificationProblem, theta_hat, theta0, uncertainty: BaseUncertainty,
                        level: float = LEVEL, joint: bool = False, solver: str = "CLARABEL",
                        solver_options: dict | None = None) -> PlausibleParameters:
    """θ_p closest to θ₀ with β(θ_p) in the fit's ``level`` confidence ellipsoid (module docstring), solved by
    dualid's interior point (``evaluation.plausible_newton``); ``solver``/``solver_options`` serve level 0 only."""
    level = check_level(level)
    P = problem.parameters
    theta_hat = np.asarray(theta_hat, dtype=float)
    if theta_hat.shape != (P.p,) or not np.all(np.isfinite(theta_hat)):
        raise DataError(f"plausible_in_region: θ̂ must be {P.p} finite numbers, got shape {theta_hat.shape}")
    base = uncertainty.base
    if base.parameters.p != P.p or uncertainty.covariance.shape != (base.rank, base.rank):
        raise DataError(f"plausible_in_region: the uncertainty is for {base.parameters.p} parameters and "
                        f"{base.rank} base parameters (covariance {uncertainty.covariance.shape}); the problem has {P.p}")
    rmse_hat = training_rmse(problem, theta_hat)
    if level == 0.0:
        exact = plausible_parameters(problem, theta_hat, theta0, solver, solver_options)
        return dataclasses.replace(exact, form=EXACT, training_rmse_hat=rmse_hat,
                                   training_rmse=training_rmse(problem, exact.theta))
    tau_rms = float(np.sqrt(np.mean(problem.tau**2)))
    if rmse_hat <= EXACT_RTOL * tau_rms:  # noise-free data: Σ_β is roundoff, the region is θ̂'s slice
        exact = plausible_parameters(problem, theta_hat, theta0, solver, solver_options)
        return dataclasses.replace(exact, form=EXACT, training_rmse_hat=rmse_hat,
                                   training_rmse=training_rmse(problem, exact.theta), note=(
                                       f"the training residual is roundoff ({rmse_hat / tau_rms:.1e} of the torque): "
                                       "the data fix the identifiable combinations exactly, the region is θ̂'s slice"))
    theta0 = checked_prior(P, theta0, solver, "plausible_in_region")
    r = base.rank
    # χ²_r quantile (scipy.stats.chi2.ppf computes it so; scipy.stats costs 0.6 s to import)
    radius2 = 2.0 * float(scipy.special.gammaincinv((r if joint else 1) / 2, level)) if r else 0.0
    scale = np.linalg.norm(problem.Y.reshape(-1, P.p), axis=0)
    scale[scale == 0] = 1.0
    s_ind = scale[list(base.independent)]
    Sigma = np.asarray(uncertainty.covariance, dtype=float)
    beta_hat = base.values(theta_hat)
    out = solve_region(problem, theta0, beta_hat, base.C, Sigma, radius2, scale, s_ind, theta_hat)
    chain = [out["chain"]]
    try:
        theta_p, pulled = clear_boundary(out["theta"], theta_hat, P)  # the segment stays in the region
    except SolverError as exc:
        raise SolverError(f"{exc} ({' → '.join(chain)})", status=exc.status) from None
    if pulled:
        chain.append(f"moved {pulled:.1e} of the way back to θ̂ to clear a rounding-size violation of consistency")
    # prior share from the quadratic model: ∂θ_p/∂θ₀ = (G + λF)⁻¹G, F = CᵀΣ⁻¹C; the penalty μ‖u‖² = (μ/c²)·statistic
    # has Hessian (2μ/c²)F, so λ = 2μ/c²
    lam = 2.0 * out["mu"] / radius2 if radius2 > 0 else 0.0
    share = _prior_share(out["G"], base.C, Sigma, lam, scale, s_ind)
    determined = tuple(PRIOR if x_ >= PRIOR_SHARE else DATA for x_ in share)
    _, Sinv = _whitening(uncertainty, s_ind)
    d = base.values(theta_p) - beta_hat
    A = problem.Y.reshape(-1, P.p)
    change = float(np.linalg.norm(A @ (theta_p - theta_hat)) / max(np.linalg.norm(A @ theta_hat), 1e-300))
    return PlausibleParameters(
        theta_p, theta_hat=theta_hat, theta0=theta0, names=P.names, prior_share=share, determined_by=determined,
        null_space=_null_space(base.C, scale, s_ind), rank=r, status="optimal" if not out["note"] else "outside_region",
        solver="newton", solver_chain=" → ".join(chain), fallback_used=bool(out["note"]), objective="prior",
        prediction_change=change, predictions_unchanged=change <= PREDICTION_RTOL,
        consistent=P.is_consistent(theta_p, tol=1e-7),
        divergence_hat=prior_divergence(problem, theta_hat, theta0),
        divergence=prior_divergence(problem, theta_p, theta0), form=CONFIDENCE, level=level, radius2=radius2,
        statistic=float(d @ Sinv @ d), training_rmse_hat=rmse_hat, training_rmse=training_rmse(problem, theta_p),
        note=out["note"],
    )


def _null_space(C: np.ndarray, scale: np.ndarray, s_ind: np.ndarray) -> np.ndarray:
    """A basis (p, p − r) of C's null space in θ units (computed in the column-scaled chart)."""
    r, p = C.shape
    if r >= p:
        return np.zeros((p, 0))
    return scipy.linalg.null_space(C / scale[None, :] * s_ind[:, None]) / scale[:, None]
