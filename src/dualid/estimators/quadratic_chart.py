"""The diagonal chart θ = s ⊙ φ in which a weighted or energy least-squares fit (with or without a geometric prior)
is handed to cvxpy.

The chart used before, s_k = 1/‖Y_k‖ with Y the raw regressor, is the Jacobi scaling of OLS. A weighted fit
(W = Σ̂⁻¹) or an energy fit (residual vᵀr) does not change when one coordinate changes units, but ‖Y_k‖ does: with
q1 in units ×1e6 every parameter the first joint sees got s_k 1e6 too small against the parameters the data do not
see (s = 1, physical units), and with q1 in units ×1e-6 the parameters only the first joint sees got s_k 1e6 too
large, so the scaled Hessian's diagonal spread over 12 decades. Clarabel then stopped with a numerical error on two
feasible fits of the stress corpus (energy at ×1e-6, pullback with the OLS prior at ×1e6).

Here the chart comes from the fit's own statistics H = Σ Y_iᵀ W_i Y_i and c = Σ τ_iᵀ W_i τ_i:

    s_k = √(c / H_kk)       where H_kk > 0,  so  φ_k = ‖Y_k θ_k‖_W / ‖τ‖_W

the share of the weighted torques that θ_k alone carries: invariant to a change of coordinates (H and c move
together), to the noise level (W = Σ̂⁻¹ scales both by 1/σ²; the plain Jacobi chart 1/√H_kk does not, and puts the
data-seen parameters 1e13 away from the others on exact data) and to N. With a prior γR(θ) the
data-seen parameters use the whole curvature, s_k = √(c / (H_kk + γ g_kk)) with g the prior's pullback metric (the
log-det divergence's Hessian at θ₀ too): a near-singular prior body (the Crazyflie's thin pendulum links, g ~ 1e16)
otherwise left the prior term 1e10 above the data term in the scaled problem, and Clarabel stopped on the Crazyflie
with q1 in units ×1e3 (pullback, CAD-like prior; measured with √(c/H_kk): 1 failed and 5 optimal_inaccurate
regularized fits over the corpus's small cases, with the whole curvature 0 and 3). A parameter the data do not see
keeps 1/√g_kk from the prior's pullback metric when a prior sees it (its size in C_b(θ₀)), else its physical unit, 1.
Measured: the per-equation normalisation √(c/(N n H_kk)) (a chart N·n times smaller) made Clarabel report the
feasible pullback fit with a margin of tests/test_margin.py "infeasible", and so does the whole-curvature chart
(its margin puts the feasible set far out in φ); the quadratic fits therefore check a cvxpy "infeasible" with
dualid's interior point (``quadratic_fit._solve_with_fallback``: chain "CLARABEL claimed infeasible → newton
optimal" there). Without a prior the chart is invariant to the noise level; with one it is not, nor should it be:
the balance of data and prior is then part of the problem.
"""

from __future__ import annotations

import numpy as np

from dualid.model.consistency import prior_blocks, pullback_metric


def signal_scale(H: np.ndarray, c: float, parameters=None, regularizer=None) -> np.ndarray:
    """s (p,) of the module doc; H (p, p) and c the fit's weighted statistics, regularizer (kind, θ₀, γ) or None."""
    d = np.clip(np.diag(H).astype(float), 0.0, None)
    seen = d > 0
    g = np.zeros_like(d)  # diag of the prior's pullback metric (the log-det divergence's Hessian at θ₀ too)
    gamma = 0.0
    if regularizer is not None:
        kind, theta0, gamma = regularizer
        for idx, V, C0 in prior_blocks(kind, parameters, np.asarray(theta0, dtype=float)):
            g[np.asarray(idx)] += np.clip(np.diag(pullback_metric(V, C0)), 0.0, None)
    s = np.ones_like(d)
    s[seen] = np.sqrt(max(float(c), 1e-300) / (d[seen] + float(gamma) * g[seen]))
    prior_only = ~seen & (g > 0)
    s[prior_only] = 1.0 / np.sqrt(g[prior_only])
    return s
