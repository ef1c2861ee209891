"""Plausible parameters: among all θ with the same training predictions as θ̂, the one closest to a prior θ₀.

A URDF chain is never fully identifiable from joint torques: θ̂ + z for any z in the null space of the
stacked regressor Y predicts the training torques exactly as θ̂ does, and a fit returns one of these
minimisers, whose values along the null directions (e.g. a 1,700 kg link) come from the solver, not
from the data. ``plausible_parameters`` chooses

    θ_p = argmin_θ  Σ_b D(C_b(θ) ‖ C_b(θ₀))   subject to   θ − θ̂ ∈ null(Y),   C_b(θ) ⪰ 0, bounds,

with D(C‖C₀) = −log det C + log det C₀ + tr(C₀⁻¹C) − m the log-det (Bregman) divergence of each
block's constraint matrix (``model.consistency.prior_blocks``: 4×4 pseudo-inertias of rigid bodies,
diag(x) of non-negative joint terms). D is invariant under a change of the body frame and of units,
so the choice does not depend on how θ is written down.

The null space is that of ``IdentificationProblem.identifiability`` (the one rank rule of
``dualid.linalg``, on unit-norm columns). θ is parametrised as c + N z, N a basis of the null space
orthonormal in the prior's metric G (the divergence's Hessian at θ₀) and c the point of the slice
nearest θ₀ in G, so the equality constraint P_range(θ − θ̂) = 0 holds by construction and the
solver's variables are O(1) even when θ̂ is 1e5 away from θ₀.

Which parameters the data determine: the prior share of parameter k is (N_G N_Gᵀ G)_kk, the diagonal
of the G-orthogonal projector onto the null space, i.e. ∂θ_p,k/∂θ₀,k where no constraint is active:
0 when the data fix θ_k (no null component), 1 when θ_k alone is a null direction (e.g. the mass of
a first link turning about a vertical axis). ``determined_by`` says "prior" from a share of 0.5 on.

When no strictly consistent θ has θ̂'s predictions (the data pin a body onto the consistency
boundary, det C_b = 0), the log-det divergence is infinite everywhere on the slice; then its
second-order expansion at θ₀ (the constant pullback metric, finite on the boundary) is minimised
instead, and ``objective`` says so. Clarabel solves the conic problems, SCS is the fallback; an
inaccurate solution is kept only when it is physically consistent, and the chain records every try.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.errors import ConfigError, ConsistencyError, DataError, SolverError
from dualid.estimators.base import SOLVERS, captured_warnings, is_problem_property, solve_cvxpy
from dualid.model.consistency import check_nominal, prior_blocks, pullback_metric, regularizer_value
from dualid.problem import IdentificationProblem

DATA, PRIOR = "data", "prior"
PRIOR_SHARE = 0.5  # a parameter whose prior share is at least this is "determined by the prior"
PREDICTION_RTOL = 1e-8  # ‖Y(θ_p − θ̂)‖ / ‖Y θ̂‖ above which the training predictions count as changed
TIE_BREAK = 1e-9  # weight of ‖z‖² (z in the prior metric's units) making the choice unique where the prior is flat
# the choice needs a feasible, better point, not 1e-10 optimality (checked after the solve); a fallback
# must not take minutes
OPTIONS = {"CLARABEL": {"tol_gap_abs": 1e-8, "tol_gap_rel": 1e-8, "tol_feas": 1e-8, "max_iter": 200},
           "SCS": {"eps": 1e-8, "max_iters": 20000}}


@dataclass(frozen=True, eq=False)
class PlausibleParameters:
    """θ_p and how it was chosen (see the module docstring). Arrays are read-only."""

    theta: np.ndarray  # (p,) θ_plausible
    theta_hat: np.ndarray  # (p,) the fit it started from
    theta0: np.ndarray  # (p,) the prior
    names: tuple[str, ...]
    prior_share: np.ndarray  # (p,) ∂θ_p,k/∂θ₀,k of the quadratic model: 0 fixed by the data, 1 set by the prior
    determined_by: tuple[str, ...]  # (p,) "prior" where prior_share ≥ PRIOR_SHARE, else "data"
    null_space: np.ndarray  # (p, p − rank) directions of θ the data do not determine (θ units)
    rank: int  # number of data-determined combinations
    status: str  # the solver's status, or "full rank" when there was nothing to choose
    solver: str  # "CLARABEL", "SCS" or "none"
    solver_chain: str  # what was tried, e.g. "logdet CLARABEL optimal" or "logdet CLARABEL failed (…) → …"
    fallback_used: bool
    objective: str  # "logdet"; "pullback" when no strictly consistent θ has θ̂'s predictions; "prior": plausible_newton's R
    prediction_change: float  # ‖Y(θ_p − θ̂)‖ / ‖Y θ̂‖ on the training data
    predictions_unchanged: bool  # prediction_change ≤ PREDICTION_RTOL
    consistent: bool  # θ_p physically consistent (tolerance 1e-7, as IdentificationResult)
    divergence_hat: float  # Σ_b D(C_b(θ̂) ‖ C_b(θ₀)) (inf when θ̂ is on the consistency boundary)
    divergence: float  # Σ_b D(C_b(θ_p) ‖ C_b(θ₀))
    # the noise-aware choice (evaluation.plausible_region): "exact" (θ̂'s predictions) or "confidence" (β(θ) in
    # the fit's confidence ellipsoid at ``level``: (β − β̂)ᵀΣ⁻¹(β − β̂) ≤ χ²_r(level) = radius2)
    form: str = "exact"
    level: float = 0.0
    radius2: float = 0.0  # χ²_r(level)
    statistic: float = 0.0  # (β(θ_p) − β̂)ᵀΣ⁻¹(β(θ_p) − β̂) at the solution
    training_rmse_hat: float = float("nan")  # τ RMSE of θ̂ on the training data (all joints)
    training_rmse: float = float("nan")  # the same for θ_p
    note: str = ""  # e.g. why the exact form was used although a region was asked for

    def __post_init__(self) -> None:
        for name in ("theta", "theta_hat", "theta0", "null_space", "prior_share"):
            a = np.array(getattr(self, name), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def by_prior(self) -> tuple[str, ...]:
        """Names of the parameters whose value the prior chose."""
        return tuple(n for n, d in zip(self.names, self.determined_by) if d == PRIOR)

    def as_dict(self) -> dict:
        return {
            "status": self.status, "solver": self.solver, "solver_chain": self.solver_chain,
            "fallback_used": self.fallback_used, "objective": self.objective, "rank": self.rank,
            "null_dimension": int(self.null_space.shape[1]),
            "prediction_change": self.prediction_change, "predictions_unchanged": self.predictions_unchanged,
            "consistent": self.consistent, "divergence_raw": self.divergence_hat, "divergence": self.divergence,
            "form": self.form, "level": self.level, "radius2": self.radius2, "statistic": self.statistic,
            "training_rmse_raw": self.training_rmse_hat, "training_rmse": self.training_rmse, "note": self.note,
        }


def _null_basis(problem: IdentificationProblem) -> tuple[np.ndarray, int, tuple[str, ...]]:
    """(N (p, k) null-space basis in θ units whose columns are orthonormal after column scaling, rank,
    the parameters with a component in the null space)."""
    ident = problem.identifiability()
    scale = np.linalg.norm(problem.Y.reshape(-1, problem.p), axis=0)
    scale[scale == 0] = 1.0
    if ident.null_space.size == 0:
        return np.zeros((problem.p, 0)), ident.rank, ()
    Q, _ = np.linalg.qr(ident.null_space * scale[:, None])  # orthonormal in the scaled chart
    return Q / scale[:, None], ident.rank, ident.unidentifiable


def _scaled_block(theta, idx, V, C0):
    """(S C(θ_b) S, (S C₀ S)⁻¹) with S = diag(C₀)^-½: the congruence keeps the cone's entries O(1) near
    θ₀ and changes the divergence only by a constant."""
    import cvxpy as cp

    k, m, _ = V.shape
    S = 1.0 / np.sqrt(np.diag(C0))
    VS = V * S[None, :, None] * S[None, None, :]
    C = cp.reshape(VS.reshape(k, m * m).T @ theta[idx], (m, m), order="C")
    return 0.5 * (C + C.T), np.linalg.inv(C0 * np.outer(S, S))


def _prior_metric(P, blocks, scale: np.ndarray) -> np.ndarray:
    """G (p, p): the pullback metric g_b at θ₀ on each constrained block (the divergence's Hessian
    there), the data chart's 1/scale² on unconstrained parameters; used only to scale the variables."""
    G = np.diag(1.0 / scale**2)
    for idx, V, C0 in blocks:
        G[np.ix_(idx, idx)] = pullback_metric(V, C0)
    return 0.5 * (G + G.T)


