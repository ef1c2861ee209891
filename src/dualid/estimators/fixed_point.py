"""The bounded fixed point of the dual-metric weight (a comparison for the feasible-GLS ``dm``).

The plain fixed point θ_{k+1} = argmin Σ r_iᵀ M_i(θ_k)⁻¹ r_i solves the unbiased estimating
equation Σ Y_iᵀ M_i(θ̂)⁻¹ r_i = 0 but, under model error, lets the weight follow the estimate without
bound (on a real arm's data the wrist metric shrank ×70). Here the weight's metric is kept inside
a chart-invariant trust region around a fixed pilot θ_ref:

    M̄_i = L_i · clip_[1/c, c](L_i⁻¹ M_i(θ_k) L_i⁻ᵀ) · L_iᵀ,    M_i(θ_ref) = L_i L_iᵀ

(the generalised eigenvalues of M_i(θ_k) against M_i(θ_ref) clipped to [1/c, c]), damped
geometrically between iterations (M̄ ← M̄_prev^{1−η} M̄_new^η in the pencil's eigenbasis, η =
``damping``), and θ_{k+1} = argmin Σ r_iᵀ M̄_i⁻¹ r_i under the usual constraints. Every step is a
weighted least squares (estimators.quadratic_fit.fit_weighted). The clip and the pencil are chart-invariant,
and the pilot is fitted in the sensor chart, so the estimator is invariant under the charts the
problem records.

Large N (N > 4 × ``warm_start_samples``, default 20,000): the same damped iterations first run on an evenly
strided subsample; all samples then start from the clipped pencil at the subsample's θ and iterate undamped
while each step at least halves the last (the damping takes over otherwise), to the same stopping rule and the
same fixed point (info: warm_start_samples, iterations_outer_subsample / _full, damping_full).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from dualid.errors import ConfigError, DataError, MetricError, SolverError
from dualid.estimators.base import freeze_options
from dualid.estimators.gls import PILOTS, FeasibleGLS
from dualid.estimators.metric_guard import DEFAULT_BOUND, guard_from_ratios
from dualid.estimators.newton.objective import tri_inverse
from dualid.estimators.quadratic_fit import fit_weighted
from dualid.problem import IdentificationProblem

CHUNK = 8192  # samples per block: the weight and the pencil are computed blockwise (no (N, n, n) temporaries)
WARM_SAMPLES = 20_000  # default warm-start subsample: used when N > 4× this (smaller than Newton's 50,000: the subsample takes
# ~15 damped outer iterations, the full data then ~4 undamped ones from there on the benchmark Crazyflie)


def _pencil(M_ref: np.ndarray, M: np.ndarray):
    """(L, λ, U): M_ref = L Lᵀ, L⁻¹ M L⁻ᵀ = U diag(λ) Uᵀ."""
    L = np.linalg.cholesky(M_ref)
    Li = tri_inverse(L)  # batched L⁻¹ (np.linalg.solve ran a general LU per sample)
    A = Li @ M @ np.swapaxes(Li, 1, 2)
    lam, U = np.linalg.eigh(0.5 * (A + np.swapaxes(A, 1, 2)))
    return L, lam, U


def _in_basis(V: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """(c, n): diag(V_iᵀ diag(λ_i) V_i) = Σ_k V_ki² λ_k: the old weight diag(λ) seen in the new eigenbasis V (both
    in the old basis), O(n²) per sample (a 5-operand einsum here once looped over n⁵ index tuples per sample)."""
    return np.einsum("cki,ck->ci", V * V, lam)


@dataclass(frozen=True)
class BoundedFixedPoint:
    """θ_{k+1} = argmin Σ r_iᵀ M̄_i(θ_k)⁻¹ r_i with M̄ the metric clipped to [1/c, c]·M(θ_ref), damped."""

    bound: float = 10.0  # c
    damping: float = 0.5  # η ∈ (0, 1]
    max_iter: int = 30
    tol: float = 1e-5  # stop when the clipped pencil's eigenvalues move by less than tol (relative, log scale)
    pilot: str = "wls"
    constrained: bool = True
    solver: str = "newton"  # as FeasibleGLS: "newton" or a cvxpy solver
    solver_options: tuple | None = None
    allow_unidentifiable: bool = False
    guard_bound: float = DEFAULT_BOUND
    warm_start_samples: int = WARM_SAMPLES  # N > 4× this: outer iterations on ~this many strided samples first; 0: off
    name = "dm-bfp"

    def __post_init__(self) -> None:
        if not (np.isfinite(self.bound) and self.bound >= 1.0):
            raise ConfigError(f"bound: expected a finite c ≥ 1, got {self.bound!r}")
        if not (np.isfinite(self.damping) and 0 < self.damping <= 1):
            raise ConfigError(f"damping: expected a number in (0, 1], got {self.damping!r}")
        if isinstance(self.max_iter, bool) or not isinstance(self.max_iter, int) or self.max_iter < 1:
            raise ConfigError(f"max_iter: expected an integer ≥ 1, got {self.max_iter!r}")
        if not (np.isfinite(self.tol) and self.tol > 0):
            raise ConfigError(f"tol: expected a number > 0, got {self.tol!r}")
        if self.pilot not in PILOTS:
            raise ConfigError(f"pilot: expected one of {PILOTS}, got {self.pilot!r}")
        w = self.warm_start_samples
        if isinstance(w, bool) or not isinstance(w, int) or w < 0:
            raise ConfigError(f"warm_start_samples: expected an integer ≥ 0 (0: no warm start), got {w!r}")
        object.__setattr__(self, "solver_options", freeze_options(self.solver_options, "BoundedFixedPoint: solver_options"))

    def fit(self, problem: IdentificationProblem):
        if not isinstance(problem, IdentificationProblem):
            raise DataError(f"{self.name}: keeps a weight per sample between its iterations, so it needs the data in "
                            f"memory (an IdentificationProblem), got {type(problem).__name__}")
        sensor = problem.in_sensor_chart()
        helper = FeasibleGLS(pilot=self.pilot, constrained=self.constrained, solver=self.solver,
                             solver_options=self.solver_options, allow_unidentifiable=self.allow_unidentifiable)
        common = helper._common()
        theta_ref, pilot = helper.reference(sensor)
        c = float(self.bound)
        # warm start (large N): the same outer iterations on an evenly strided subsample first, then on all samples
        # from the subsample's θ (the weight's state there: clip(pencil(θ_sub)), the fixed point's own form)
        m = self.warm_start_samples
        warm = {}
        theta_start = None
        if m and sensor.N > 4 * m:
            sub = sensor.subset(slice(0, None, sensor.N // m))
            theta_start, _, hist_sub, _, conv_sub, _, _ = _outer(self, sub, theta_ref, None, common, c)
            warm = {"warm_start_samples": sub.N, "iterations_outer_subsample": len(hist_sub),
                    "converged_subsample": conv_sub}
        theta, result, history, clipped, converged, eta, ratios = _outer(self, sensor, theta_ref, theta_start, common, c)
        if warm:
            warm.update(iterations_outer_full=len(history), damping_full=eta)
        info = {
            "pilot": pilot,
            "bound": c,
            "damping": self.damping,
            "iterations_outer": len(history),  # on all samples (see iterations_outer_subsample)
            **warm,
            "converged": converged,
            "last_step": history[-1],
            "clipped_fraction": clipped,  # share of pencil eigenvalues at the trust-region bound
            "feedback": "bounded",
        }
        if not converged:
            info["fallback"] = f"stopped after max_iter = {self.max_iter} outer iterations (last step {history[-1]:.2g})"
        # the guard: the pencil's extreme eigenvalues at θ̂ against θ_ref over every sample, from the last pencil pass
        info.update(guard_from_ratios(*ratios, self.guard_bound, f"pilot ({pilot})"))
        return dataclasses.replace(result, method=self.name, info={**result.info, **info})



def _fit(sensor, weight, whiten, est, common, first):
    """θ = argmin Σ r_iᵀ M̄_i⁻¹ r_i: the first fit of a run through ``fit_weighted`` (identifiability check,
    fallbacks), later ones from the weighted statistics whitened by the stored factor, without the objective's
    pass (the caller computes it in its pencil pass); ``fit_weighted`` takes over if that fit fails."""
    if not first and common["solver"] == "newton":
        from dualid.estimators.newton.weighted import fit_weighted_newton

        try:
            result = fit_weighted_newton(sensor, weight, constrained=common["constrained"], method=est.name,
                                         whiten=whiten, objective_pass=False, **common["solver_options"])
        except SolverError:
            result = None
        if result is not None:
            return result
    return fit_weighted(sensor, weight, est.name, common, {})


def _outer(est, sensor, theta_ref, theta_start, common, c):
    """The outer iterations on ``sensor`` (all its samples): from the pilot's metric (U_i = I, λ = 1) with the
    estimator's damping; or, given θ_start (the warm start), from the clipped pencil at θ_start, undamped while
    each step at least halves the last (near the fixed point the undamped map contracts faster than the damping
    η; the damping takes over otherwise). The fixed point and the stopping rule are the same (an undamped step
    |log λ̄_new − log λ̄_old| is ≥ the damped one, η times it). Returns (θ, last weighted fit with its objective,
    step history, clipped share, converged, damping used last, (min, max) pencil eigenvalue at θ)."""
    chunk = CHUNK
    N, n = sensor.N, sensor.n
    # the weight's state, per sample: pencil eigenvalues (log) and W_i = (L_i U_i)⁻¹ = U_iᵀ L_i⁻¹ (M_i(θ_ref) =
    # L_i L_iᵀ): M̄_i⁻¹ = W_iᵀ diag(1/λ_i) W_i, so a weighted pass whitens with diag(λ_i^-½) W_i, no factorisation
    log_lam = np.zeros((N, n))
    Winv = np.empty((N, n, n))
    for start in range(0, N, chunk):  # M_i(θ_ref) ≻ 0 everywhere (the pencil's reference); U_i = I at first
        rows = slice(start, start + chunk)
        try:
            M_ref = sensor.metric.evaluate(theta_ref, rows)
            if theta_start is None:
                Winv[rows] = tri_inverse(np.linalg.cholesky(M_ref))
                continue
            L, lam, U = _pencil(M_ref, sensor.metric.evaluate(theta_start, rows))
        except np.linalg.LinAlgError as exc:
            raise MetricError(f"{est.name}: the pilot's metric M_i(θ_ref) is not positive definite") from exc
        log_lam[rows], Winv[rows] = np.log(np.clip(lam, 1.0 / c, c)), np.swapaxes(U, 1, 2) @ tri_inverse(L)

    def whiten(block, rows):  # diag(λ_i^-½) W_i: M̄_i⁻¹ = (·)ᵀ(·)
        return np.exp(-0.5 * log_lam[rows])[:, :, None] * Winv[rows]

    def weight(block, rows):  # M̄_i = G_i diag(λ_i) G_iᵀ, G_i = L_i U_i = M_i(θ_ref) W_iᵀ
        G = block.metric.evaluate(theta_ref, rows) @ np.swapaxes(Winv[rows], 1, 2)
        return (G * np.exp(log_lam[rows])[:, None, :]) @ np.swapaxes(G, 1, 2)

    theta, result = theta_ref, None
    eta = est.damping if theta_start is None else 1.0
    history, clipped, converged = [], 0.0, False
    for k in range(est.max_iter):
        # the warm start's full phase skips the first fit's checks: the subsample passed them (its rows are a subset)
        result = _fit(sensor, weight, whiten, est, common, first=k == 0 and theta_start is None)
        theta = result.theta
        step, n_clipped, f, lo, hi = 0.0, 0, 0.0, np.inf, -np.inf
        for start in range(0, N, chunk):
            rows = slice(start, start + chunk)
            W = Winv[rows]
            e = np.exp(-0.5 * log_lam[rows])[:, :, None] * W  # the objective of this fit, with its weight
            e = np.einsum("cab,cb->ca", e, sensor.Y[rows] @ theta - sensor.tau[rows])
            f += float(np.sum(e * e))
            # the pencil in the stored basis: W_i M_i(θ) W_iᵀ = U_iᵀ (L_i⁻¹ M_i(θ) L_i⁻ᵀ) U_i = V_i diag(λ) V_iᵀ, so
            # the new basis is U_i V_i (W_i ← V_iᵀ W_i), and the old weight in it has the diagonal Σ_k V_ki² λ̄_k
            # (no M_i(θ_ref), Cholesky or triangular inverse per pass)
            A = W @ sensor.metric.evaluate(theta, rows) @ np.swapaxes(W, 1, 2)
            lam, V = np.linalg.eigh(0.5 * (A + np.swapaxes(A, 1, 2)))
            lam_c = np.clip(lam, 1.0 / c, c)
            n_clipped += int(np.sum((lam < 1.0 / c) | (lam > c)))
            lo, hi = float(np.minimum(lo, lam[:, 0].min())), float(np.maximum(hi, lam[:, -1].max()))  # NaN stays
            # damping: geometric mean of the previous weight and the new one, in the new eigenbasis
            old_in_new = np.log(np.clip(_in_basis(V, np.exp(log_lam[rows])), 1e-300, None))
            new_log = (1 - eta) * old_in_new + eta * np.log(lam_c)
            step = max(step, float(np.max(np.abs(new_log - old_in_new))))
            log_lam[rows], Winv[rows] = new_log, np.swapaxes(V, 1, 2) @ W
        result = dataclasses.replace(result, objective=f)
        clipped = n_clipped / (N * n)
        if eta != est.damping and history and step > 0.5 * history[-1]:
            eta = est.damping  # not contracting fast: the damped iteration from here
        history.append(step)
        if step < est.tol:
            converged = True
            break
    return theta, result, history, clipped, converged, eta, (lo, hi)
