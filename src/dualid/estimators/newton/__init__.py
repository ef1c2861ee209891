"""Dual-metric least squares by a structure-exploiting primal–dual interior-point Newton method.

    min_θ f(θ) = Σ_i r_iᵀ M_i(θ)⁻¹ r_i,   r_i = Y_i θ − τ_i,   M_i(θ) ≻ 0 (the domain),
    s.t.  C_b(θ) = C_b0 + Σ_k θ_k V_bk ⪰ 0   (pseudo-inertia / drag matrices: small LMIs)
          G θ + h ≥ 0                        (diagonal blocks and per-parameter bounds)

With w_i = M_i⁻¹ r_i the derivatives are (M affine in θ, so the Hessian below is *exact*, not an
approximation: d/dθ_l of 2Y_kᵀw − wᵀM_k w is 2(Y_k − M_k w)ᵀ dw/dθ_l, dw/dθ_l = M⁻¹(Y_l − M_l w)):

    ∂f/∂θ_k        = Σ_i 2 Y_ikᵀ w_i − w_iᵀ M_ik w_i
    ∂²f/∂θ_k∂θ_l   = Σ_i 2 (Y_ik − M_ik w_i)ᵀ M_i⁻¹ (Y_il − M_il w_i)      (PSD: f is convex)

Both are accumulated over chunks of samples (``objective.CHUNK``, 1,024) with batched Cholesky factors and the
factored metric (the quantities of ``AffineMetric.quad`` / ``apply``, computed together), so memory
is O(chunk·n·p) beyond the problem's own arrays; the dense N·p·n² basis is never formed.

Constraints: primal–dual (HKM) Newton steps on C_b Z_b = σμ I (and s_j z_j = σμ), where the dual
variables are eliminated: (∇²f + Ψ) Δθ = −∇f + σμ A*(C⁻¹), Ψ_kl = Σ_b tr(V_k Z_b V_l C_b⁻¹). The
step is a descent direction of the barrier merit f − σμ Σ log det C_b, on which a backtracking line
search keeps every C_b ≻ 0 and every M_i ≻ 0 (every Cholesky must succeed). σ by Mehrotra's
predictor heuristic (≥ 0.05), one step length for primal and dual. Stops when the duality gap
Σ⟨C_b, Z_b⟩ plus the squared Newton decrement of the Lagrangian is below tol·f.

Start: least squares from the sufficient statistics, moved toward a strictly feasible point (each
block's matrix with its eigenvalues lifted); only if that fails, a small phase-I conic problem
(cvxpy; size p plus the offending samples) decides between a start, SolverError (constraints with
empty interior) and MetricError (no feasible θ makes every M_i ≻ 0). For N > 200,000 the iterations
are warm-started from a strided 50,000-sample subsample.

Modules: constraints (the feasible set), objective (f, ∇f, ∇²f), start (starting point, phase I),
linalg (Newton-matrix solves), interior_point (the iterations), fit (fit_dual_metric_newton).
"""

from dualid.estimators.newton.fit import fit_dual_metric_newton
from dualid.estimators.newton.objective import dual_metric_derivatives
from dualid.estimators.newton.start import starting_point
from dualid.model.consistency import feasible_set

__all__ = ["feasible_set", "dual_metric_derivatives", "fit_dual_metric_newton", "starting_point"]
