"""The closed feasible set over parameters the objective cannot see, for fits whose infimum is not attained.

Some parameters enter neither Y nor the metric (their rows of ∇²f are exactly 0), only a consistency LMI: the mass
of the link next to a fixed base, which enters its pseudo-inertia as m·e₄e₄ᵀ. Growing such a parameter only loosens
its block: C_b(θ) + m·λ uuᵀ ⪰ 0 holds for some m iff the compression Pᵀ C_b P ⪰ 0 (P an orthonormal basis of u⊥),
up to the boundary. So the fit's infimum may be reached only as m → ∞ (a centre of mass falling onto the joint axis
with vanishing axis inertia), and then an interior-point method stops wherever rounding leaves it along that ray:
on the statistical benchmark's sensor case (5-DoF arm, seed 2) the weighted fit of ``dm`` stopped at j0.m = 8·10⁴ kg
in the sensor chart and at 371 kg on the same data re-charted and carried back (rounding, 6e-14), both with a
certified relative gap below 1e-9 but 1.3e-4 apart in f: the stopping test (duality gap + Newton decrement of the
Lagrangian) sees the dual residual along m (−4.5e-3 per kg) through the barrier's curvature there (∝ C_b⁻²),
i.e. as negligible, and the barrier itself has no minimiser along m (−log det C_b falls as m grows).

``close`` replaces every such block by its compression (drops m from it): the closure of the feasible set's
projection, on which the same f has its minimum (the infimum of the original problem; on that arm 13212.8774 in
20 iterations, against 13212.8855 / 13214.5791 at the two stopping points, and the same in both charts to 1e-11).
``complete`` then gives m the smallest value that makes the full block feasible (it changes no prediction: f and
the metric do not depend on m), and says so in the result's info.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.errors import SolverError
from dualid.model.consistency import LMI, FeasibleSet

SLACK = 1e-9  # the completed block's smallest eigenvalue: this × its largest (strictly consistent, on the boundary)


@dataclass(frozen=True)
class Projected:
    """One parameter projected out of one block: V_k = lam · u uᵀ, P an orthonormal basis of u⊥."""

    block: int  # index into cons.lmis
    k: int  # parameter index
    lam: float
    u: np.ndarray  # (m,)
    P: np.ndarray  # (m, m−1)


def _only_in(cons: FeasibleSet, k: int, block: int, lower_ok: bool = True) -> bool:
    """θ_k appears in no other block and in no linear row but (optionally) a lower bound θ_k ≥ l."""
    if any(k in c.idx for j, c in enumerate(cons.lmis) if j != block):
        return False
    if len(cons.h):
        col = cons.G[:, k]
        rows = np.flatnonzero(col)
        for r in rows:
            if col[r] < 0 or not lower_ok or np.count_nonzero(cons.G[r]) != 1:
                return False  # an upper bound (the ray is cut: the minimum is attained) or a coupled row
    return True


def close(cons: FeasibleSet, hess: np.ndarray, grad: np.ndarray | None = None) -> tuple[FeasibleSet, tuple[Projected, ...]]:
    """(closed feasible set, what was projected out). A parameter k is projected out of block b when ∇²f's row k
    (and ∇f's entry, when given) is exactly 0, it enters block b as a rank-one positive semidefinite term and no
    other constraint but a lower bound. One parameter per block; the others are left as they are."""
    flat = np.all(hess == 0, axis=1)
    if grad is not None:
        flat &= grad == 0
    if not flat.any() or not cons.lmis:
        return cons, ()
    lmis, projected = list(cons.lmis), []
    for b, c in enumerate(cons.lmis):
        for j, k in enumerate(int(i) for i in c.idx):
            if not flat[k] or not _only_in(cons, k, b):
                continue
            lam, U = np.linalg.eigh(0.5 * (c.V[j] + c.V[j].T))
            top = float(np.abs(lam).max())
            if top == 0 or lam[-1] <= 0 or np.count_nonzero(np.abs(lam) > 1e-12 * top) != 1:
                continue
            u, P = U[:, -1], U[:, :-1]
            keep = [i for i in range(len(c.idx)) if i != j]
            V = np.einsum("am,kab,bn->kmn", P, c.V[keep], P)
            lmis[b] = LMI(c.name, np.asarray(c.idx)[keep], V, P.T @ c.C0 @ P)
            projected.append(Projected(b, k, float(lam[-1]), u, P))
            break
    if not projected:
        return cons, ()
    return FeasibleSet(tuple(lmis), cons.G, cons.h, cons.names), tuple(projected)


def complete(theta: np.ndarray, cons: FeasibleSet, projected: tuple[Projected, ...], names=None) -> tuple[np.ndarray, dict]:
    """θ with every projected parameter set to the smallest value (plus SLACK) that makes its full block feasible,
    given the others (a strictly feasible compression has one); (θ, info) with info["projected_parameters"]."""
    theta = np.array(theta, dtype=float)
    if not projected:
        return theta, {}
    notes = []
    for pr in projected:
        c = cons.lmis[pr.block]
        theta[pr.k] = 0.0
        Q = c.C(theta)  # the block without the projected term
        S = pr.P.T @ Q @ pr.P
        w = pr.P.T @ Q @ pr.u
        q = float(pr.u @ Q @ pr.u)
        top = max(float(np.abs(np.linalg.eigvalsh(S)).max()), abs(q), 1e-300)
        # m·λ ≥ wᵀS⁻¹w − q (Schur complement); S may be nearly singular (the closed optimum on its boundary): a
        # least-squares solve (no LinAlgError), a relative slack against its rounding, then a Cholesky check below
        need = float(w @ np.linalg.lstsq(S, w, rcond=None)[0]) - q
        value = (need * (1.0 + 1e-8) + SLACK * top) / pr.lam
        lo = -np.inf
        for r in np.flatnonzero(cons.G[:, pr.k]) if len(cons.h) else ():
            lo = max(lo, -cons.h[r] / cons.G[r, pr.k])
        theta[pr.k] = max(value, lo)
        for _ in range(60):  # the full block must factor; if rounding left it singular, grow the mass (×2)
            try:
                np.linalg.cholesky(c.C(theta))
                break
            except np.linalg.LinAlgError:
                theta[pr.k] = 2.0 * max(theta[pr.k], SLACK * top / pr.lam)
        else:
            label = names[pr.k] if names is not None else f"θ[{pr.k}]"
            raise SolverError(f"closure: no value of {label} makes its consistency block positive definite (the "
                              "rest of the block, compressed, is singular: smallest eigenvalue "
                              f"{float(np.linalg.eigvalsh(S)[0]):.3g}); the closed fit did not end inside its cone",
                              status="closure_failed")
        label = names[pr.k] if names is not None else f"θ[{pr.k}]"
        notes.append(f"{label} = {theta[pr.k]:.6g}")
    info = {"projected_parameters": ", ".join(notes),
            "projected_note": "parameters f does not depend on, which only loosen a consistency block as they grow: "
                              "fitted on the closed feasible set (their block compressed), then set to the smallest "
                              "value that keeps the block consistent; a large value means the infimum is approached "
                              "only as it grows (predictions are those of the limit)"}
    return theta, info


def on_closure(cons: FeasibleSet, hess: np.ndarray, names=None, enabled: bool = True):
    """close → (the caller solves) → complete, the one sequence of every fit on the closed feasible set: returns
    (the set to solve on, done) with done(θ, info) → (θ completed against the full ``cons``, info with the
    completion's note). enabled=False: ``cons`` itself and a done that only returns θ as a float array."""
    closed, projected = close(cons, hess) if enabled else (cons, ())

    def done(theta: np.ndarray, info: dict) -> tuple[np.ndarray, dict]:
        theta, completed = complete(theta, cons, projected, names)
        info.update(completed)
        return theta, info

    return closed, done
