"""The one rank rule of dualid, and the pseudo-inverse that follows it.

A direction of θ is *identifiable* when, after scaling the regressor's columns to unit norm, its
singular value exceeds ``RANK_RTOL`` times the largest one (a condition number of at most 1e7).
For a Gram (normal) matrix H = AᵀA the singular values are √λ, so the same rule reads
λ > RANK_RTOL² λ_max after the matching diagonal (Jacobi) scaling of H. The value sits above the
resolution of a Gram matrix in double precision (√eps ≈ 1.5e-8 relative in σ), so the rank is
the same whether it is computed from Y or from YᵀWY.

Also the batched kernels for many tiny positive-definite matrices (one per sample): Cholesky, triangular inverse
and forward substitution, vectorised over the samples; and the solves with PSD, possibly singular matrices
(``solve_psd``; ``NewtonSystem``, the interior points' Newton matrices, and their ``SecantCorrection``).
"""

from __future__ import annotations

import numpy as np

RANK_RTOL = 1e-7  # σ_k / σ_max on unit-norm columns below which a direction is not identifiable


def rank_from_singular_values(s: np.ndarray) -> int:
    """Rank of a matrix (with unit-norm columns) from its singular values s."""
    s = np.asarray(s, dtype=float)
    if s.size == 0:
        return 0
    return int(np.sum(s > RANK_RTOL * max(float(s.max()), 1e-300)))


def jacobi_scale(H: np.ndarray) -> np.ndarray:
    """d with H / (d dᵀ) of unit diagonal (zero diagonal entries keep scale 1)."""
    d = np.sqrt(np.clip(np.diag(H), 0, None))
    d[d == 0] = 1.0
    return d


