"""The one rank rule of dualid, and the pseudo-inverse that follows it.

A direction of θ is *identifiable* when, after scaling the regressor's columns to unit norm, its
singular value exceeds ``RANK_RTOL`` times the largest one (a condition number of at most 1e7).
For a Gram (normal) matrix H = AᵀA the singular values are √λ, so the same rule reads
λ > RANK_RTOL² λ_max after the matching diagonal (Jacobi) scaling of H. The value sits above the
resolution of a Gram matrix in double precision (√eps ≈ 1.5e-8 relative in σ), so the rank is
the same whether it is computed from Y or from YᵀWY.
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