def _pullback_term(theta, idx, V, C0, theta0):
    """(θ_b − θ_b0)ᵀ g (θ_b − θ_b0), g the pullback of the affine-invariant metric at C₀: the divergence's
    second-order expansion at θ₀, finite on the consistency boundary too."""
    import cvxpy as cp

    w, U = np.linalg.eigh(pullback_metric(V, C0))
    F = U * np.sqrt(np.maximum(w, 0.0))
    return cp.sum_squares(F.T @ (theta[idx] - theta0[idx]))


def _min_margin(P, theta: np.ndarray) -> float:
    """Smallest eigenvalue over the blocks, each relative to its largest (scale-free)."""
    out = np.inf
    for b in P.blocks:
        C = b.constraint_matrix(theta)
        if C is not None:
            lam = np.linalg.eigvalsh(C)
            out = min(out, lam[0] / max(abs(lam[-1]), 1e-300))
    return float(out)


def clear_boundary(theta_p: np.ndarray, theta_hat: np.ndarray, P) -> tuple[np.ndarray, float]:
    """θ_p, or the first point θ_p + t(θ̂ − θ_p), t = 1e-8 … 1, with every block's constraint matrix ⪰ 0
    (both ends have θ̂'s predictions, so every point between does): a solver's 1e-10-size violation
    would make the URDF writer refuse the body. Returns (θ, t)."""
    if _min_margin(P, theta_p) >= 0:
        return theta_p, 0.0
    for t in 10.0 ** np.arange(-8, 0):
        theta = theta_p + t * (theta_hat - theta_p)
        if _min_margin(P, theta) >= 0:
            return theta, float(t)
    raise SolverError("plausible_parameters: the solution violates physical consistency (smallest constraint "
                      f"eigenvalue {_min_margin(P, theta_p):.3g} relative) and so does every point within 10 % of the "
                      "way back to θ̂", status="inconsistent")


