"""The objectives' sums over the samples, in one pass each: f(θ) = Σ r_iᵀ M_i(θ)⁻¹ r_i with its gradient and (exact)
Hessian, and the sufficient statistics of the quadratic objectives H = Σ Y_iᵀ W Y_i, g = Σ Y_iᵀ W τ_i,
c = Σ τ_iᵀ W τ_i (or the energy residual's, v_iᵀ r_i).

The dual-metric derivatives use per-chunk kernels arranged for numpy's batched small products (the same mathematics
as ``AffineMetric.apply_quad``, which the tests compare with; measured in benchmarks/derivatives_speed.md): M_i(θ)
without explicit symmetrisation (``AffineMetric.evaluate(θ, rows, symmetric=False)``: the Cholesky reads the lower
triangle only), [M_ik w_i]_k written straight into one (c, n, p) array, and Σ_i w_iᵀ M_ik w_i by one GEMM for the
terms whose E_k are shared by all samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.linalg import NotPositiveDefinite, cholesky_batch, forward_substitute, tri_inverse
from dualid.model.metric import AffineMetric, dense_apply
from dualid.problem import IdentificationProblem, additive, sample_blocks

CHUNK = 1024  # samples per block of a pass: the per-chunk temporaries (c·n·p floats each) stay in cache
# (benchmarks/derivatives_speed.md: 2.7 µs per sample against 3.1 µs with 4,096 on the benchmark Crazyflie)
ROUNDING = 1e-12  # a least-squares f(θ) ≤ this × f(0) (exact data) is optimal to that accuracy: f ≥ 0 (no iterations)


def stopping_scale(f_min: float, c: float) -> float:
    """A least-squares fit's stopping scale: its unconstrained minimum (≈ f*; c = f(0) ≫ f* at high SNR), ≥ rounding."""
    return max(float(f_min), ROUNDING * float(c), 1e-300)


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


def value_or_inf(objective, theta: np.ndarray) -> float:
    """objective(θ, 0).f for an objective(θ, order) → Derivatives; +inf outside its domain (NotPositiveDefinite)."""
    try:
        return objective(theta, 0).f
    except NotPositiveDefinite:
        return np.inf


def objective_value(problem, theta, chunk) -> float:
    """f(θ), +inf outside the domain."""
    return value_or_inf(lambda th, order: dual_metric_derivatives(problem, th, order, chunk), theta)


@additive
def force_scale(problem, theta, chunk) -> float:
    """Σ τ_iᵀ M_i(θ)⁻¹ τ_i: the size of the measured forces in the dual metric (the objective's scale)."""
    total = 0.0
    for block, rows, _ in sample_blocks(problem, chunk):
        L = np.linalg.cholesky(block.metric.evaluate(theta, rows, symmetric=False))
        z = forward_substitute(L, block.tau[rows])  # L⁻¹ τ_i
        total += float(np.sum(z * z))
    return total


def residual_jacobian(metric: AffineMetric, Y: np.ndarray, w: np.ndarray, rows) -> tuple[np.ndarray, np.ndarray]:
    """(D = Y_i − [M_ik w_i]_k (c, n, p), Σ_i w_iᵀ M_ik w_i (p,)): ``AffineMetric.apply_quad(w, rows, Y.copy())``
    without the copy of Y. Y (c, n, p) is not modified."""
    K = metric.dense_rows(rows)
    if K is not None:  # a small system: [M_ik w_i]_k in one batched product (``AffineMetric.dense_rows``)
        P = dense_apply(K, w)
        wMw = np.einsum("ca,cak->k", w, P)
        return np.subtract(Y, P, out=P), wMw
    c, n, p = Y.shape
    A = np.zeros((c, n, p))  # [M_ik w_i]_k; columns no term touches stay 0
    wMw = np.zeros(p)
    written = np.zeros(p, dtype=bool)
    for t, u, Eu in metric.factors(w, rows):  # u_i = J_i w_i (c, d), E_k u_i (c, k, d)
        J = t.J[rows]  # (c, d, n)
        k = len(t.indices)
        quad = np.einsum("ckd,cd->k", Eu, u) if t.per_sample else np.einsum("kde,de->k", t.E, u.T @ u)
        idx = list(t.indices)
        wMw[idx] += quad
        JtEu = np.swapaxes(J, 1, 2), np.swapaxes(Eu, 1, 2)  # J_iᵀ E_k u_i = (n, d)(d, k)
        consecutive = idx == list(range(idx[0], idx[0] + k))
        if consecutive and not written[idx].any():
            np.matmul(*JtEu, out=A[:, :, idx[0]:idx[0] + k])
        else:  # parameters shared with an earlier term: accumulate
            A[:, :, idx] += np.matmul(*JtEu)
        written[idx] = True
    return np.subtract(Y, A, out=A), wMw