def gram_eigh(H: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(λ, U, keep) of a symmetric PSD matrix H (as given, no scaling): keep marks the eigenvalues
    above RANK_RTOL² λ_max, the directions the rank rule calls identifiable."""
    w, U = np.linalg.eigh(0.5 * (H + H.T))
    keep = w > RANK_RTOL**2 * max(float(w.max()) if w.size else 0.0, 1e-300)
    return w, U, keep


def gram_rank(H: np.ndarray) -> int:
    """Rank of a PSD Gram matrix H = AᵀWA under the rule, after Jacobi scaling."""
    d = jacobi_scale(H)
    return int(np.sum(gram_eigh(H / np.outer(d, d))[2]))


def pinv_psd(H: np.ndarray) -> tuple[np.ndarray, int]:
    """(H⁺, rank) of a PSD matrix under the rule (computed on the Jacobi-scaled matrix)."""
    d = jacobi_scale(H)
    w, U, keep = gram_eigh(H / np.outer(d, d))
    Hs_pinv = (U[:, keep] / w[keep]) @ U[:, keep].T
    return Hs_pinv / np.outer(d, d), int(keep.sum())


class NotPositiveDefinite(Exception):
    """A matrix of a batch is not positive definite (e.g. some M_i(θ): θ outside an objective's domain)."""


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


def cholesky_inverse(L: np.ndarray) -> np.ndarray:
    """(L Lᵀ)⁻¹ (c, n, n) from the Cholesky factor L: L⁻ᵀ L⁻¹ (LAPACK's batched inverse is ~10× slower for n ≤ 8)."""
    Li = tri_inverse(L)
    return np.swapaxes(Li, 1, 2) @ Li


def forward_substitute(L: np.ndarray, r: np.ndarray) -> np.ndarray:
    """L⁻¹ r for r (c, n)."""
    z = np.empty_like(r)
    for a in range(L.shape[1]):
        acc = r[:, a].copy()
        for b in range(a):
            acc -= L[:, a, b] * z[:, b]
        z[:, a] = acc / L[:, a, a]
    return z


def solve_psd(K: np.ndarray, b: np.ndarray, rtol: float = 1e-13) -> np.ndarray:
    """K⁺ b for K ⪰ 0 (Jacobi-scaled; directions with eigenvalue < rtol·max are left out)."""
    d = jacobi_psd(K)
    lam, U = np.linalg.eigh(K / np.outer(d, d))
    keep = lam > rtol * max(lam.max(), 1e-300)
    x = U[:, keep] @ ((U[:, keep].T @ (b / d)) / lam[keep])
    return x / d


def jacobi_psd(K: np.ndarray) -> np.ndarray:
    """√diag(K) of a PSD K, with (numerically) empty columns given the largest scale so they drop out."""
    d = np.sqrt(np.abs(np.diag(K)))
    top = d.max() if d.size and d.max() > 0 else 1.0
    d[d <= 1e-7 * top] = top
    return d


def positive_definite(K: np.ndarray, rtol: float = 1e-10) -> bool:
    """Is K (Jacobi-scaled) positive definite with a margin of rtol? A Cholesky attempt: the inertia test."""
    d = jacobi_psd(K)
    try:
        np.linalg.cholesky(K / np.outer(d, d) - rtol * np.eye(len(K)))
    except np.linalg.LinAlgError:
        return False
    return True


class NewtonSystem:
    """Solves K x = b for the PSD Newton matrix K: Jacobi-scaled Cholesky of K + δ·diag(K), δ = 1e-12 (a
    Levenberg term that leaves non-identifiable directions with a zero step instead of failing); eigen
    pseudo-inverse if even that is not positive definite numerically."""

    def __init__(self, K: np.ndarray, levenberg: float = 1e-12):
        self.d = jacobi_psd(K)
        Ks = K / np.outer(self.d, self.d)
        if levenberg:
            Ks[np.diag_indices_from(Ks)] += levenberg
        try:
            self.L = np.linalg.cholesky(Ks)
            self.U = None
        except np.linalg.LinAlgError:
            lam, U = np.linalg.eigh(Ks)
            keep = lam > 1e-13 * max(lam.max(), 1e-300)
            self.L, self.U, self.lam = None, U[:, keep], lam[keep]

    def solve(self, b: np.ndarray) -> np.ndarray:
        from scipy.linalg import solve_triangular

        bs = b / self.d
        if self.L is not None:
            x = solve_triangular(self.L.T, solve_triangular(self.L, bs, lower=True), lower=False)
        else:
            x = self.U @ ((self.U.T @ bs) / self.lam)
        return x / self.d


class SecantCorrection:
    """A ≈ ∇²f − H, the curvature that the handed Hessian H leaves out (e.g. a Gauss–Newton H's), learnt along the
    steps by NL2SOL's structured secant update (Dennis, Gay & Welsch; Nocedal & Wright §10.3): A₊ s = y#, y# = ∇f₊ −
    ∇f − H₊ s, as the symmetric rank-2 (PSB) correction of least change in the unit-free metric W = diag(H) (defined
    also where f's curvature along s is negative), A first sized by min(1, |sᵀy#| / |sᵀAs|)."""

    def __init__(self, p: int):
        self.A = np.zeros((p, p))

    def update(self, s: np.ndarray, y: np.ndarray, hess_new: np.ndarray) -> None:
        y_sharp = y - hess_new @ s
        v = jacobi_psd(hess_new) ** 2 * s  # W s
        vs = float(v @ s)
        if not vs > 0:  # a zero step
            return
        sAs = float(s @ self.A @ s)
        if sAs:
            self.A *= min(1.0, abs(float(s @ y_sharp)) / abs(sAs))
        r = y_sharp - self.A @ s
        self.A += (np.outer(r, v) + np.outer(v, r)) / vs - float(r @ s) * np.outer(v, v) / vs**2


def triangular_factor(blocks, width: int) -> np.ndarray:
    """R with RᵀR = Σ AᵀA over the row blocks A (each (m, width)): TSQR, R = qr([R; A]) block by block, so the
    stacked matrix is never formed (memory O(block · width))."""
    R = np.zeros((0, width))
    for A in blocks:
        B = np.empty((len(R) + len(A), width), order="F")  # LAPACK's layout: numpy's qr copies C-ordered input
        B[:len(R)], B[len(R):] = R, A
        R = np.linalg.qr(B, mode="r")
    return R