def _bounds(theta, P) -> list:
    lo = np.full(P.p, -np.inf) if P.lower is None else np.asarray(P.lower)
    hi = np.full(P.p, np.inf) if P.upper is None else np.asarray(P.upper)
    out = []
    if np.isfinite(lo).any():
        out.append(theta[np.flatnonzero(np.isfinite(lo))] >= lo[np.isfinite(lo)])
    if np.isfinite(hi).any():
        out.append(theta[np.flatnonzero(np.isfinite(hi))] <= hi[np.isfinite(hi)])
    return out


def _solve(cvx, z, solver: str, solver_options, chain: list[str], what: str, usable):
    """Solved or None, trying ``solver`` then the others of SOLVERS; every attempt is appended to chain.
    An "optimal_inaccurate" point is kept when usable(z) (physically consistent), and labelled so."""
    for name in dict.fromkeys((solver, *SOLVERS)):
        options = {**OPTIONS[name], **dict(solver_options or {})} if name == solver else OPTIONS[name]
        failure = None
        with captured_warnings() as notes:  # what the solver said (its printed lines too) goes into the chain
            try:
                solved = solve_cvxpy(cvx, z, name, options, f"plausible parameters ({what})")
            except SolverError as exc:
                failure = exc
        said = f" [{'; '.join(notes)}]" if notes else ""
        if failure is not None:
            chain.append(f"{what} {name} failed ({failure.status}){said}")
            if is_problem_property(failure):
                return None
            continue
        if solved.status != "optimal":
            ok = usable(solved.value)
            chain.append(f"{what} {name} {solved.status}" + (" (kept: consistent)" if ok else "") + said)
            if ok:
                return solved
            continue
        chain.append(f"{what} {name} optimal{said}")
        return solved
    return None


