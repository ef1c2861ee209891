"""The confidence-region choice of plausible parameters by dualid's own interior point (no conic compiler).

``plausible_region`` states the problem: θ closest to the prior θ₀ whose base parameters β = Cθ lie in the fit's
confidence ellipsoid (β − β̂)ᵀΣ_β⁻¹(β − β̂) ≤ c², physically consistent, within the bounds. In the chart

    u(θ) = Λ^-½ Uᵀ D (Cθ − β̂) / c,    the region ‖u(θ)‖ ≤ 1,

U Λ Uᵀ = D Σ_β D the covariance in the column-scaled chart (D = diag of the independent columns' norms), its
eigenvalues floored at SIGMA_RTOL × the largest, so that ‖u‖² c² is the statistic and u is O(1) whatever the units
and the noise level. The region is one more LMI, [[I, u], [uᵀ, 1]] ⪰ 0, beside the consistency LMIs and bound rows.
Below REGION_ROWS_MAX rows the problem is one run of ``newton.interior_point.run_interior_point`` (primal–dual,
affine-invariant) from a point inside the region: the prior with θ̂'s base parameters mostly taken over (its other
parameters kept), or else a point on the segment from the prior to θ̂ (strictly consistent when θ̂ is consistent,
the prior being strictly). The region's multiplier is read off its dual block. A run that ends with a body heavier
than HEAVY_RATIO × the prior's whole moving mass (a start near θ̂'s completed masses, which the data do not determine
and the fit may leave at 10¹¹ kg, stalls the iterates there) is checked against the penalised sequence below; the
lower R is kept.

From REGION_ROWS_MAX rows on (a 7-DoF arm's 64), when neither start is strictly consistent (an unconstrained θ̂), or
when that run fails, the problem is solved as a sequence of penalised ones, θ(μ) = argmin_θ R(θ) + μ‖u(θ)‖² under
the other constraints, from the prior: μ by regula falsi in log μ until ‖u‖ ∈ [1 − U_TOL, 1] (KKT with multiplier
μ/c²), each solve warm-started from the previous μ's. Where a large region's sequence fails or ends outside, the
single run is tried last.

The prior term R is scale-aware in every block:
- rigid bodies: the log-det divergence of the pseudo-inertia to the prior's (invariant under units and body
  frame; itself a barrier of the consistency cone). ``dualid fit`` rounds the prior's bodies first
  (``rounded_prior``: a thin CAD link would otherwise make one direction 1/λ² stiff and push the fit's
  disagreement into its mass);
- joint terms (friction, armature: a URDF carries none) and free parameters: ½ w_k (θ_k − θ₀_k)² with
  w_k = ‖Y_k‖² / ‖τ_j‖² (``torque_weights``): a change that would explain the joint's whole measured torque costs
  ½, so a prior at (or near) the bound 0 costs nothing extra and no 1/x² curvature appears.

When no μ up to MU_MAX brings ‖u‖ to 1 (the data pin a body onto the consistency boundary), the last point is
kept and ``note`` says how far outside the region it lies.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pinocchio as pin

from dualid.errors import SolverError
from dualid.evaluation.plausible import HEAVY_RATIO, heavy_links
from dualid.estimators.newton.objective import Derivatives, NotPositiveDefinite, value_or_inf
from dualid.estimators.newton.interior_point import run_interior_point
from dualid.estimators.newton.start import run_quadratic
from dualid.model.consistency import LMI, FeasibleSet, feasible_set, pullback_metric
from dualid.problem import IdentificationProblem

SIGMA_RTOL = 1e-12  # Σ_β's eigenvalues floored at this × the largest (column-scaled chart)
U_TOL = 5e-6  # accept log ‖u‖ in [−U_TOL, 0]: the statistic within 1e-5 of c² (the constraint active)
MU_MAX = 1e14  # the largest penalty tried before the point is kept outside the region
MAX_SOLVES = 40
TOL = 1e-9  # the interior point's relative gap
REGION_ROWS_MAX = 32  # a region LMI of this many rows or more: the penalised sequence first, not one interior point
# with the region as a constraint, whose Newton term grows with its rows (simulated Panda, 64 rows: the step took
# 0.26–0.27 s instead of 0.90–1.95 s per `dualid fit`; DFKI, 12 rows: the single run 0.16 s for seven methods, the
# sequence 0.39 s)
MASSLESS_SHARE = 0.01  # a prior body without mass: this share of the other bodies' mean mass (rounded_prior)
BALL_RADIUS_MIN = 0.01  # [m] the smallest radius of gyration of ball_prior's bodies
ROUNDING = 0.1  # each prior body's inertia about its centre of mass made up to this much rounder (rounded_body)


def torque_weights(problem: IdentificationProblem) -> np.ndarray:
    """w (p,): ‖Y_k‖² / ‖τ over the rows Y_k acts on‖² (1/w: the squared value of θ_k that would explain those rows'
    whole torque). Invariant under units of θ_k and of τ. A column with no effect gets its block's mean weight."""
    A = problem.Y.reshape(-1, problem.p)
    tau = problem.tau.reshape(-1)
    col2 = np.einsum("ik,ik->k", A, A)
    seen = np.abs(A) > 0
    tau2 = (seen * (tau**2)[:, None]).sum(axis=0)
    w = np.where((col2 > 0) & (tau2 > 0), col2 / np.where(tau2 > 0, tau2, 1.0), np.nan)
    for b in problem.parameters.blocks:
        idx = list(b.indices)
        fill = np.nanmean(w[idx]) if np.isfinite(w[idx]).any() else np.nanmean(w) if np.isfinite(w).any() else 1.0
        w[idx] = np.where(np.isfinite(w[idx]), w[idx], fill)
    return w


