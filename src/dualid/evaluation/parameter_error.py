"""Parameter error of a rigid body: the geodesic distance between pseudo-inertias (simulation, true θ known).

A body's 10 inertial parameters θ_b map affinely to its 4×4 pseudo-inertia P(θ_b) (``pseudo_inertia_basis``),
positive definite exactly for a physically consistent body. The affine-invariant distance

    d(θ_ref, θ) = sqrt(½ Σ_k log² λ_k),   λ_k the eigenvalues of P(θ_ref)^{-1/2} P(θ) P(θ_ref)^{-1/2}

does not depend on the frame or the units the body is written in (Lee, Wensing and Park, "Geometric robot
dynamic identification: a convex programming approach", IEEE T-RO 2020; the ½ is the half-trace convention of
Yang and Hatton's public example). It is +inf when P(θ) is not positive definite.
"""

from __future__ import annotations

import numpy as np

from dualid.errors import DataError
from dualid.model.parameters import ParameterSpace, pseudo_inertia_basis


def pseudo_inertia(theta_body: np.ndarray) -> np.ndarray:
    """P(θ_b) (4, 4) of one body's parameters in Pinocchio's order."""
    theta_body = np.asarray(theta_body, dtype=float)
    if theta_body.shape != (10,):
        raise DataError(f"pseudo_inertia: expected 10 parameters of one body, got shape {theta_body.shape}")
    return np.tensordot(theta_body, pseudo_inertia_basis(), axes=1)


def geodesic_distance(theta_ref: np.ndarray, theta: np.ndarray) -> float:
    """d(θ_ref, θ) of one body (see the module doc); θ_ref must be physically consistent (P ≻ 0)."""
    ref, est = pseudo_inertia(theta_ref), pseudo_inertia(theta)
    lam, V = np.linalg.eigh(ref)
    if lam.min() <= 0:
        raise DataError(f"geodesic_distance: the reference pseudo-inertia is not positive definite "
                        f"(smallest eigenvalue {lam.min():.3g})")
    if np.linalg.eigvalsh(est).min() <= 0:
        return float("inf")
    W = (V / np.sqrt(lam)) @ V.T
    logs = np.log(np.linalg.eigvalsh(W @ est @ W))
    return float(np.sqrt(0.5 * logs @ logs))


def body_geodesics(parameters: ParameterSpace, theta_ref: np.ndarray, theta: np.ndarray) -> dict[str, float]:
    """{body: d(θ_ref, θ)} over the rigid-body blocks of a parameter space."""
    return {b.name: geodesic_distance(np.asarray(theta_ref)[list(b.indices)], np.asarray(theta)[list(b.indices)])
            for b in parameters.blocks if b.kind == "rigid_body"}
