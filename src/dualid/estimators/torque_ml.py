"""``dm``'s fit where the residual is not its modelled noise: the residual as a torque noise of full unknown covariance.

Unmodelled torques (a payload the model lacks, a torque sensor's gain and offset) correlate the joints' residuals.
The Gaussian likelihood of r_i ~ N(0, Σ) with Σ unknown, Σ profiled out (Σ̂ = S(θ)/N), is maximised at the minimum
of log det S(θ), S(θ) = Σ_i r_i r_iᵀ: the fixed point of WLS in its own residual covariance, and the same minimiser in
every constant linear chart of the coordinates (log det moves by a constant). S is a quadratic in θ, so one pass over
the data gives every derivative (``pair_statistics``).
"""

from __future__ import annotations

import numpy as np

from dualid.estimators.newton.objective import CHUNK, Derivatives
from dualid.linalg import NotPositiveDefinite
from dualid.problem import additive, sample_blocks

CURVATURE_FLOOR = 1e-6  # the handed Hessian's smallest eigenvalue in its diagonal scaling (covariance_ml_derivatives)


def pair_statistics(problem, theta0: np.ndarray, chunk: int = CHUNK) -> tuple:
    """(θ0, Σ vec Y_i vec Y_iᵀ (np, np), Σ vec Y_i r_iᵀ (np, n), Σ r_i r_iᵀ (n, n)), r_i at θ0: S(θ) about θ0, one pass.
    About θ0, not from Σ τ_i τ_iᵀ: there S would be a difference of terms ~1/(noise share) larger than itself."""
    theta0 = np.asarray(theta0, dtype=float)
    return (theta0, *_pair_sums(problem, theta0, chunk))


@additive
def _pair_sums(problem, theta0: np.ndarray, chunk: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n, p = problem.n, problem.p
    G, D, S = np.zeros((n * p, n * p)), np.zeros((n * p, n)), np.zeros((n, n))
    for block, rows, _ in sample_blocks(problem, chunk):
        Y = block.Y[rows]
        r = (Y.reshape(-1, p) @ theta0).reshape(-1, n) - block.tau[rows]
        Y = Y.reshape(-1, n * p)
        G, D, S = G + Y.T @ Y, D + Y.T @ r, S + r.T @ r
    return G, D, S


def covariance_ml_derivatives(stats, theta: np.ndarray, order: int = 2) -> Derivatives:
    """f(θ) = det S(θ)^(1/n), S from ``pair_statistics`` (positive and of the size of Σ‖r_i‖², as the interior
    point's relative stopping test wants); NotPositiveDefinite where S is not. With E_akb = ∂s_ab/∂θ_k, W = S⁻¹:

        ∇ log det S = Σ W_ab E_ab,    ∇² log det S = 2 Σ W_ab G_ab − Σ W_ac W_bd E_ab E_cdᵀ

    The Hessian handed on is the exact one with its eigenvalues replaced by their absolute values, at least
    CURVATURE_FLOOR (in its diagonal scaling): along negative curvature a step, not a jump to the constraints'
    boundary. The PSD first term alone, or the exact Hessian shifted to positive definite, crept along the boundary
    (300 iterations on 6-DoF arms); a floor of 1e-10 let a column at rounding (a mass whose torques cancel) propose
    steps no line search could shorten enough; 1e-6 converged on every statistical-benchmark fit."""
    theta0, G, D0, S0 = stats
    n, p = S0.shape[0], len(theta)
    T, D0, step = G.reshape(n, p, n, p), D0.reshape(n, p, n), np.asarray(theta) - theta0
    D = D0 + T @ step  # D_akb = Σ_i Y_iak r_ib(θ)
    U = np.einsum("k,akb->ab", step, D0 + 0.5 * (T @ step))  # s_ab(θ) = s_ab(θ0) + U_ab + U_ba
    S = S0 + U + U.T
    try:
        L = np.linalg.cholesky(0.5 * (S + S.T))
    except np.linalg.LinAlgError:
        raise NotPositiveDefinite from None
    f = float(np.exp(2.0 * np.sum(np.log(np.diag(L))) / n))
    if not order:
        return Derivatives(f)
    W = np.linalg.inv(S)
    E = D + D.transpose(2, 1, 0)
    grad = np.einsum("ab,akb->k", W, E)
    H = 2.0 * np.einsum("ab,akbl->kl", W, T) + np.outer(grad, grad) / n  # f = exp(log det S / n): the outer product
    H -= np.einsum("ckd,cld->kl", np.einsum("ac,akb,bd->ckd", W, E, W), E)
    d = np.sqrt(np.abs(np.diag(H))) + (np.diag(H) == 0)
    w, U = np.linalg.eigh(0.5 * (H + H.T) / np.outer(d, d))
    H = (U * np.maximum(np.abs(w), CURVATURE_FLOOR)) @ U.T * np.outer(d, d)
    return Derivatives(f, f / n * grad, f / n * H)
