"""The primal–dual (HKM) interior-point iterations, for the dual-metric f or any smooth convex objective."""

from __future__ import annotations

import numpy as np

from dualid.errors import SolverError
from dualid.estimators.newton.linalg import (
    barrier,
    dual_direction,
    dual_max_step,
    duality_gap,
    min_centrality,
)
from dualid.estimators.newton.objective import dual_metric_derivatives, force_scale, value_or_inf
from dualid.linalg import NewtonSystem, NotPositiveDefinite, SecantCorrection, positive_definite
from dualid.model.consistency import FeasibleSet, repair_psd

LARGE_LMI = 32  # blocks of this size or more assemble their Newton term by one GEMM (einsum: 4× slower at 64, the
# plausible step's region on a 7-DoF arm); smaller ones keep einsum, whose rounding the stress corpus was tuned on
RESTART = 1.0  # non-convex f only: after a step that lowered f by Δf > the duality gap, the barrier restarts at
# μ = RESTART · Δf / ν with the dual re-centred (Z_b = μ C_b⁻¹, z = μ / s), as the barrier update of Nocedal & Wright
# §19.3 and IPOPT's monotone μ (not below the optimality error, here the observed decrease). For convex f the gap
# bounds f − f*, so the ``dm-paper`` path never restarts; ``dm`` starts at the paper's optimum, which is not a local
# minimum of its objective, and a μ fitted to that point left the steps crawling along the block boundaries
DIVERGENCE_RATIO = 0.95  # each of the last primal steps at least this times the one before (not shrinking) …
DIVERGENCE_STEPS = 5  # … this many in a row, along one direction, |θ| growing and f falling: optimum at infinity
CENTRALITY_MIN = 0.0075  # below this × μ, the smallest eigenvalue of C_b^½ Z_b C_b^½ (or s_j z_j) calls for a centring
# step (σ = 1): at a rank-deficient optimum (a point mass) Mehrotra's σ ≤ 0.5 lets one eigen-pair of C_b Z_b collapse
# far ahead of μ, and every later step is blocked by that block's boundary
SHORT_STEP = 0.5  # … and only after a step shorter than this (primal or dual): well-centred runs keep Mehrotra's σ
GAP_BALANCE = 3.0  # the centring target σμ is kept ≥ GAP_BALANCE · λ²/ν (λ² the Lagrangian's squared Newton
# decrement, the stationarity error in units of f; at most μ), so that the gap cannot run ahead of stationarity
# (docs/performance.md, "What keeps the solvers converging", for these rules and their measurements)


ACCEPTABLE_GROWTH = 1e-2  # run_interior_point(acceptable=…): flagged |θ| growth below 1 % does not block it


def diverging_iterates(thetas: list[np.ndarray], f_history: list[float]) -> dict:
    """Does the iteration run off to infinity? Near a finite minimiser Newton's steps shrink; when the infimum is
    approached as θ → ∞ along a ray (e.g. f = S_A/m + S_B as a mass m grows: DFKI Joint1) they keep their length and
    direction while |θ| grows and f keeps falling. Flags it when the last DIVERGENCE_STEPS steps each keep ≥
    DIVERGENCE_RATIO of the previous one's length, point the same way (cosine ≥ 0.99), |θ| increases at every one
    of them and f decreases; ``diverging_direction`` is the last step, normalised."""
    out = {"optimum_at_infinity": False}
    k = DIVERGENCE_STEPS
    if len(thetas) < k + 2 or len(f_history) < k + 2:
        return out
    th = thetas[-(k + 2):]
    d = [b - a for a, b in zip(th[:-1], th[1:])]
    lengths = [float(np.linalg.norm(x)) for x in d]
    if min(lengths) <= 0:
        return out
    keep = all(b >= DIVERGENCE_RATIO * a for a, b in zip(lengths[:-1], lengths[1:]))
    aligned = all(float(x @ y) >= 0.99 * lx * ly for x, y, lx, ly in zip(d[:-1], d[1:], lengths[:-1], lengths[1:]))
    norms = [float(np.linalg.norm(x)) for x in th]
    growing = all(b > a for a, b in zip(norms[:-1], norms[1:]))
    falling = all(b < a for a, b in zip(f_history[-(k + 2):-1], f_history[-(k + 1):]))
    if keep and aligned and growing and falling:
        out.update(optimum_at_infinity=True, diverging_steps=k, theta_norm_growth=norms[-1] / max(norms[0], 1e-300),
                   diverging_direction=d[-1] / lengths[-1])
        return out
    # earlier in the run: ≥ 3 aligned steps (cosine ≥ 0.99) over which |θ| grew ≥ 2× — a candidate direction
    # for the caller to test on the objective (``ray_decreases``): on the DFKI pendubot the mass runs 18 → 65 kg
    # in 4 such steps, then its direction turns flat to the tolerance and the iteration converges there
    d = [b - a for a, b in zip(thetas[:-1], thetas[1:])]
    best, start = None, 0
    for j in range(1, len(d) + 1):
        if j == len(d) or not (float(d[j] @ d[j - 1]) >= 0.99 * np.linalg.norm(d[j]) * np.linalg.norm(d[j - 1]) > 0):
            if j - start >= 3:
                n0, n1 = float(np.linalg.norm(thetas[start])), float(np.linalg.norm(thetas[j]))
                if n1 >= 2.0 * n0 and (best is None or n1 / max(n0, 1e-300) > best[0]):
                    move = thetas[j] - thetas[start]
                    best = (n1 / max(n0, 1e-300), move / np.linalg.norm(move), j - start)
            start = j
    if best is not None:
        out.update(diverging_candidate=best[1], theta_norm_growth=best[0], diverging_steps=best[2])
    return out