@dataclass(frozen=True)
class Statistics:
    """Sufficient statistics of Σ r_iᵀ W_i r_i = θᵀHθ − 2gᵀθ + c, and the weight they came from."""

    H: np.ndarray  # (p, p)
    g: np.ndarray  # (p,)
    c: float
    W: np.ndarray | None = None  # (n, n) constant weight; None: identity (or energy if energy=True)
    energy: bool = False

    def objective(self, problem: IdentificationProblem, theta: np.ndarray) -> float:
        """Σ r_iᵀ W_i r_i from the residuals (no cancellation, unlike θᵀHθ − 2gᵀθ + c)."""
        return _residual_sum(problem, theta, self.W, self.energy)


@additive
def _residual_sum(problem, theta: np.ndarray, W: np.ndarray | None, energy: bool) -> float:
    f = 0.0
    for block, rows, _ in sample_blocks(problem, 16384):
        r = block.Y[rows] @ theta - block.tau[rows]
        if energy:
            f += float(np.sum(np.einsum("na,na->n", block.v[rows], r) ** 2))
        elif W is None:
            f += float(np.sum(r * r))
        else:
            f += float(np.einsum("na,ab,nb->", r, W, r))
    return f


def statistics(problem: IdentificationProblem, W: np.ndarray | None = None, chunk: int = 16384) -> Statistics:
    """H, g, c for a constant weight W (n, n) (None: identity), accumulated in chunks of samples."""
    F = None
    if W is not None:  # W = F Fᵀ (eigen-factor, W ⪰ 0): Σ Y_iᵀ W Y_i = Σ (Fᵀ Y_i)ᵀ (Fᵀ Y_i), one GEMM per chunk
        lam, U = np.linalg.eigh(0.5 * (np.asarray(W, dtype=float) + np.asarray(W, dtype=float).T))
        F = U * np.sqrt(np.clip(lam, 0.0, None))
    H, g, c = weighted_sums(problem, F, chunk)
    return Statistics(0.5 * (H + H.T), g, c, W)


@additive
def weighted_sums(problem, F: np.ndarray | None, chunk: int, energy: bool = False) -> tuple:
    """Σ A_iᵀA_i, Σ A_iᵀt_i, Σ t_iᵀt_i with A_i = FᵀY_i, t_i = Fᵀτ_i (F None: the identity); with energy=True also
    the energy residual's Σ e_i e_iᵀ, Σ e_i y_i (``energy_statistics``) from the same pass."""
    p = problem.p
    H, g, c, He, ge = np.zeros((p, p)), np.zeros(p), 0.0, np.zeros((p, p)), np.zeros(p)
    for block, rows, _ in sample_blocks(problem, chunk):
        if energy:
            e, y = _energy_rows(block, rows)
            He, ge = He + e.T @ e, ge + e.T @ y
        Yc, tau = block.Y[rows], block.tau[rows]
        if F is not None:
            Yc, tau = np.matmul(F.T, Yc), tau @ F
        A, t = Yc.reshape(-1, p), tau.reshape(-1)
        H += A.T @ A
        g += A.T @ t
        c += float(t @ t)
    return (H, g, c, He, ge) if energy else (H, g, c)


def _energy_rows(block, rows) -> tuple[np.ndarray, np.ndarray]:
    """The energy residual's rows e_i = Y_iᵀ v_i and targets y_i = v_iᵀ τ_i of a block's samples."""
    return (np.einsum("nap,na->np", block.Y[rows], block.v[rows]),
            np.einsum("na,na->n", block.tau[rows], block.v[rows]))


def energy_statistics(problem: IdentificationProblem, chunk: int = 16384) -> Statistics:
    """W_i = v_i v_iᵀ: the rows e_i = Y_iᵀ v_i and targets v_iᵀ τ_i, accumulated in chunks of samples."""
    return Statistics(*_energy_sums(problem, chunk), energy=True)


@additive
def _energy_sums(problem, chunk: int) -> tuple[np.ndarray, np.ndarray, float]:
    p = problem.p
    H, g, c = np.zeros((p, p)), np.zeros(p), 0.0
    for block, rows, _ in sample_blocks(problem, chunk):
        e, y = _energy_rows(block, rows)
        H += e.T @ e
        g += e.T @ y
        c += float(y @ y)
    return H, g, c