def rounded_body(theta_b: np.ndarray, alpha: float = ROUNDING) -> np.ndarray:
    """The 10 parameters of the body with θ_b's mass and centre of mass and the inertia (1 − α) I_c + α tr(I_c)/3 · 1
    about the centre of mass: a thin CAD body (a pseudo-inertia with a tiny eigenvalue, whose divergence would be
    stiff as 1/λ² along it) made at most α rounder; the smallest eigenvalue of its second moment is ≥ α/3 × the
    largest."""
    inertia = pin.Inertia.FromDynamicParameters(np.asarray(theta_b, dtype=float))
    Ic = np.array(inertia.inertia)
    Ic = (1.0 - alpha) * Ic + alpha * np.trace(Ic) / 3.0 * np.eye(3)
    return np.array(pin.Inertia(inertia.mass, np.array(inertia.lever), Ic).toDynamicParameters())


def rounded_prior(P, theta0: np.ndarray) -> np.ndarray:
    """θ₀ with every rigid body of positive mass rounded (``rounded_body``), and every massless or singular one (a
    URDF link without inertial, a point mass) replaced by a regularised body: MASSLESS_SHARE × the mean mass of the
    prior's other bodies, at its frame's origin, an isotropic inertia of their mean radius of gyration. Other
    entries unchanged."""
    theta0 = np.array(theta0, dtype=float)
    good, bad = [], []
    for b in (b for b in P.blocks if b.kind == "rigid_body"):
        idx = list(b.indices)
        if theta0[idx[0]] > 0:
            theta0[idx] = rounded_body(theta0[idx])
        C = b.constraint_matrix(theta0)
        (good if np.linalg.eigvalsh(C)[0] > 1e-12 * max(float(np.abs(C).max()), 1e-300) else bad).append(idx)
    if bad and good:
        masses = np.array([theta0[idx[0]] for idx in good])
        gyration = np.mean([np.sqrt(np.trace(pin.Inertia.FromDynamicParameters(theta0[idx]).inertia) / (2 * theta0[idx[0]]))
                            for idx in good])
        m = MASSLESS_SHARE * float(masses.mean())
        ball = pin.Inertia(m, np.zeros(3), m * gyration**2 * np.eye(3)).toDynamicParameters()
        for idx in bad:
            theta0[idx] = ball
    return theta0


