"""Lift a geometric prior off the consistency boundary, chart-invariantly.

The log-det and pullback priors (``consistency.prior_blocks``) use C_b0⁻¹, the inverse of each body's
pseudo-inertia at θ₀. A prior taken from a constrained fit sits on the cone boundary: a body's centred
second moments Σ_c (eigenvalues σ₁ ≥ σ₂ ≥ σ₃ ≥ 0, the mass distribution's principal spreads) have σ₃ ≈ 0, so C_b0
has a condition number ~1e11 and both Clarabel and dualid's interior-point method fail on the prior term.

``lift_prior`` raises every body's principal second moments to at least ``floor · m_b ℓ²``, keeping its mass,
centre of mass and principal axes; ℓ² = max_b σ₁,b / m_b is the largest squared radius of gyration among the
prior's bodies (the model's own length scale). In terms of the pseudo-inertia this is a floor on the generalised
eigenvalues of C_b0 against a reference body of the same mass and centre of mass with isotropic spread m_b ℓ², so
it commutes with any rigid change of a body frame and any change of units: the lifted prior is the same body in
every chart. A floor relative to each body's own largest moment is not enough: a constrained fit also shrinks
whole bodies to near point masses (σ₁ ~ 1e-8 m L², measured on the stress corpus). Bodies with m ≤ 0 are left as
they are and reported. Non-rigid blocks (drag, joint terms) are not changed.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from dualid.model.parameters import ParameterSpace

DEFAULT_FLOOR = 1e-4  # σ_k / (m ℓ²) below this is lifted (a rod with r/L ≥ 0.006 is not)


def centred_moments(theta_b: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """(m, c (3,), σ (3,) ascending, R (3, 3) principal axes) of a rigid body's 10 parameters (m > 0)."""
    inertia = pin.Inertia.FromDynamicParameters(np.asarray(theta_b, dtype=float))
    Ic = np.array(inertia.inertia)
    S = 0.5 * np.trace(Ic) * np.eye(3) - Ic  # Σ_c = ∫ρ (x−c)(x−c)ᵀ
    sigma, R = np.linalg.eigh(0.5 * (S + S.T))
    return float(inertia.mass), np.array(inertia.lever), sigma, R


def lift_prior(parameters: ParameterSpace, theta0: np.ndarray, floor: float = DEFAULT_FLOOR) -> tuple[np.ndarray, dict]:
    """(θ₀ with every rigid body's σ_k ≥ floor · m_b ℓ², report {body: {...}} of the bodies changed or skipped).

    ℓ² = max_b σ_max,b / m_b is the largest squared radius of gyration among the prior's bodies (one length scale
    for the whole model, so a body whose every second moment vanished, a point mass, is lifted too). floor = 0
    returns θ₀ unchanged and an empty report."""
    theta = np.array(theta0, dtype=float)
    report: dict = {}
    if floor <= 0:
        return theta, report
    bodies = {}
    for b in parameters.blocks:
        if b.kind != "rigid_body":
            continue
        idx = list(b.indices)
        if not theta[idx][0] > 0:
            report[b.name] = {"lifted": False, "reason": f"mass {theta[idx][0]:.3g} ≤ 0"}
            continue
        bodies[b.name] = (idx, *centred_moments(theta[idx]))
    ell2 = max((max(sigma[-1], 0.0) / m for _, m, _, sigma, _ in bodies.values()), default=0.0)
    if not ell2 > 0:
        return theta, report
    for name, (idx, m, c, sigma, R) in bodies.items():
        level = floor * m * ell2
        if sigma[0] >= level:
            continue
        lifted = np.maximum(sigma, level)
        S = (R * lifted) @ R.T
        Ic = np.trace(S) * np.eye(3) - S
        theta[idx] = pin.Inertia(m, c, Ic).toDynamicParameters()
        report[name] = {"lifted": True, "sigma_min_before": float(sigma[0] / (m * ell2)),
                        "sigma_min_after": float(floor)}
    return theta, report
