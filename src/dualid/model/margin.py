"""The chart-invariant margin C_b(θ) ⪰ ε·C_b(θ_ref) on every constrained block.

C_b is linear in θ, so the margin says θ − εθ_ref is physically consistent; M_i is linear in θ too, hence
M_i(θ) − ε·M_i(θ_ref) = M_i(θ − εθ_ref) ⪰ 0 at EVERY configuration, seen in the data or not. Body quantities do
not depend on the joint coordinates and a change of units scales θ and θ_ref alike, so the margin is the same
in every chart and every unit system. It is consistency shifted by a constant: ``feasible_set`` and
``cvxpy_constraints`` (model/consistency.py) take it as C0 = −ε·C_b(θ_ref) and h = −ε·θ_ref,k, so every
constrained estimator and both dual-metric solvers apply it alike. The ParameterSpace carries it
(``ParameterSpace.with_margin``), so ``in_coordinates``, ``subset`` and bounds keep it.
"""

from __future__ import annotations

import numpy as np

from dualid.errors import ConfigError

RANGE_RTOL = 1e-6  # reference directions below this × the block's largest are not compared (a reference on the
# boundary of consistency, e.g. a WLS pilot's damping at 1e-11: the margin there is plain consistency, and a
# ratio against it would measure solver tolerance)
ACTIVE_RTOL = 1e-3  # a block's margin is "active" at θ̂ when its ratio is within ε·(1 + 1e-3) (+1e-6)


def check_margin(parameters, theta_ref, epsilon) -> tuple[tuple[float, ...], float]:
    """(θ_ref as a tuple, ε) after checking them: ε ∈ [0, 1), θ_ref (p,) finite and physically consistent."""
    try:
        eps = float(epsilon)
    except (TypeError, ValueError):
        raise ConfigError(f"margin.epsilon: expected a number in [0, 1), got {epsilon!r}") from None
    if not (np.isfinite(eps) and 0.0 <= eps < 1.0):
        raise ConfigError(f"margin.epsilon: expected a number in [0, 1), got {epsilon!r}")
    if theta_ref is None:
        raise ConfigError("margin.reference: the margin needs a reference θ_ref (the prior or a WLS pilot), got none")
    ref = np.asarray(theta_ref, dtype=float)
    if ref.shape != (parameters.p,):
        raise ConfigError(f"margin.reference: expected θ_ref of shape ({parameters.p},), got {ref.shape}")
    if not np.all(np.isfinite(ref)):
        raise ConfigError("margin.reference: θ_ref has non-finite entries (NaN or inf)")
    violated = parameters.violated_block(ref)
    if violated is not None:
        name, lam = violated
        raise ConfigError(
            f"margin.reference: θ_ref is not physically consistent: block {name!r} has constraint-matrix "
            f"smallest eigenvalue {lam:.3g} < 0; the margin C_b(θ) ⪰ ε·C_b(θ_ref) needs a consistent reference"
        )
    return tuple(float(x) for x in ref), eps


def _ratio(C: np.ndarray, C_ref: np.ndarray) -> float:
    """Smallest generalised eigenvalue of (C, C_ref) on the range of C_ref (inf when C_ref = 0)."""
    lam, U = np.linalg.eigh(0.5 * (C_ref + C_ref.T))
    keep = lam > RANGE_RTOL * max(lam.max(), 0.0)
    if not keep.any():
        return float("inf")
    W = U[:, keep] / np.sqrt(lam[keep])  # C_ref^{-1/2} on its range
    return float(np.linalg.eigvalsh(W.T @ C @ W)[0])


def margin_ratios(parameters, theta) -> dict[str, float]:
    """Per constrained block (per row for diagonal blocks): min generalised eigenvalue of C_b(θ̂) against
    C_b(θ_ref) on the range of C_b(θ_ref) (directions above RANGE_RTOL × its largest eigenvalue) — ≥ ε when
    the margin holds; chart- and unit-invariant."""
    ref = np.asarray(parameters.margin_reference)
    theta = np.asarray(theta, dtype=float)
    out = {}
    for b in parameters.blocks:
        if b.constraint_basis is None:
            continue
        if b.kind in ("drag_diagonal", "nonnegative"):
            top = max(float(ref[list(b.indices)].max()), 0.0)
            for i in b.indices:
                if ref[i] > RANGE_RTOL * top:
                    out[parameters.names[i]] = float(theta[i] / ref[i])
            continue
        out[b.name] = _ratio(b.constraint_matrix(theta), b.constraint_matrix(ref))
    return out


def margin_info(parameters, theta, constrained: bool = True) -> dict:
    """What a result records about the margin (flat, JSON-able): ε, where θ_ref came from, whether the fit
    enforced it (unconstrained fits do not), the smallest ratio and the blocks where it is active at θ̂."""
    if parameters.margin_reference is None:
        return {}
    eps = parameters.margin_epsilon
    ratios = margin_ratios(parameters, theta)
    active = [k for k, r in ratios.items() if r <= eps * (1 + ACTIVE_RTOL) + 1e-6]
    return {
        "margin_epsilon": float(eps),
        "margin_reference": parameters.margin_label or "given θ_ref",
        "margin_enforced": bool(constrained),
        "margin_min_ratio": float(min(ratios.values())) if ratios else float("inf"),
        "margin_active": ", ".join(active),
    }
