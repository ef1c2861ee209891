"""Per-chunk kernels of the dual-metric derivatives, arranged for numpy's batched small products.

Same mathematics as ``AffineMetric.apply_quad`` (the reference the tests compare with), re-arranged where that was
measured to be cheaper on a 4,096-sample Crazyflie chunk (n = 8, p = 30, three bodies; benchmarks/derivatives_speed.md):

- M_i(θ) = Σ_b J_bᵀ (G_b J_b): G_b J_b by one broadcast product, no explicit symmetrisation (the Cholesky reads
  the lower triangle only): 530 → 420 ns per sample; that is ``AffineMetric.evaluate(θ, rows, symmetric=False)``;
- [M_ik w_i]_k written straight into one (c, n, p) array (``matmul(…, out=…)``) and D = Y − A by one subtraction,
  instead of a copy of Y and a strided in-place update per body: 1,430 → 640 ns per sample;
- Σ_i w_iᵀ M_ik w_i = Σ_de E_k,de S_de with S = Σ_i u_i u_iᵀ (u_i = J_i w_i): one (d×c)(c×d) GEMM instead of a
  (c, k, d) einsum, for the terms whose E_k are shared by all samples.
"""

from __future__ import annotations

import numpy as np

from dualid.model.metric import AffineMetric


def residual_jacobian(metric: AffineMetric, Y: np.ndarray, w: np.ndarray, rows) -> tuple[np.ndarray, np.ndarray]:
    """(D = Y_i − [M_ik w_i]_k (c, n, p), Σ_i w_iᵀ M_ik w_i (p,)): ``AffineMetric.apply_quad(w, rows, Y.copy())``
    without the copy of Y. Y (c, n, p) is not modified."""
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
