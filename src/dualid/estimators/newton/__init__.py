"""Dual-metric least squares by a structure-exploiting primal–dual interior-point Newton method.

    min_θ f(θ) = Σ_i r_iᵀ M_i(θ)⁻¹ r_i,   r_i = Y_i θ − τ_i,   M_i(θ) ≻ 0 (the domain),
    s.t.  C_b(θ) = C_b0 + Σ_k θ_k V_bk ⪰ 0   (pseudo-inertia / drag matrices: small LMIs)
          G θ + h ≥ 0                        (diagonal blocks and per-parameter bounds)

M is affine in θ, so the Hessian Σ_i 2 (Y_ik − M_ik w_i)ᵀ M_i⁻¹ (Y_il − M_il w_i) (w_i = M_i⁻¹ r_i) is exact; it is
accumulated over chunks of samples with batched Cholesky factors, O(chunk·n·p) memory. The constraints enter
through primal–dual (HKM) steps with the dual variables eliminated; a backtracking line search keeps every C_b ≻ 0
and every M_i ≻ 0; it stops when the duality gap plus the squared Newton decrement of the Lagrangian is below tol·f.
The start is chart-invariant (phase I by cvxpy only when it fails); large N is warm-started from a subsample
(docs/performance.md, "How the Newton solver works").

Modules: objective (f, ∇f, ∇²f and the sufficient statistics), start (starting point, phase I), linalg (dual steps),
interior_point (the iterations and their diagnostics), fit (fit_dual_metric_newton), weighted (a constant metric from
sufficient statistics).
"""

from dualid.estimators.newton.fit import fit_dual_metric_newton
from dualid.estimators.newton.objective import dual_metric_derivatives
from dualid.estimators.newton.start import starting_point
from dualid.model.consistency import feasible_set

__all__ = ["feasible_set", "dual_metric_derivatives", "fit_dual_metric_newton", "starting_point"]
