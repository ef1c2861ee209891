"""The linear algebra of the interior-point iterations: the (PSD, possibly singular) Newton matrices (Jacobi-scaled,
with a pseudo-inverse fallback) and their secant correction, and the duality gap, barrier and HKM dual steps."""

from __future__ import annotations

import numpy as np

from dualid.linalg import jacobi_psd
from dualid.model.consistency import FeasibleSet, max_step_psd, max_step_psd_batched


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


def dual_direction(cons: FeasibleSet, Z, z, Cinv, s, d, target):
    """HKM direction: ΔZ = σμ C⁻¹ − Z − sym(Z ΔC C⁻¹); Δz = σμ/s − z − (z/s) G d."""
    dZ = []
    for c, Zb, Ci in zip(cons.lmis, Z, Cinv):
        X = Zb @ c.dC(d) @ Ci
        dZ.append(target * Ci - Zb - 0.5 * (X + X.T))
    dz = target / s - z - (z / s) * (cons.G @ d) if len(s) else np.zeros(0)
    return dZ, dz


def dual_max_step(Z, z, dZ, dz) -> float:
    alpha = np.inf
    if Z and len({Zb.shape for Zb in Z}) == 1:  # equal blocks: one batched call
        alpha = max_step_psd_batched(np.stack(Z), np.stack(dZ))
    else:
        for Zb, dZb in zip(Z, dZ):
            alpha = min(alpha, max_step_psd(Zb, dZb))
    neg = dz < 0
    if neg.any():
        alpha = min(alpha, float(np.min(-z[neg] / dz[neg])))
    return alpha


def min_centrality(cons: FeasibleSet, theta, Z, z, s) -> float:
    """min over blocks of λ_min(L_bᵀ Z_b L_b) (C_b = L_b L_bᵀ) and over rows of s_j z_j: μ on the central path; 0
    when a block no longer factors (an iterate on its boundary by rounding), so that a centring step follows."""
    try:
        w = [float(np.linalg.eigvalsh(L.T @ Zb @ L)[0])
             for L, Zb in ((np.linalg.cholesky(c.C(theta)), Zb) for c, Zb in zip(cons.lmis, Z))]
    except np.linalg.LinAlgError:
        return 0.0
    if len(s):
        w.append(float(np.min(s * z)))
    return min(w) if w else np.inf


def duality_gap(cons: FeasibleSet, theta, Z, z) -> float:
    gap = sum(float(np.sum(c.C(theta) * Zb)) for c, Zb in zip(cons.lmis, Z))
    if len(z):
        gap += float((cons.G @ theta + cons.h) @ z)
    return gap


def barrier(cons: FeasibleSet, theta) -> float:
    """−Σ log det C_b(θ) − Σ log s_j(θ); +inf outside the interior."""
    val = 0.0
    for c in cons.lmis:
        sign, logdet = np.linalg.slogdet(c.C(theta))
        if sign <= 0:
            return np.inf
        val -= logdet
    if len(cons.h):
        s = cons.G @ theta + cons.h
        if np.any(s <= 0):
            return np.inf
        val -= float(np.sum(np.log(s)))
    return val
