"""Diagnostics of one interior-point iteration, printed by ``run_interior_point(verbose=True)``.

Per block b: the conditioning of C_b(θ) (λ_min/λ_max) and the centrality spread of the eigenvalues of
L_bᵀ Z_b L_b / μ (C_b = L_b L_bᵀ, μ = gap/ν; all 1 on the central path); the Newton matrix's conditioning
(from its Jacobi-scaled Cholesky diagonal, or the rank kept by the eigen fallback). Read-only: it changes
nothing in the iteration.
"""

from __future__ import annotations

import numpy as np


def iteration_diagnostics(cons, theta, Z, gap, system) -> str:
    mu = gap / max(cons.size, 1)
    parts = []
    for c, Zb in zip(cons.lmis, Z):
        C = c.C(theta)
        lam = np.linalg.eigvalsh(C)
        try:
            L = np.linalg.cholesky(C)
            w = np.linalg.eigvalsh(L.T @ Zb @ L) / max(mu, 1e-300)
            spread = f"[{w[0]:.2g}, {w[-1]:.2g}]"
        except np.linalg.LinAlgError:
            spread = "[C not PD]"
        parts.append(f"{c.name}: cond {lam[0] / lam[-1]:.1e} centrality {spread}")
    if system.L is not None:
        dd = np.diag(system.L) ** 2
        newton = f"Newton matrix cholesky, diag ratio {dd.max() / dd.min():.1e}"
    else:
        newton = f"Newton matrix eigen fallback, rank {len(system.lam)}"
    return newton + (" | " + " | ".join(parts) if parts else "")


GROWTH = 2.0  # a constraint-only parameter this many times farther from 0 at the end than at the start: "grew"


def _constraint_only(cons, der, thetas) -> list[int]:
    """Indices of the parameters f does not depend on (gradient and Hessian rows exactly 0) that enter an LMI."""
    if der is None or der.grad is None or der.hess is None or len(thetas) < 2:
        return []
    free = np.flatnonzero((der.grad == 0) & np.all(der.hess == 0, axis=1))
    in_lmi = set()
    for c in cons.lmis:
        in_lmi.update(int(k) for k in c.idx)
    if len(cons.h):  # a parameter with a bound row against the way it moved cannot run off to infinity
        move = thetas[-1] - thetas[0]
        in_lmi -= {int(k) for k in np.flatnonzero(np.any(cons.G * move < 0, axis=0))}
    return [int(k) for k in free if int(k) in in_lmi]


def constraint_only_direction(cons, der, thetas) -> np.ndarray:
    """The unit vector along the constraint-only parameter that loosens its LMI (V_k ⪰ 0, e.g. a body's mass) and
    moved most, signed by the move; one coordinate, so that pushing it out alone keeps the LMI feasible."""
    free = set(_constraint_only(cons, der, thetas))
    move = thetas[-1] - thetas[0]
    best, d = None, np.zeros_like(thetas[-1])
    for c in cons.lmis:
        for j, k in enumerate(int(i) for i in c.idx):
            lam = np.linalg.eigvalsh(c.V[j])
            if k in free and move[k] > 0 and lam[0] >= -1e-12 * max(abs(lam[-1]), 1e-300):
                if best is None or move[k] > move[best]:
                    best = k
    if best is not None:
        d[best] = 1.0
    return d


def constraint_only_growth(cons, der, thetas, names, growth_min: float = GROWTH) -> str:
    """Why the iteration may not converge: parameters that f does not depend on (their gradient and Hessian
    rows are exactly 0 — zero columns of Y and of the metric, e.g. the mass and off-axis second moments of the
    link next to a fixed base) enter only the constraints, where growing loosens them. If such parameters grew
    ≥ growth_min× (default GROWTH) over the iterations, the infimum is likely approached only as they go to
    infinity (not attained); an SDP then stops at a tolerance-dependent θ. Returns a message suffix naming them, or ''."""
    free = _constraint_only(cons, der, thetas)
    if not free:
        return ""
    start, end = thetas[0][free], thetas[-1][free]
    growth = float(np.linalg.norm(end)) / max(float(np.linalg.norm(start)), 1e-300)
    if growth < growth_min:
        return ""
    label = ", ".join(names[k] if names is not None else f"θ[{k}]" for k in free[:6]) + (" …" if len(free) > 6 else "")
    return (f"; the objective does not depend on {label} (they enter only the consistency constraints, which "
            f"loosen as they grow) and they grew {growth:.3g}× over the iterations: the infimum is likely not "
            "attained at a finite θ; fix or bound these parameters")


def main_components(d: np.ndarray, top: int = 4) -> list[int]:
    """Indices of direction d's largest components (at most ``top``, each above 1e-3 of |d|), largest first."""
    d = np.asarray(d, dtype=float)
    size = float(np.linalg.norm(d))
    return [int(k) for k in np.argsort(-np.abs(d))[:top] if abs(d[k]) > 1e-3 * size]


def direction_names(d: np.ndarray, names) -> list[str]:
    """The parameter names of d's main components (a plain, JSON-friendly list for result.info)."""
    return [names[k] for k in main_components(d)]


def direction_label(d: np.ndarray, names) -> str:
    """d's main components as "+0.707·name …" (result.info["diverging_direction"])."""
    return " ".join(f"{d[k]:+.3f}·{names[k]}" for k in main_components(d))
