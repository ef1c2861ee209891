"""The linear algebra of the interior-point iterations on the feasible set: the duality gap, barrier and HKM dual
steps (the Newton matrices: ``dualid.linalg.NewtonSystem``, ``SecantCorrection``)."""

from __future__ import annotations

import numpy as np

from dualid.model.consistency import FeasibleSet, max_step_blocks


def dual_direction(cons: FeasibleSet, Z, z, Cinv, s, d, target):
    """HKM direction: ΔZ = σμ C⁻¹ − Z − sym(Z ΔC C⁻¹); Δz = σμ/s − z − (z/s) G d."""
    dZ = []
    for c, Zb, Ci in zip(cons.lmis, Z, Cinv):
        X = Zb @ c.dC(d) @ Ci
        dZ.append(target * Ci - Zb - 0.5 * (X + X.T))
    dz = target / s - z - (z / s) * (cons.G @ d) if len(s) else np.zeros(0)
    return dZ, dz


def dual_max_step(Z, z, dZ, dz) -> float:
    alpha = max_step_blocks(Z, dZ)
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