def solve_divergence(theta, z, x, point, scaled, blocks, theta0, constraints, P, solver, solver_options,
                     chain: list[str]):
    """Minimise the log-det divergence to the prior (plus TIE_BREAK·‖z‖²) over the cvxpy variable ``x`` (θ = the
    affine expression ``theta`` of it; ``point``: x's value → θ), falling back to its second-order (pullback)
    expansion when no strictly consistent θ is found (e.g. the data pin a body onto the consistency boundary).
    Returns (the solved variable or None, "logdet" | "pullback"); every try is recorded in ``chain``."""
    import cvxpy as cp

    objective = "logdet"

    def usable(x_value) -> bool:  # an inaccurate point is kept only when consistent (log-det: strictly)
        th = point(x_value)
        strict = objective == "pullback" or np.isfinite(regularizer_value("logdet", P, th, theta0))
        return strict and P.is_consistent(th, tol=1e-7)

    logdet = sum(-cp.log_det(C) + cp.sum(cp.multiply(C0inv, C)) for C, C0inv in scaled)
    cvx = cp.Problem(cp.Minimize(logdet + TIE_BREAK * cp.sum_squares(z)), constraints)
    solved = _solve(cvx, x, solver, solver_options, chain, "logdet", usable)
    if solved is None:
        objective = "pullback"
        quad = sum(_pullback_term(theta, idx, V, C0, theta0) for idx, V, C0 in blocks)
        cvx = cp.Problem(cp.Minimize(quad + TIE_BREAK * cp.sum_squares(z)), constraints)
        solved = _solve(cvx, x, solver, solver_options, chain, "pullback", usable)
    return solved, objective


def checked_prior(P, theta0, solver: str, who: str) -> np.ndarray:
    """θ₀ as a strictly consistent array (ConsistencyError otherwise: the divergence needs C_b(θ₀)⁻¹), with
    ``solver`` checked (ConfigError); ``who`` names the caller in the messages."""
    try:
        theta0 = check_nominal(P, theta0, strict=True)
    except ConsistencyError as exc:
        raise ConsistencyError(f"{who}: the prior {exc}") from None
    if solver not in SOLVERS:
        raise ConfigError(f"{who}: solver must be one of {', '.join(SOLVERS)}, got {solver!r}")
    return theta0


