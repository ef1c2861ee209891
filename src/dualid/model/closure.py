"""The closed feasible set over parameters the objective cannot see, for fits whose infimum is not attained.

Some parameters enter neither Y nor the metric (their rows of ∇²f vanish), only a consistency LMI: the mass of the
link next to a fixed base, which enters its pseudo-inertia as m·e₄e₄ᵀ. Growing such a parameter only loosens
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
the metric do not depend on m), and says so in the result's info: such a value is not determined by the data (it is
the smallest one consistent with the other parameters, and its size reflects how close the fit ends to the
boundary, i.e. the solver's tolerance: DFKI small case Joint1.m = 4.9·10⁷ kg, statistical benchmark up to
2.7·10¹³ kg), not an estimate.

Which parameters f cannot see. Analytically Y's column of such a mass is 0; numerically it is 0 only when nothing
cancels. With the link's parameters taken about a point of a tilted joint axis (a link or CAD frame, not the joint
frame: the mass then enters through m·d in the first moment and m(|d|²1 − ddᵀ) in the inertia, d on the axis,
whose torques about the axis cancel) the column is rounding, H_kk = 7e-38·c on the 5-DoF arm of
tests/test_closure_paths.py, and a rule "row exactly 0" missed the ray. So a parameter is unseen when
H_kk ≤ ZERO_CURVATURE · c, with H = Σ Y_iᵀW_iY_i and c = Σ τ_iᵀW_iτ_i = f(0) of the same fit: ‖Y_k‖_W/‖τ‖_W, the
share of the weighted torques one SI unit of θ_k carries (the quadratic chart's √(c/H_kk) of
``signal_scale`` in estimators.quadratic_fit, read as a size: an unseen parameter would need more than 10¹² kg, kg m or kg m² to
move the torques by their own size). H and c transform together under any change of force coordinates (both are
Σ of a weighted product of covectors), and dm's fits are made in the sensor chart, so the set is the same in every
chart the problem records. The rounding level scales like (ε·|d|·‖Y_mc‖_W/‖τ‖_W)², about (ε·|d|/|m c|)² with m c the
link's first moment: 7e-38 on that arm (|d| = 0.12 m), below 1e-24 while |d|/|m c| < 10⁴ kg⁻¹ (a 1 g link with its
centre of mass 1 cm from the axis and its frame 10 cm up it); the parameters the data see on the statistical
benchmark's arms carry at least 1e-7 of c per SI unit (the least seen one per arm: 1e-7 to 1.6e-4), 17 decades above.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.errors import SolverError
from dualid.model.consistency import LMI, FeasibleSet

SLACK = 1e-9  # the completed block's smallest eigenvalue: this × its largest (strictly consistent, on the boundary)
NOT_DETERMINED = "not determined by the data: the smallest value consistent with the other parameters"
ZERO_CURVATURE = 1e-24  # f cannot see θ_k when H_kk ≤ this × c: one SI unit of θ_k moves the weighted torques by at
# most 1e-12 of their size, ‖Y_k‖_W ≤ 1e-12 ‖τ‖_W (module doc: "Which parameters f cannot see")


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


def unseen(hess: np.ndarray, scale: float) -> np.ndarray:
    """(p,) bool: the parameters f cannot see, H_kk ≤ ZERO_CURVATURE · c (module doc; H = ½∇²f, c = f(0))."""
    d = np.diag(np.asarray(hess, dtype=float))
    return d <= ZERO_CURVATURE * max(float(scale), 0.0)


def close(cons: FeasibleSet, hess: np.ndarray, scale: float) -> tuple[FeasibleSet, tuple[Projected, ...]]:
    """(closed feasible set, what was projected out). hess: H = Σ Y_iᵀ W_i Y_i (½∇²f), scale: c = Σ τ_iᵀ W_i τ_i
    (f(0)) of the same fit. A parameter k is projected out of block b when f cannot see it (``unseen``: H_kk, and
    so its whole row and ∇f's entry, at most rounding), it enters block b as a rank-one positive semidefinite term
    and no other constraint but a lower bound. One parameter per block; the others are left as they are."""
    flat = unseen(hess, scale)
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
    given the others (a strictly feasible compression has one); (θ, info) with info["projected_parameters"] (names =
    values, said to be not determined by the data), ["projected_names"] and ["projected_note"] (the reports' text)."""
    theta = np.array(theta, dtype=float)
    if not projected:
        return theta, {}
    notes, labels = [], []
    for pr in projected:
        c = cons.lmis[pr.block]
        label = names[pr.k] if names is not None else f"θ[{pr.k}]"
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
            raise SolverError(f"closure: no value of {label} makes its consistency block positive definite (the "
                              "rest of the block, compressed, is singular: smallest eigenvalue "
                              f"{float(np.linalg.eigvalsh(S)[0]):.3g}); the closed fit did not end inside its cone",
                              status="closure_failed")
        notes.append(f"{label} = {theta[pr.k]:.6g}")
        labels.append(label)
    info = {"projected_parameters": f"{', '.join(notes)} ({NOT_DETERMINED})",
            "projected_names": labels,
            "projected_note": f"{NOT_DETERMINED}, not an estimate: neither the data nor the metric depend on "
                              f"{'it' if len(labels) == 1 else 'them'}, and a larger value only loosens "
                              "the consistency block, so the fit was made on the closed feasible set (the block "
                              "compressed) and then set to the smallest value that keeps the block consistent. "
                              "Its size reflects how close the fit ended to that block's boundary (the solver's "
                              "tolerance), not the data: the infimum is approached only as it grows, and the "
                              "predictions are those of that limit"}
    return theta, info


def on_closure(cons: FeasibleSet, hess: np.ndarray, scale: float, names=None, enabled: bool = True):
    """close → (the caller solves) → complete, the one sequence of every fit on the closed feasible set: returns
    (the set to solve on, done) with done(θ, info) → (θ completed against the full ``cons``, info with the
    completion's note); hess and scale as in ``close``. enabled=False: ``cons`` itself and a done that only returns
    θ as a float array."""
    closed, projected = close(cons, hess, scale) if enabled else (cons, ())

    def done(theta: np.ndarray, info: dict) -> tuple[np.ndarray, dict]:
        theta, completed = complete(theta, cons, projected, names)
        info.update(completed)
        return theta, info

    return closed, done
