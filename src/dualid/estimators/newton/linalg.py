"""Solves with the (PSD, possibly singular) Newton matrices: Jacobi-scaled, with a pseudo-inverse fallback."""

from __future__ import annotations

import numpy as np


def solve_psd(K: np.ndarray, b: np.ndarray, rtol: float = 1e-13) -> np.ndarray:
    """K⁺ b for K ⪰ 0 (Jacobi-scaled; directions with eigenvalue < rtol·max are left out)."""
    d = _jacobi(K)
    lam, U = np.linalg.eigh(K / np.outer(d, d))
    keep = lam > rtol * max(lam.max(), 1e-300)
    x = U[:, keep] @ ((U[:, keep].T @ (b / d)) / lam[keep])
    return x / d


def _jacobi(K: np.ndarray) -> np.ndarray:
    """√diag(K), with (numerically) empty columns given the largest scale so they drop out."""
    d = np.sqrt(np.abs(np.diag(K)))
    top = d.max() if d.size and d.max() > 0 else 1.0
    d[d <= 1e-7 * top] = top
    return d


class _NewtonSystem:
    """Solves K x = b for the PSD Newton matrix K: Jacobi-scaled Cholesky of K + δ·diag(K), δ = 1e-12 (a
    Levenberg term that leaves non-identifiable directions with a zero step instead of failing); eigen
    pseudo-inverse if even that is not positive definite numerically."""

    def __init__(self, K: np.ndarray, levenberg: float = 1e-12):
        self.d = _jacobi(K)
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


def positive_definite(K: np.ndarray, rtol: float = 1e-10) -> bool:
    """Is K (Jacobi-scaled) positive definite with a margin of rtol? A Cholesky attempt: the inertia test."""
    d = _jacobi(K)
    try:
        np.linalg.cholesky(K / np.outer(d, d) - rtol * np.eye(len(K)))
    except np.linalg.LinAlgError:
        return False
    return True


class SecantCorrection:
    """A ≈ ∇²f − H, the curvature that the handed Hessian H leaves out (e.g. the indefinite second-order part of a
    Gauss–Newton H), learnt from the gradients along the steps: the structured secant update of NL2SOL (Dennis,
    Gay & Welsch; Nocedal & Wright §10.3), A₊ s = y# with y# = ∇f₊ − ∇f − H₊ s and s the step, as the symmetric
    rank-2 (PSB) correction of least change in the metric W = diag(H) (Jacobi, so that it does not depend on the
    parameters' units, and defined where f's curvature along s is negative, unlike the y-weighted DGW/BFGS form),
    A first sized by min(1, |sᵀy#| / |sᵀAs|) as in NL2SOL."""

    def __init__(self, p: int):
        self.A = np.zeros((p, p))

    def update(self, s: np.ndarray, y: np.ndarray, hess_new: np.ndarray) -> None:
        y_sharp = y - hess_new @ s
        v = _jacobi(hess_new) ** 2 * s  # W s
        vs = float(v @ s)
        if not vs > 0:  # a zero step
            return
        sAs = float(s @ self.A @ s)
        if sAs:
            self.A *= min(1.0, abs(float(s @ y_sharp)) / abs(sAs))
        r = y_sharp - self.A @ s
        self.A += (np.outer(r, v) + np.outer(v, r)) / vs - float(r @ s) * np.outer(v, v) / vs**2