def ball_prior(problem: IdentificationProblem, theta0: np.ndarray) -> tuple[np.ndarray, str]:
    """(θ₀, how its bodies were chosen or ""): when every rigid body of θ₀ has a zero mass (a URDF without inertials,
    or with zero masses everywhere), every body becomes the same ball: mass m at its joint frame's origin, inertia
    m r² 1 (r ≥ BALL_RADIUS_MIN), (m, m r²) the non-negative least squares of the training torques by that uniform
    robot (the other parameters at θ₀, NaN as 0). A regularised prior at the data's scale, physically consistent;
    otherwise θ₀ unchanged. Raises SolverError when the torques give such a robot no positive mass."""
    from scipy.optimize import nnls

    P = problem.parameters
    blocks = [b for b in P.blocks if b.kind == "rigid_body"]
    theta0 = np.array(theta0, dtype=float)
    if not blocks or any(theta0[b.indices[0]] != 0 for b in blocks):  # a negative mass is a bad prior, not none
        return theta0, ""
    rigid = [i for b in blocks for i in b.indices]
    rest = np.setdiff1d(np.arange(P.p), rigid)
    A = problem.Y.reshape(-1, P.p)
    target = problem.tau.reshape(-1) - A[:, rest] @ np.nan_to_num(theta0[rest])
    columns = np.stack([A[:, [b.indices[0] for b in blocks]].sum(axis=1),  # mass at each joint frame's origin
                        A[:, [b.indices[k] for b in blocks for k in (4, 6, 9)]].sum(axis=1)], axis=1)  # Ixx, Iyy, Izz
    (m, J), _ = nnls(columns, target)
    if not m > 0:
        raise SolverError("ball_prior: the URDF has no inertials and the training torques give a robot of equal "
                          "balls no positive mass; give inertials in the URDF or a prior.source parameters file")
    r = max(float(np.sqrt(J / m)), BALL_RADIUS_MIN)
    ball = pin.Inertia(float(m), np.zeros(3), m * r**2 * np.eye(3)).toDynamicParameters()
    for b in blocks:
        theta0[list(b.indices)] = ball
    return theta0, (f"the URDF has no inertials: every body's prior is the same ball fitted to the training torques "
                    f"({m:.4g} kg at its joint frame, radius of gyration {r:.3g} m)")


def prior_terms(problem: IdentificationProblem, theta0: np.ndarray):
    """(rigid [(idx, V, V flattened (k, m·m), log det C0, C0⁻¹)], quad_idx, quad_w, G (p, p)): the log-det blocks, the quadratic (torque-weighted)
    parameters and the prior metric G (R's Hessian at θ₀)."""
    P = problem.parameters
    w = torque_weights(problem)
    G = np.zeros((P.p, P.p))
    rigid, quad = [], []
    for b in P.blocks:
        idx = np.asarray(b.indices)
        if b.kind == "rigid_body":
            V = np.asarray(b.constraint_basis, dtype=float)
            C0 = b.constraint_matrix(theta0)  # V flattened once and log det C0 taken once: prior_value runs per iteration
            rigid.append((idx, V, np.ascontiguousarray(V.reshape(len(idx), -1)), np.linalg.slogdet(C0)[1],
                          np.linalg.inv(C0)))
            G[np.ix_(idx, idx)] = pullback_metric(V, C0)
        else:
            quad.extend(idx.tolist())
    quad_idx = np.array(quad, dtype=int)
    G[quad_idx, quad_idx] = w[quad_idx]
    return rigid, quad_idx, w[quad_idx], 0.5 * (G + G.T)


def prior_value(rigid, quad_idx, quad_w, theta, theta0, order: int = 0):
    """R(θ) (and its θ-gradient and Hessian when order): Σ log-det divergences + ½ Σ w (θ − θ₀)²."""
    p = theta.shape[0]
    e = theta[quad_idx] - theta0[quad_idx]
    f = 0.5 * float(np.sum(quad_w * e * e))
    grad = np.zeros(p) if order else None
    hess = np.zeros((p, p)) if order else None
    if order:
        grad[quad_idx] = quad_w * e
        hess[quad_idx, quad_idx] = quad_w
    for idx, V, V2, logdet0, C0inv in rigid:
        C = np.dot(theta[idx][None, :], V2).reshape(V.shape[1:])  # np.tensordot(θ_idx, V, 1) without its overhead
        try:
            L = np.linalg.cholesky(0.5 * (C + C.T))
        except np.linalg.LinAlgError:
            raise NotPositiveDefinite from None
        f += -2.0 * float(np.sum(np.log(np.diag(L)))) + logdet0 + float(np.sum(C0inv * C)) - C.shape[0]
        if order:
            Cinv = np.linalg.inv(C)
            grad[idx] += np.einsum("kab,ba->k", V, C0inv - Cinv)
            CV = np.einsum("ab,kbc->kac", Cinv, V)
            hess[np.ix_(idx, idx)] += np.einsum("kab,lba->kl", CV, CV)
    return f, grad, hess


