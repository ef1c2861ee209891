"""f(θ) = Σ r_iᵀ M_i(θ)⁻¹ r_i with its gradient and (exact) Hessian, accumulated over chunks of samples."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.estimators.newton.kernels import residual_jacobian
from dualid.problem import IdentificationProblem, additive, sample_blocks

CHUNK = 1024  # samples per block of a pass: the per-chunk temporaries (Y_i, D_i, L⁻¹D_i: c·n·p floats each) stay in
# cache; on the benchmark Crazyflie a pass costs 2.7 µs per sample with 1,024 against 3.1 µs with 4,096
# (benchmarks/derivatives_speed.md)


class NotPositiveDefinite(Exception):
    """Some M_i(θ) is not positive definite (θ outside the domain)."""


# Per-sample matrices are tiny (n ≲ 10) and numerous, where LAPACK's per-matrix calls are slow: the
# kernels below loop over the small dimensions and vectorise over the samples of a chunk instead.
def cholesky_batch(M: np.ndarray) -> np.ndarray:
    """L (c, n, n) lower triangular with M_i = L_i L_iᵀ; raises NotPositiveDefinite."""
    try:
        L = np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        raise NotPositiveDefinite from None
    if not np.all(np.isfinite(np.diagonal(L, axis1=1, axis2=2))):
        raise NotPositiveDefinite
    return L


def tri_inverse(L: np.ndarray) -> np.ndarray:
    """L⁻¹ (c, n, n) of lower-triangular L, by substitution vectorised over the samples."""
    Lt = np.ascontiguousarray(np.moveaxis(L, 0, -1))  # (n, n, c): contiguous per-entry sample vectors
    n = Lt.shape[0]
    X = np.zeros_like(Lt)
    inv_diag = 1.0 / np.diagonal(Lt).T  # (n, c)
    for a in range(n):
        X[a, a] = inv_diag[a]
        for b in range(a):
            acc = Lt[a, b] * X[b, b]
            for k in range(b + 1, a):
                acc += Lt[a, k] * X[k, b]
            X[a, b] = -acc * inv_diag[a]
    return np.moveaxis(X, -1, 0)


def forward_substitute(L: np.ndarray, r: np.ndarray) -> np.ndarray:
    """L⁻¹ r for r (c, n)."""
    z = np.empty_like(r)
    for a in range(L.shape[1]):
        acc = r[:, a].copy()
        for b in range(a):
            acc -= L[:, a, b] * z[:, b]
        z[:, a] = acc / L[:, a, a]
    return z


@dataclass(frozen=True)
class Derivatives:
    f: float
    grad: np.ndarray | None = None  # (p,)
    hess: np.ndarray | None = None  # (p, p)


def dual_metric_derivatives(
    problem: IdentificationProblem, theta: np.ndarray, order: int = 2, chunk: int = CHUNK
) -> Derivatives:
    """f (and ∇f, ∇²f for order 2) accumulated over chunks of samples (memory O(chunk·n·p)).

    Raises NotPositiveDefinite when some M_i(θ) is not positive definite.
    """
    f, grad, hess = _derivative_sums(problem, np.asarray(theta, dtype=float), order, chunk)
    if not np.isfinite(f):
        raise NotPositiveDefinite
    return Derivatives(f, grad, None if hess is None else 0.5 * (hess + hess.T))


@additive
def _derivative_sums(problem, theta: np.ndarray, order: int, chunk: int):
    """(f, ∇f, ∇²f) summed over the samples (∇f, ∇²f None for order 0)."""
    n, p = problem.n, problem.p
    f = 0.0
    grad = np.zeros(p) if order else None
    hess = np.zeros((p, p)) if order else None
    for block, rows, _ in sample_blocks(problem, chunk):
        Y = block.Y[rows]  # (c, n, p)
        c = Y.shape[0]
        r = (Y.reshape(c * n, p) @ theta).reshape(c, n) - block.tau[rows]  # (c, n)
        L = cholesky_batch(block.metric.evaluate(theta, rows, symmetric=False))  # M_i = L_i L_iᵀ
        if not order:
            z = forward_substitute(L, r)  # L⁻¹ r
            f += float(np.sum(z * z))
            continue
        Li = tri_inverse(L)  # (c, n, n)
        z = np.einsum("cab,cb->ca", Li, r)  # L⁻¹ r
        f += float(np.sum(z * z))
        w = np.einsum("cba,cb->ca", Li, z)  # M⁻¹ r = L⁻ᵀ L⁻¹ r
        D, wMw = residual_jacobian(block.metric, Y, w, rows)  # D = Y_i − [M_ik w_i]_k, Σ_i w_iᵀ M_ik w_i
        grad += 2.0 * (w.reshape(-1) @ Y.reshape(-1, p)) - wMw
        Z = np.matmul(Li, D).reshape(-1, p)  # L⁻¹ (Y_i − M_ik w_i)
        hess += 2.0 * (Z.T @ Z)
    return f, grad, hess


def _objective(problem, theta, chunk) -> float:
    """f(θ), +inf outside the domain."""
    try:
        return dual_metric_derivatives(problem, theta, order=0, chunk=chunk).f
    except NotPositiveDefinite:
        return np.inf


@additive
def _force_scale(problem, theta, chunk) -> float:
    """Σ τ_iᵀ M_i(θ)⁻¹ τ_i: the size of the measured forces in the dual metric (the objective's scale)."""
    total = 0.0
    for block, rows, _ in sample_blocks(problem, chunk):
        L = np.linalg.cholesky(block.metric.evaluate(theta, rows, symmetric=False))
        z = forward_substitute(L, block.tau[rows])  # L⁻¹ τ_i
        total += float(np.sum(z * z))
    return total
