"""f(θ) = Σ r_iᵀ C_i(θ)⁻¹ r_i with the physical noise model C_i(θ) = Σ_τ + M_i(θ) Σ_a M_i(θ), and its derivatives.

r_i = Y_i θ − τ_i. Torque noise ε (covariance Σ_τ, a covector covariance) and noise δa in the accelerations inside
Y_i (covariance Σ_a, a vector covariance; e.g. encoders differentiated twice) give, at the true θ,
r_i = M_i(θ) δa_i − ε_i, whose covariance is C_i(θ). Minimising f with C depending on θ is weighted total least
squares (Deming regression): the weight shrinks as the fitted inertia grows, which undoes least squares'
errors-in-variables attenuation. Σ_τ → 0 with Σ_a = M⁻¹ frozen is the paper's objective; Σ_a = 0 is WLS.

With w_i = C_i⁻¹ r_i, u_i = Σ_a M_i w_i, P_i = [M_ik w_i]_k and Q_i = [M_ik u_i]_k (n × p), C_ik = M_ik Σ_a M_i +
M_i Σ_a M_ik, and D_i = Y_i − C_ik w_i = Y_i − Q_i − M_i Σ_a P_i:

    ∂f/∂θ_k       = Σ_i 2 Y_ikᵀ w_i − 2 u_iᵀ M_ik w_i
    ∂²f/∂θ_k∂θ_l  = Σ_i 2 D_ikᵀ C_i⁻¹ D_il − 2 P_ikᵀ Σ_a P_il        (M affine in θ: exact)

The first term is PSD (the Gauss–Newton part); f is not convex, so the Hessian handed to the interior point is the
exact one where it is positive definite and the Gauss–Newton part otherwise. Σ_τ and Σ_a are constant (n, n) in
the chart the problem is in; every term transforms so that f is the same in every chart when they are carried
covariantly (Σ_τ' = BᵀΣ_τB, Σ_a' = B⁻¹Σ_aB⁻ᵀ).
"""

from __future__ import annotations

import numpy as np

from dualid.estimators.newton.objective import CHUNK, cholesky_batch, Derivatives, forward_substitute, NotPositiveDefinite, tri_inverse
from dualid.problem import additive, sample_blocks


def noise_model_covariance(M: np.ndarray, sigma_tau: np.ndarray, sigma_a: np.ndarray) -> np.ndarray:
    """C_i = Σ_τ + M_i Σ_a M_i for M (c, n, n)."""
    C = sigma_tau + M @ sigma_a @ M
    return 0.5 * (C + np.swapaxes(C, 1, 2))


def noise_model_derivatives(problem, theta: np.ndarray, sigma_tau: np.ndarray, sigma_a: np.ndarray, order: int = 2,
                            chunk: int = CHUNK) -> Derivatives:
    """f (and ∇f and the Hessian for order 2; see the module doc), accumulated over chunks of samples.

    Raises NotPositiveDefinite when some C_i(θ) is not positive definite (Σ_τ singular and M_i(θ) singular)."""
    f, grad, gn, neg = noise_model_sums(problem, np.asarray(theta, dtype=float), sigma_tau, sigma_a, order, chunk)
    if not np.isfinite(f):
        raise NotPositiveDefinite
    if not order:
        return Derivatives(f)
    gn = 0.5 * (gn + gn.T)
    exact = gn - 0.5 * (neg + neg.T)
    return Derivatives(f, grad, exact if _positive_definite(exact) else gn)


@additive
def noise_model_sums(problem, theta: np.ndarray, sigma_tau: np.ndarray, sigma_a: np.ndarray, order: int,
                     chunk: int) -> tuple:
    """(f, ∇f, Gauss–Newton part, negative part) summed over the samples (None beyond f for order 0): one pass,
    run where the data live on a problem spread over partitions."""
    p = problem.p
    f = 0.0
    grad = np.zeros(p) if order else None
    gn = np.zeros((p, p)) if order else None
    neg = np.zeros((p, p)) if order else None
    for block, rows, _ in sample_blocks(problem, chunk):
        Y = block.Y[rows]
        c, n = Y.shape[0], Y.shape[1]
        r = (Y.reshape(c * n, p) @ theta).reshape(c, n) - block.tau[rows]
        M = block.metric.evaluate(theta, rows)
        L = cholesky_batch(noise_model_covariance(M, sigma_tau, sigma_a))
        if not order:
            z = forward_substitute(L, r)
            f += float(np.sum(z * z))
            continue
        Li = tri_inverse(L)
        z = np.einsum("cab,cb->ca", Li, r)
        f += float(np.sum(z * z))
        w = np.einsum("cba,cb->ca", Li, z)  # C⁻¹ r
        u = np.einsum("cab,cb->ca", M, w) @ sigma_a  # Σ_a M w (Σ_a symmetric)
        P = block.metric.apply(w, rows)  # [M_k w]_k (c, n, p)
        Q = block.metric.apply(u, rows)  # [M_k u]_k
        grad += 2.0 * (w.reshape(-1) @ Y.reshape(-1, p)) - 2.0 * np.einsum("ca,cak->k", u, P)
        SP = np.matmul(sigma_a, P)  # Σ_a P (c, n, p)
        D = Y - Q - _bmm(M, SP)
        Z = _bmm(Li, D).reshape(-1, p)
        gn += 2.0 * (Z.T @ Z)
        neg += 2.0 * (P.reshape(-1, p).T @ SP.reshape(-1, p))
    return f, grad, gn, neg


def _bmm(A: np.ndarray, X: np.ndarray) -> np.ndarray:
    """A_i X_i for A (c, n, n), X (c, n, p): a loop over the small n, vectorised over samples and columns (numpy's
    batched matmul of many 7×7 by 7×p products is several times slower)."""
    out = A[:, :, 0, None] * X[:, None, 0, :]
    for b in range(1, A.shape[2]):
        out += A[:, :, b, None] * X[:, None, b, :]
    return out


def _positive_definite(K: np.ndarray) -> bool:
    d = np.sqrt(np.abs(np.diag(K)))
    d[d == 0] = 1.0
    try:
        np.linalg.cholesky(K / np.outer(d, d) - 1e-10 * np.eye(len(K)))
    except np.linalg.LinAlgError:
        return False
    return True


def noise_model_objective(problem, theta, sigma_tau, sigma_a, chunk: int = CHUNK) -> float:
    """f(θ), +inf where some C_i(θ) is not positive definite."""
    try:
        return noise_model_derivatives(problem, theta, sigma_tau, sigma_a, 0, chunk).f
    except NotPositiveDefinite:
        return np.inf


@additive
def noise_model_scale(problem, theta, sigma_tau, sigma_a, chunk: int = CHUNK) -> float:
    """Σ τ_iᵀ C_i(θ)⁻¹ τ_i: the size of the measured forces in the noise model's metric (the objective's scale)."""
    total = 0.0
    for block, rows, _ in sample_blocks(problem, chunk):
        L = cholesky_batch(noise_model_covariance(block.metric.evaluate(theta, rows), sigma_tau, sigma_a))
        z = forward_substitute(L, block.tau[rows])
        total += float(np.sum(z * z))
    return total