def prior_divergence(problem: IdentificationProblem, theta: np.ndarray, theta0: np.ndarray) -> float:
    """R(θ) of the module docstring (inf where a rigid body is not strictly consistent)."""
    rigid, quad_idx, quad_w, _ = prior_terms(problem, theta0)
    try:
        return prior_value(rigid, quad_idx, quad_w, np.asarray(theta, dtype=float), theta0)[0]
    except NotPositiveDefinite:
        return float("inf")


def _inside(theta0: np.ndarray, cons: FeasibleSet) -> np.ndarray:
    """θ₀ moved strictly inside the bound rows (each row has one non-zero; rigid bodies: θ₀ is strictly consistent)."""
    theta = theta0.copy()
    for j in range(len(cons.h)):
        i = int(np.flatnonzero(cons.G[j])[0])
        s = cons.G[j, i] * theta[i] + cons.h[j]
        gap = 1e-3 * max(abs(theta[i]), abs(cons.h[j]), 1e-300)
        if s < gap:
            theta[i] += (gap - s) / cons.G[j, i]
    return theta


def _region_map(beta_hat: np.ndarray, C: np.ndarray, covariance: np.ndarray, radius2: float,
                s_ind: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(W, b) with u(θ) = W θ − b and (β − β̂)ᵀΣ_β⁻¹(β − β̂) = c²‖u‖²: u = Λ^-½ Uᵀ (Cs θ − s_ind ⊙ β̂) / √c², Cs =
    diag(s_ind) C, Σ̃ = U Λ Uᵀ the column-scaled Σ_β (eigenvalues floored)."""
    S = covariance * np.outer(s_ind, s_ind)
    w, U = np.linalg.eigh(0.5 * (S + S.T))
    w = np.maximum(w, SIGMA_RTOL * max(float(w.max(initial=0.0)), 1e-300))
    rad = np.sqrt(radius2)
    W = (U.T @ (C * s_ind[:, None])) / np.sqrt(w)[:, None] / rad  # (r, p)
    b = (U.T @ (s_ind * beta_hat)) / np.sqrt(w) / rad
    return W, b


def _region_lmi(W: np.ndarray, b: np.ndarray) -> LMI:
    """‖Wθ − b‖ ≤ 1 as the LMI [[I, u], [uᵀ, 1]] ⪰ 0 (its Schur complement is 1 − ‖u‖²), u = Wθ − b."""
    r, p = W.shape
    V = np.zeros((p, r + 1, r + 1))
    V[:, :r, r] = V[:, r, :r] = W.T
    C0 = np.eye(r + 1)
    C0[:r, r] = C0[r, :r] = -b
    return LMI("confidence region", np.arange(p), V, C0)


def solve_region(problem: IdentificationProblem, theta0: np.ndarray, beta_hat: np.ndarray, C: np.ndarray,
                 covariance: np.ndarray, radius2: float, scale: np.ndarray, s_ind: np.ndarray,
                 theta_hat: np.ndarray) -> dict:
    """The module's problem. Returns {theta, mu, statistic, G, chain, solves, note}; raises SolverError when the
    penalised sequence's first interior point fails."""
    P = problem.parameters
    rigid, quad_idx, quad_w, G = prior_terms(problem, theta0)
    W, b = _region_map(beta_hat, C, covariance, radius2, s_ind)
    WtW = W.T @ W
    if P.margin_reference is not None:  # chosen without the fit's margin C_b(θ) ⪰ ε·C_b(θ_ref) (docs/margin.md)
        P = dataclasses.replace(P, margin_reference=None, margin_epsilon=0.0, margin_label="")
    cons = feasible_set(P)
    theta = _inside(np.asarray(theta0, dtype=float), cons)

    def objective(th: np.ndarray, order: int, mu: float) -> Derivatives:
        f, g, H = prior_value(rigid, quad_idx, quad_w, th, theta0, order)
        u = W @ th - b
        f += mu * float(u @ u)
        if not order:
            return Derivatives(f)
        H = H + 2.0 * mu * WtW
        return Derivatives(f, g + 2.0 * mu * (W.T @ u), 0.5 * (H + H.T))

    def solve(mu: float, start: np.ndarray) -> np.ndarray:
        try:
            return run_quadratic(cons, start, TOL, 200, lambda t, order: objective(t, order, mu), 1.0)[0]
        except NotPositiveDefinite:  # a start outside the prior's domain (a body not strictly consistent)
            raise SolverError("plausible parameters: the start is not strictly consistent",
                              status="no_start") from None

    def u_norm(th: np.ndarray) -> float:
        return float(np.linalg.norm(W @ th - b))

    chain: list[str] = []
    if u_norm(theta) <= 1.0:  # the prior itself is in the region
        return {"theta": theta, "mu": 0.0, "statistic": u_norm(theta) ** 2 * radius2, "G": G,
                "chain": "the prior is in the region", "solves": 0, "note": ""}
    both = dataclasses.replace(cons, lmis=(*cons.lmis, _region_lmi(W, b)))
    t = 1.0 - 0.5 / u_norm(theta)  # u(θ₀ + t(θ̂ − θ₀)) = (1 − t) u(θ₀): inside the region

    def region_run() -> dict | None:
        return _region_run(both, _region_start(both, theta, theta_hat, C, scale, t),
                           lambda t_, order: objective(t_, order, 0.0), u_norm, radius2, G, chain)

    large = len(b) + 1 >= REGION_ROWS_MAX
    one = None  # the region's run as a candidate: it ended with a heavy body, or the sequence below did not succeed
    if large:
        chain.append(f"a region LMI of {len(b) + 1} rows: the penalised sequence")
    else:
        one = region_run()
        heavy = [] if one is None else heavy_links(P, one["theta"], theta0)
        if one is not None and not heavy:
            return one
        if heavy:  # a start near θ̂'s completed masses (10¹¹ kg: not determined by the data) left the iterates 11
            # decades apart in scale and the run stopped there; the problem is convex, so the penalised sequence from
            # the prior solves it too, and the lower R of the two is kept
            chain.append(f"{one['chain']} ended with the body of {heavy[0][0]} at {heavy[0][1]:.3g} kg (above "
                         f"{HEAVY_RATIO:g} × the prior's whole moving mass)")
    try:
        th, mu_best, solves, note = _penalised(solve, u_norm, theta, radius2, chain)
    except (SolverError, ArithmeticError, np.linalg.LinAlgError):
        if one is None and large:  # the region's run as the last resort
            one = region_run()
        if one is None:
            raise
        return {**one, "chain": "; ".join((*chain, f"{one['chain']}: kept (the penalised sequence failed)"))}
    if note and large and one is None:  # the sequence ended outside the region: the region's run as the last resort
        one = region_run()
    def divergence(th_: np.ndarray) -> float:  # R (``prior_divergence``) from the terms built above
        return value_or_inf(lambda t_, order: objective(t_, order, 0.0), th_)

    if one is not None and (note or divergence(one["theta"]) < divergence(th)):
        why = "the sequence ended outside the region" if note else "its R is lower"
        return {**one, "solves": one["solves"] + solves, "chain": "; ".join((*chain, f"{one['chain']}: kept ({why})"))}
    chain.append(f"interior point, {solves} solves, μ {mu_best:.3g}, statistic {u_norm(th) ** 2 * radius2:.3g}")
    return {"theta": th, "mu": float(mu_best), "statistic": u_norm(th) ** 2 * radius2, "G": G,
            "chain": "; ".join(chain), "solves": solves, "note": note}


def _region_run(both: FeasibleSet, start: np.ndarray | None, objective, u_norm, radius2: float, G: np.ndarray,
                chain: list[str]) -> dict | None:
    """One interior point on R with the region as a constraint (``both``) from ``start``, its tolerance relative to
    R there: its result where it ends inside the region; None where there is no start, the run fails or it ends
    outside (said in ``chain``)."""
    if start is None:
        chain.append("no strictly feasible start in the region")
        return None
    try:
        th, Z, _, info = run_interior_point(None, both, start, None, None, TOL * 1e-3, 200, 0, False,
                                            objective=objective, f_scale=1.0)
    except (SolverError, ArithmeticError, np.linalg.LinAlgError) as exc:
        chain.append(f"interior point with the region as a constraint failed ({type(exc).__name__})")
        return None
    if u_norm(th) > 1.0 + 1e-7:  # (a tiny region: u = Wθ − b cancels ~1/c-sized terms in the LMI)
        chain.append(f"interior point with the region as a constraint ended outside it (‖u‖ = {u_norm(th):.9g})")
        return None
    # Z = μ v vᵀ with v = (−u, 1) at ‖u‖ = 1: the multiplier of μ‖u‖²
    return {"theta": th, "mu": float(Z[-1][-1, -1]), "statistic": u_norm(th) ** 2 * radius2, "G": G, "note": "",
            "solves": 1, "chain": f"interior point with the region as a constraint, {info['iterations']} iterations"}


def _region_start(both: FeasibleSet, theta: np.ndarray, theta_hat: np.ndarray, C: np.ndarray, scale: np.ndarray,
                  t: float) -> np.ndarray | None:
    """A strictly feasible point of the region problem (``both``: the constraints and the region) from the prior
    ``theta``: θ₀ + t·(θ̂'s base parameters − θ₀'s), θ₀'s others (inside the region); else on the way from it to
    θ₀ + t(θ̂ − θ₀) (strictly consistent when θ̂ is consistent, the prior being strictly); None if neither is."""
    Cs = C / scale[None, :]  # the base parameters in the column-scaled chart
    towards = (np.linalg.pinv(Cs) @ (Cs @ (scale * (theta_hat - theta)))) / scale
    start = theta + t * towards
    if both.margin(start) > 0:
        return start
    far = theta + t * (np.asarray(theta_hat, dtype=float) - theta)
    return far + 0.9 * min(1.0, both.max_step(far, start - far)) * (start - far) if both.margin(far) > 0 else None


def _penalised(solve, u_norm, theta: np.ndarray, radius2: float,
               chain: list[str]) -> tuple[np.ndarray, float, int, str]:
    """(θ, μ, solves, note) of the penalised sequence from the prior ``theta`` (module docstring); ``solve(μ, start)``
    is one interior point of R + μ‖u‖², ``u_norm(θ)`` = ‖u(θ)‖; a failure is appended to ``chain``."""
    # g(t) = log ‖u‖ at μ = e^t falls with t: bracket its root by ×10 steps, then regula falsi (Illinois)
    bracket: dict[str, tuple[float, float]] = {}  # "lo": (t, g > 0), "hi": (t, g ≤ 0)
    t, solves, best, last, side = 0.0, 0, None, theta, ""
    while solves < MAX_SOLVES:
        try:
            th = solve(float(np.exp(t)), last)
        except SolverError as exc:
            chain.append(f"μ {np.exp(t):.3g}: {exc.status}")
            if solves == 0:
                raise SolverError(f"plausible parameters: the interior point failed ({'; '.join(chain)})",
                                  status=exc.status) from None
            break
        solves += 1
        last, un = th, u_norm(th)
        g = float(np.log(max(un, 1e-300)))
        if g <= 0:
            best = (th, float(np.exp(t)), un)
            if g >= -U_TOL:
                break
        new = "hi" if g <= 0 else "lo"
        if new == side and len(bracket) == 2:  # Illinois: halve the stale end's value
            other = "lo" if new == "hi" else "hi"
            bracket[other] = (bracket[other][0], 0.5 * bracket[other][1])
        bracket[new], side = (t, g), new
        if len(bracket) < 2:
            t += np.log(10.0) if new == "lo" else -np.log(10.0)
            if t > np.log(MU_MAX):
                break
            continue
        (t_lo, g_lo), (t_hi, g_hi) = bracket["lo"], bracket["hi"]
        if abs(t_hi - t_lo) < 1e-9:
            break
        t = t_lo - g_lo * (t_hi - t_lo) / (g_hi - g_lo)
    note = ""
    if best is None:  # no μ ≤ MU_MAX reached the region: keep the last point and say so
        best = (last, float(np.exp(t)), u_norm(last))
        note = (f"no strictly consistent θ inside the region was found (the data pin a body onto the consistency "
                f"boundary): the written θ lies at {best[2] ** 2 * radius2:.3g} against the radius {radius2:.3g}")
    return best[0], best[1], solves, note