def barrier_restart(decrease, gap, floor, nu, Cinv, s):
    """The dual re-centred at μ = RESTART · decrease / ν (Z_b = μ C_b⁻¹, z = μ / s) when the last step lowered f by
    more than the duality gap (and more than ``floor``, the stopping tolerance in units of f); else None."""
    if not decrease > max(gap, floor):
        return None
    mu = RESTART * decrease / nu
    return [mu * Ci for Ci in Cinv], (mu / s if len(s) else np.zeros(0))


def run_interior_point(problem, cons: FeasibleSet, theta, Z, z, tol, max_iter, chunk, verbose, der=None, gap0=1.0,
                    objective=None, f_scale=None, levenberg=1e-12, balance: float = GAP_BALANCE, convex: bool = True,
                    acceptable: float = 0.0):
    """Primal–dual iterations from a strictly feasible θ (and dual Z, z, or None: centred at θ, gap0·f).

    Returns (θ, Z, z, info) at relative gap ≤ tol (or, after max_iter, ≤ acceptable, with info["status"]
    "optimal_inaccurate"); raises SolverError otherwise. objective(θ, order) → Derivatives
    (raising NotPositiveDefinite outside its domain) replaces the dual-metric f, with f_scale its size (then problem
    is unused): the same method for any smooth convex f under these constraints. convex=False (a Hessian handed as a
    PSD part such as Gauss–Newton) lets the barrier restart (RESTART) and adds the curvature the handed Hessian leaves
    out, learnt by secant updates (``dualid.linalg.SecantCorrection``), where the Newton matrix stays positive definite;
    the stopping test is the same, a KKT point of f's local model to tol · f.
    """
    p = len(theta)
    dual_metric = objective is None  # the candidate direction below is for fit_dual_metric_newton (fit.pushed_out)
    if objective is None:
        def objective(th, order):
            return dual_metric_derivatives(problem, th, order, chunk)
    nu = cons.size  # barrier parameter: μ = gap / ν on the central path
    der = objective(theta, 2) if der is None else der
    f_start = der.f
    if f_scale is None:
        f_scale = force_scale(problem, theta, chunk)
    f_scale = max(f_start, f_scale)  # exact data drive f → 0
    if Z is None:
        mu = gap0 * max(der.f, 1e-300) / max(nu, 1)  # dual start on the central path: Z_b = μ C_b⁻¹, z = μ / s
        Z = [mu * np.linalg.inv(c.C(theta)) for c in cons.lmis]
        z = mu / (cons.G @ theta + cons.h) if len(cons.h) else np.zeros(0)
    history, n_evals, thetas = [], 0, [np.array(theta, dtype=float)]
    secant = SecantCorrection(p)  # convex=False: the curvature that the handed Hessian leaves out
    last_step = 0.0  # min(primal, dual) step length of the previous iteration
    for it in range(max_iter + 1):
        if der is None:
            der = objective(theta, 2)
        f, grad, K = der.f, der.grad, der.hess.copy()
        if not convex:
            if it:
                secant.update(theta - thetas[-2], grad - grad_prev, K)
            grad_prev = grad
        Cinv = [np.linalg.inv(c.C(theta)) for c in cons.lmis]
        s = cons.G @ theta + cons.h
        if not convex and it and nu:
            restarted = barrier_restart(history[-1] - f, gap, tol * abs(f), nu, Cinv, s)
            if restarted is not None:
                Z, z = restarted
                if verbose:
                    print(f"            barrier restart: f fell {history[-1] - f:.3g} > gap {gap:.3g}")
        r_dual = grad.copy()  # ∇f − A*(Z), the Lagrangian's gradient
        barrier_grad = np.zeros(p)  # A*(C⁻¹) = −∇(barrier)
        for c, Zb, Ci in zip(cons.lmis, Z, Cinv):
            r_dual[c.idx] -= np.einsum("kab,ba->k", c.V, Zb)
            barrier_grad[c.idx] += np.einsum("kab,ba->k", c.V, Ci)
            VZ, VC = c.V @ Zb, c.V @ Ci  # tr(V_k Z V_l C⁻¹), O(k² m²); a large block (the plausible step's confidence
            K[np.ix_(c.idx, c.idx)] += (np.einsum("kab,lba->kl", VZ, VC) if len(Zb) < LARGE_LMI else  # region) by GEMM
                                        VZ.reshape(len(VZ), -1) @ np.swapaxes(VC, 1, 2).reshape(len(VC), -1).T)
        if len(s):
            r_dual -= cons.G.T @ z
            barrier_grad += cons.G.T @ (1.0 / s)
            K += cons.G.T @ ((z / s)[:, None] * cons.G)
        system = None  # the Newton system of the handed Hessian, when the learnt curvature is added below
        if not convex and positive_definite(K + secant.A):
            # the Lagrangian's Hessian with the learnt curvature, where it is positive definite (the inertia test
            # of IPOPT, on the whole Newton matrix: the barrier's curvature may cover f's negative part); else the
            # handed PSD Hessian alone
            system = NewtonSystem(0.5 * (K + K.T), levenberg)
            K = K + secant.A
        # the stop is measured in the handed Hessian's metric too, and the larger decrement counts: a learnt
        # curvature with spurious positive directions cannot make the test pass early
        kkt = 0.0 if system is None else float(r_dual @ system.solve(r_dual))
        system = NewtonSystem(0.5 * (K + K.T), levenberg)
        gap = duality_gap(cons, theta, Z, z)
        kkt = float(max(r_dual @ system.solve(r_dual), kkt, 0.0))  # squared Newton decrement of the Lagrangian
        f_ref = max(f, 1e-12 * f_scale, 1e-300)
        history.append(f)
        if verbose:
            print(f"newton {it:3d}: f {f:.15g} gap {gap:.3g} kkt {kkt:.3g}")
            print("      " + iteration_diagnostics(cons, theta, Z, gap, system))
        if gap + kkt <= tol * f_ref:
            info = {"objective": f, "iterations": it, "duality_gap": gap, "kkt_residual": float(np.sqrt(kkt)),
                    "relative_gap": (gap + kkt) / f_ref, "objective_start": f_start,
                    "objective_evaluations": n_evals, "f_history": history}
            info.update(diverging_iterates(thetas, history))
            names = getattr(getattr(problem, "parameters", None), "names", None)
            grew = constraint_only_growth(cons, der, thetas, names, growth_min=10.0)
            if grew:  # met the tolerance, but perhaps on the way to an infimum at infinity: say so, and let the caller
                # test that direction (fit.pushed_out): the parameters f cannot see, rather than the iterates' last run
                info["constraint_only_growth"] = grew.removeprefix("; ")
                d_free = constraint_only_direction(cons, der, thetas)
                if dual_metric and not info["optimum_at_infinity"] and d_free.any():
                    k = int(np.flatnonzero(d_free)[0])
                    info.update(diverging_candidate=d_free, diverging_steps=it,
                                theta_norm_growth=abs(thetas[-1][k]) / max(abs(thetas[0][k]), 1e-300))
            return theta, Z, z, info
        if it == max_iter:
            break
        # centring: Mehrotra's heuristic σ = (μ_aff / μ)³ from the affine-scaling (σ = 0) predictor
        mu = gap / nu if nu else 0.0
        sigma = 0.0
        if mu > 0:  # a gap that underflowed to 0 (the dual iterates at 0) leaves nothing to centre: σ = 0
            d_aff = system.solve(-grad)
            a_p = min(1.0, cons.max_step(theta, d_aff))
            dZa, dza = dual_direction(cons, Z, z, Cinv, s, d_aff, 0.0)
            a_d = min(1.0, dual_max_step(Z, z, dZa, dza))
            mu_aff = duality_gap(cons, theta + a_p * d_aff, [Zb + a_d * dZb for Zb, dZb in zip(Z, dZa)], z + a_d * dza) / nu
            sigma = float(np.clip((max(mu_aff, 0.0) / mu) ** 3, 0.05, 0.5))
        if mu > 0 and last_step < SHORT_STEP and min_centrality(cons, theta, Z, z, s) < CENTRALITY_MIN * mu:
            sigma = 1.0  # a pure centring step: see CENTRALITY_MIN
        target = sigma * mu
        if mu > 0 and balance:  # the gap kept from running ahead of stationarity: see GAP_BALANCE
            target = min(mu, max(target, balance * kkt / nu))
        rhs = -grad + target * barrier_grad  # −∇ of the merit φ = f + target · barrier
        d = system.solve(rhs)
        slope = -float(rhs @ d)
        alpha = min(1.0, 0.99 * cons.max_step(theta, d)) if nu else 1.0
        alpha_max = alpha  # fraction to the boundary, before the line search
        phi0 = f + target * barrier(cons, theta)
        der_trial, first = None, True
        while True:  # backtracking: every C_b ≻ 0, every Cholesky of M_i succeeds, Armijo on φ
            n_evals += 1
            trial = theta + alpha * d
            if first:
                # the first trial is usually accepted: evaluate all derivatives there, for the next iteration
                try:
                    der_trial = objective(trial, 2)
                    phi1 = der_trial.f
                except NotPositiveDefinite:
                    der_trial, phi1 = None, np.inf
            else:
                der_trial, phi1 = None, value_or_inf(objective, trial)
            first = False
            if np.isfinite(phi1):
                phi1 += target * barrier(cons, trial)
            # Armijo, with a tolerance for the rounding of f: batched solves with ill-conditioned M_i make
            # f jitter by a few 1e-12 relative; 1e-10 stays 10× below the stopping tolerance (1e-9)
            if phi1 <= phi0 + 1e-4 * alpha * slope + 1e-10 * abs(phi0):
                break
            alpha *= 0.5
            if alpha < 1e-12:
                raise SolverError(
                    f"dual-metric Newton: line search failed at iteration {it} (relative gap "
                    f"{(gap + kkt) / f_ref:.3g}); the problem may be badly scaled",
                    status="line_search_failed",
                )
        dZ, dz = dual_direction(cons, Z, z, Cinv, s, d, target)
        alpha_dual = min(1.0, 0.99 * dual_max_step(Z, z, dZ, dz))
        # separate primal and dual step lengths: with one common length the primal step (blocked by a nearly
        # active block) and the dual step (blocked by a Z_b near its boundary) throttle each other in turn
        theta, der = trial, der_trial
        last_step = min(alpha, alpha_dual)
        thetas.append(np.array(theta, dtype=float))
        Z = [repair_psd(Zb + alpha_dual * dZb) for Zb, dZb in zip(Z, dZ)]  # PD up to rounding
        z = z + alpha_dual * dz
        if verbose:
            print(f"            sigma {sigma:.3g} alpha {alpha:.3g} (to boundary {alpha_max:.3g}) "
                  f"alpha_dual {alpha_dual:.3g}")
    away = diverging_iterates(thetas, history)
    # within ``acceptable`` after max_iter and no |θ| growth flagged (≥ 2× earlier, > 1 % in the last steps, which
    # slow linear convergence also keeps aligned; a ray to infinity grows |θ| at every step): labelled, not raised
    if gap + kkt <= acceptable * f_ref and away.get("theta_norm_growth", 1.0) < 1.0 + ACCEPTABLE_GROWTH:
        return theta, Z, z, {**away, "objective": f, "iterations": max_iter, "duality_gap": gap,
                             "status": "optimal_inaccurate", "kkt_residual": float(np.sqrt(kkt)),
                             "relative_gap": (gap + kkt) / f_ref, "optimum_at_infinity": False}
    if away["optimum_at_infinity"]:
        raise SolverError(
            f"dual-metric Newton: no convergence in {max_iter} iterations: the objective keeps decreasing while θ "
            f"grows without bound (the last {away['diverging_steps']} steps kept their length and direction, |θ| "
            f"{away['theta_norm_growth']:.3g}× larger over them); the infimum is at infinity, not at a finite θ: bound the "
            "unidentifiable parameters (e.g. a mass bound) or fix them",
            status="optimum_at_infinity",
        )
    raise SolverError(
        f"dual-metric Newton: no convergence in {max_iter} iterations; relative gap reached "
        f"{(gap + kkt) / f_ref:.3g} (duality gap {gap:.3g}, KKT residual {np.sqrt(kkt):.3g}, tol {tol:g})"
        + constraint_only_growth(cons, der, thetas, getattr(getattr(problem, "parameters", None), "names", None)),
        status="max_iterations",
    )


def iteration_diagnostics(cons, theta, Z, gap, system) -> str:
    """One iteration's diagnostics (``run_interior_point(verbose=True)``): per block the conditioning of C_b(θ) and
    the spread of the eigenvalues of L_bᵀ Z_b L_b / μ (all 1 on the central path), and the Newton matrix's."""
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
