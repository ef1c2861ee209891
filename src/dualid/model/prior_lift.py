"""Lift a geometric prior off the consistency boundary, chart-invariantly (issue 12, point 3).

The log-det and pullback priors (``consistency.prior_blocks``) use C_b0⁻¹, the inverse of each body's
pseudo-inertia at θ₀. A prior taken from a constrained fit sits on the cone boundary: a body's centred
second moments Σ_c (eigenvalues σ₁ ≥ σ₂ ≥ σ₃ ≥ 0, the mass distribution's principal spreads) have σ₃ ≈ 0, so C_b0
has a condition number ~1e11 and both Clarabel and dualid's interior-point method fail on the prior term.

``lift_prior`` raises every body's principal second moments to at least ``floor · σ₁`` (the body's largest),
keeping its mass, centre of mass and principal axes. In terms of the pseudo-inertia this is a floor on the
generalised eigenvalues of C_b0 against a reference body of the same mass and centre of mass with isotropic
spread (σ₁ + σ₂ + σ₃)/3, so it commutes with any rigid change of the body frame and any change of units: the
lifted prior is the same body in every chart. Bodies with m ≤ 0 or σ₁ = 0 (a point mass: no length scale of
their own) are left as they are and reported. Non-rigid blocks (drag, joint terms) are not changed.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from dualid.model.parameters import ParameterSpace

DEFAULT_FLOOR = 1e-6  # σ_min / σ_max below this is lifted; a real thin rod (r/L = 0.01) has ~1e-4 and is untouched


def centred_moments(theta_b: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """(m, c (3,), σ (3,) ascending, R (3, 3) principal axes) of a rigid body's 10 parameters (m > 0)."""
    inertia = pin.Inertia.FromDynamicParameters(np.asarray(theta_b, dtype=float))
    Ic = np.array(inertia.inertia)
    S = 0.5 * np.trace(Ic) * np.eye(3) - Ic  # Σ_c = ∫ρ (x−c)(x−c)ᵀ
    sigma, R = np.linalg.eigh(0.5 * (S + S.T))
    return float(inertia.mass), np.array(inertia.lever), sigma, R


def lift_prior(parameters: ParameterSpace, theta0: np.ndarray, floor: float = DEFAULT_FLOOR) -> tuple[np.ndarray, dict]:
    """(θ₀ with every rigid body's σ_k ≥ floor·σ_max, report {body: {...}} of the bodies changed or skipped).

    floor = 0 returns θ₀ unchanged and an empty report."""
    theta = np.array(theta0, dtype=float)
    report: dict = {}
    if floor <= 0:
        return theta, report
    for b in parameters.blocks:
        if b.kind != "rigid_body":
            continue
        idx = list(b.indices)
        th = theta[idx]
        if not th[0] > 0:
            report[b.name] = {"lifted": False, "reason": f"mass {th[0]:.3g} ≤ 0"}
            continue
        m, c, sigma, R = centred_moments(th)
        if not sigma[-1] > 0:
            report[b.name] = {"lifted": False, "reason": "point mass (no second moment to scale a floor by)"}
            continue
        ratio = float(sigma[0] / sigma[-1])
        if ratio >= floor:
            continue
        lifted = np.maximum(sigma, floor * sigma[-1])
        S = (R * lifted) @ R.T
        Ic = np.trace(S) * np.eye(3) - S
        theta[idx] = pin.Inertia(m, c, Ic).toDynamicParameters()
        report[b.name] = {"lifted": True, "sigma_ratio_before": ratio, "sigma_ratio_after": float(floor)}
    return theta, report