def plausible_parameters(problem: IdentificationProblem, theta_hat, theta0, solver: str = "CLARABEL",
                         solver_options: dict | None = None) -> PlausibleParameters:
    """θ_p closest to the prior θ₀ among the θ with the training predictions of θ̂ (module docstring).

    θ₀ must be strictly consistent (every constrained block positive definite: the divergence needs
    C_b(θ₀)⁻¹). Raises SolverError when no consistent θ has θ̂'s predictions or both solvers fail.
    """
    import cvxpy as cp

    P = problem.parameters
    theta_hat = np.asarray(theta_hat, dtype=float)
    if theta_hat.shape != (P.p,) or not np.all(np.isfinite(theta_hat)):
        raise DataError(f"plausible_parameters: θ̂ must be {P.p} finite numbers, got shape {theta_hat.shape}")
    theta0 = checked_prior(P, theta0, solver, "plausible_parameters")
    N, rank, _ = _null_basis(problem)
    blocks = prior_blocks("logdet", P, theta0)
    scale = np.linalg.norm(problem.Y.reshape(-1, P.p), axis=0)
    scale[scale == 0] = 1.0
    G = _prior_metric(P, blocks, scale)
    if N.shape[1]:
        try:
            L = np.linalg.cholesky(N.T @ G @ N)
            NG = np.linalg.solve(L, N.T).T  # the same null space, orthonormal in the prior's metric: z is O(1)
        except np.linalg.LinAlgError:  # a metric too ill-conditioned for Cholesky: its eigenvalues, floored
            ev, EV = np.linalg.eigh(N.T @ G @ N)
            NG = N @ (EV / np.sqrt(np.maximum(ev, 1e-12 * max(float(ev.max()), 1e-300))))
    else:
        NG = N
    # the G-orthogonal projector onto the null space, NG NGᵀ G, is ∂θ_p/∂θ₀ where no constraint is active
    share = np.clip(np.einsum("kj,kj->k", NG, (G @ NG)), 0.0, 1.0)
    share[np.linalg.norm(N * scale[:, None], axis=1) <= 1e-6] = 0.0  # no null component: the data's alone
    determined = tuple(PRIOR if x >= PRIOR_SHARE else DATA for x in share)
    common = dict(theta_hat=theta_hat, theta0=theta0, names=P.names, prior_share=share, determined_by=determined,
                  null_space=N, rank=rank, divergence_hat=regularizer_value("logdet", P, theta_hat, theta0))
    if N.shape[1] == 0:
        return PlausibleParameters(
            theta_hat, status="full rank", solver="none", solver_chain="full rank: nothing to choose",
            fallback_used=False, objective="none", prediction_change=0.0, predictions_unchanged=True,
            consistent=P.is_consistent(theta_hat, tol=1e-7), divergence=common["divergence_hat"], **common)
    # centre: the point of the slice nearest θ₀ in G, constraints ignored. Solving for a small offset from it
    # keeps the bodies the data pin near the consistency boundary accurate (θ̂ itself may be 1e5 away)
    centre = theta_hat - NG @ (NG.T @ (G @ (theta_hat - theta0)))
    z = cp.Variable(N.shape[1])
    theta = centre + NG @ z
    scaled = [_scaled_block(theta, idx, V, C0) for idx, V, C0 in blocks]
    constraints = [C >> 0 for C, _ in scaled] + _bounds(theta, P)
    chain: list[str] = []

    solved, objective = solve_divergence(theta, z, z, lambda z_value: centre + NG @ z_value, scaled, blocks, theta0,
                                         constraints, P, solver, solver_options, chain)
    if solved is None:
        raise SolverError(f"plausible_parameters: no physically consistent θ with the training predictions of θ̂ "
                          f"was found: {' → '.join(chain)}", status="all_solvers_failed")
    fallback_used = len(chain) > 1  # another solver or objective than the first
    try:
        theta_p, pulled = clear_boundary(centre + NG @ solved.value, theta_hat, P)
    except SolverError as exc:
        raise SolverError(f"{exc} ({' → '.join(chain)})", status=exc.status) from None
    if pulled:
        chain.append(f"moved {pulled:.1e} of the way back to θ̂ to clear a rounding-size violation of consistency")
    A = problem.Y.reshape(-1, P.p)
    change = float(np.linalg.norm(A @ (theta_p - theta_hat)) / max(np.linalg.norm(A @ theta_hat), 1e-300))
    return PlausibleParameters(
        theta_p, status=solved.status, solver=solved.solver, solver_chain=" → ".join(chain),
        fallback_used=fallback_used, objective=objective, prediction_change=change,
        predictions_unchanged=change <= PREDICTION_RTOL,
        consistent=P.is_consistent(theta_p, tol=1e-7), divergence=regularizer_value("logdet", P, theta_p, theta0),
        **common,
    )


HEAVY_RATIO = 2.0  # a link heavier than this × the prior's whole moving mass: not written to a model file, and a
# region solve ending there is checked against the penalised sequence (``solve_region``)


def moving_mass(P, theta0: np.ndarray) -> float:
    """The total mass of ``theta0``'s rigid bodies (negative masses counted as 0)."""
    return float(sum(max(theta0[b.indices[0]], 0.0) for b in P.blocks if b.kind == "rigid_body"))


def heavy_links(P, theta: np.ndarray, theta0: np.ndarray) -> list[tuple[str, float, float]]:
    """[(block, mass, the prior's mass)] of the rigid bodies of ``theta`` heavier than HEAVY_RATIO × ``moving_mass`` of
    ``theta0`` (none when the prior has no mass: nothing to compare with)."""
    total = moving_mass(P, theta0)
    if not total > 0:
        return []
    return [(b.name, float(theta[b.indices[0]]), float(theta0[b.indices[0]])) for b in P.blocks
            if b.kind == "rigid_body" and theta[b.indices[0]] > HEAVY_RATIO * total]
