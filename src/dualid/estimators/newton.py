"""Dual-metric least squares by a structure-exploiting primal–dual interior-point Newton method.

    min_θ f(θ) = Σ_i r_iᵀ M_i(θ)⁻¹ r_i,   r_i = Y_i θ − τ_i,   M_i(θ) ≻ 0 (the domain),
    s.t.  C_b(θ) = C_b0 + Σ_k θ_k V_bk ⪰ 0   (pseudo-inertia / drag matrices: small LMIs)
          G θ + h ≥ 0                        (diagonal blocks and per-parameter bounds)

With w_i = M_i⁻¹ r_i the derivatives are (M affine in θ, so the Hessian below is *exact*, not an
approximation: d/dθ_l of 2Y_kᵀw − wᵀM_k w is 2(Y_k − M_k w)ᵀ dw/dθ_l, dw/dθ_l = M⁻¹(Y_l − M_l w)):

    ∂f/∂θ_k        = Σ_i 2 Y_ikᵀ w_i − w_iᵀ M_ik w_i
    ∂²f/∂θ_k∂θ_l   = Σ_i 2 (Y_ik − M_ik w_i)ᵀ M_i⁻¹ (Y_il − M_il w_i)      (PSD: f is convex)

Both are accumulated over chunks of samples (default 4,096) with batched Cholesky factors and the
factored metric (the quantities of ``AffineMetric.quad`` / ``apply``, computed together), so memory
is O(chunk·n·p) beyond the problem's own arrays; the dense N·p·n² basis is never formed.

Constraints: primal–dual (HKM) Newton steps on C_b Z_b = σμ I (and s_j z_j = σμ), where the dual
variables are eliminated: (∇²f + Ψ) Δθ = −∇f + σμ A*(C⁻¹), Ψ_kl = Σ_b tr(V_k Z_b V_l C_b⁻¹). The
step is a descent direction of the barrier merit f − σμ Σ log det C_b, on which a backtracking line
search keeps every C_b ≻ 0 and every M_i ≻ 0 (every Cholesky must succeed). σ by Mehrotra's
predictor heuristic (≥ 0.05), one step length for primal and dual. Stops when the duality gap
Σ⟨C_b, Z_b⟩ plus the squared Newton decrement of the Lagrangian is below tol·f.

Start: least squares from the sufficient statistics, moved toward a strictly feasible point (each
block's matrix with its eigenvalues lifted); only if that fails, a small phase-I conic problem
(cvxpy; size p plus the offending samples) decides between a start, SolverError (constraints with
empty interior) and MetricError (no feasible θ makes every M_i ≻ 0). For N > 200,000 the iterations
are warm-started from a strided 50,000-sample subsample.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from dualid.errors import MetricError, SolverError
from dualid.estimators.least_squares import energy_statistics, statistics
from dualid.estimators.result import IdentificationResult
from dualid.problem.problem import IdentificationProblem


class _NotPositiveDefinite(Exception):
    """Some M_i(θ) is not positive definite (θ outside the domain)."""


# --- constraints --------------------------------------------------------------------------------
@dataclass(frozen=True)
class _LMI:
    """C(θ) = C0 + Σ_k θ[idx_k] V_k ⪰ 0, an m×m block."""

    name: str
    idx: np.ndarray  # (k,) parameter indices
    V: np.ndarray  # (k, m, m)
    C0: np.ndarray  # (m, m)

    def C(self, theta: np.ndarray) -> np.ndarray:
        return self.C0 + np.tensordot(theta[self.idx], self.V, axes=1)

    def dC(self, d: np.ndarray) -> np.ndarray:
        return np.tensordot(d[self.idx], self.V, axes=1)


@dataclass(frozen=True)
class _Constraints:
    """The feasible set: LMIs (rigid bodies, drag matrices) and linear rows G θ + h ≥ 0."""

    lmis: tuple[_LMI, ...]
    G: np.ndarray  # (q, p)
    h: np.ndarray  # (q,)
    names: tuple[str, ...]  # (q,) what each linear row is, for messages

    @property
    def size(self) -> int:
        """Σ block sizes (the barrier parameter's ν)."""
        return sum(c.V.shape[1] for c in self.lmis) + len(self.h)

    @property
    def empty(self) -> bool:
        return self.size == 0

    def margin(self, theta: np.ndarray) -> float:
        """Smallest eigenvalue over all blocks and rows (> 0: strictly feasible)."""
        m = [np.linalg.eigvalsh(c.C(theta))[0] for c in self.lmis]
        if len(self.h):
            m.append((self.G @ theta + self.h).min())
        return float(min(m)) if m else np.inf

    def max_step(self, theta: np.ndarray, d: np.ndarray) -> float:
        """Largest α with every constraint strictly feasible on [θ, θ + α d) (inf if unbounded)."""
        alpha = np.inf
        for c in self.lmis:
            alpha = min(alpha, _max_step_psd(c.C(theta), c.dC(d)))
        if len(self.h):
            s, ds = self.G @ theta + self.h, self.G @ d
            neg = ds < 0
            if neg.any():
                alpha = min(alpha, float(np.min(-s[neg] / ds[neg])))
        return alpha


def _repair_psd(X: np.ndarray, floor: float = 1e-14) -> np.ndarray:
    """X itself if it is numerically positive definite, else its eigenvalues lifted to ≥ floor·λ_max."""
    X = 0.5 * (X + X.T)
    try:
        np.linalg.cholesky(X)
        return X
    except np.linalg.LinAlgError:
        lam, U = np.linalg.eigh(X)
        return (U * np.maximum(lam, floor * max(lam.max(), 1e-300))) @ U.T


def _max_step_psd(X: np.ndarray, dX: np.ndarray) -> float:
    """Largest α with X + α dX ≻ 0 for X ≻ 0."""
    L = np.linalg.cholesky(_repair_psd(X))
    Li = np.linalg.inv(L)
    lam = np.linalg.eigvalsh(Li @ dX @ Li.T)[0]
    return np.inf if lam >= 0 else float(-1.0 / lam)


def build_constraints(parameters, constrained: bool = True, fixed: np.ndarray | None = None) -> _Constraints:
    """LMIs for rigid-body and drag-matrix blocks; linear rows for diagonal blocks and bounds."""
    p = parameters.p
    lmis, rows, h, names = [], [], [], []
    if constrained:
        for b in parameters.blocks:
            V = b.constraint_basis
            if V is None:
                continue
            idx = np.asarray(b.indices)
            if b.kind in ("drag_diagonal", "nonnegative"):
                for i in idx:
                    g = np.zeros(p)
                    g[i] = 1.0
                    rows.append(g), h.append(0.0), names.append(f"{parameters.names[i]} ≥ 0")
                continue
            lmis.append(_LMI(b.name, idx, np.asarray(V, dtype=float), np.zeros(V.shape[1:])))
        for bound, sign in ((parameters.lower, 1.0), (parameters.upper, -1.0)):
            if bound is None:
                continue
            for i, x in enumerate(bound):
                if np.isfinite(x):
                    g = np.zeros(p)
                    g[i] = sign
                    rows.append(g), h.append(-sign * x)
                    names.append(f"{parameters.names[i]} {'≥' if sign > 0 else '≤'} {x:g}")
    G = np.array(rows).reshape(-1, p)
    return _Constraints(tuple(lmis), G, np.asarray(h, dtype=float), tuple(names))


# --- objective ----------------------------------------------------------------------------------
# Per-sample matrices are tiny (n ≲ 10) and numerous, where LAPACK's per-matrix calls are slow: the
# kernels below loop over the small dimensions and vectorise over the samples of a chunk instead.
def _cholesky(M: np.ndarray) -> np.ndarray:
    """L (c, n, n) lower triangular with M_i = L_i L_iᵀ; raises _NotPositiveDefinite."""
    try:
        L = np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        raise _NotPositiveDefinite from None
    if not np.all(np.isfinite(np.diagonal(L, axis1=1, axis2=2))):
        raise _NotPositiveDefinite
    return L


def _tri_inverse(L: np.ndarray) -> np.ndarray:
    """L⁻¹ (c, n, n) of lower-triangular L, by substitution vectorised over the samples."""
    Lt = np.ascontiguousarray(np.moveaxis(L, 0, -1))  # (n, n, c): contiguous per-entry sample vectors
    n = Lt.shape[0]
    X = np.zeros_like(Lt)
    inv_diag = 1.0 / np.diagonal(Lt).T  # (n, c)
    for a in range(n):
        X[a, a] = inv_diag[a]
        for b in range(a):
            acc = Lt[a, b] * X[b, b]
            for k in range(b + 1, a):
                acc += Lt[a, k] * X[k, b]
            X[a, b] = -acc * inv_diag[a]
    return np.moveaxis(X, -1, 0)


def _forward(L: np.ndarray, r: np.ndarray) -> np.ndarray:
    """L⁻¹ r for r (c, n)."""
    z = np.empty_like(r)
    for a in range(L.shape[1]):
        acc = r[:, a].copy()
        for b in range(a):
            acc -= L[:, a, b] * z[:, b]
        z[:, a] = acc / L[:, a, a]
    return z


def _metric_chunk(metric, theta: np.ndarray, rows: slice) -> np.ndarray:
    """M_i(θ) (c, n, n) for the samples in rows: Σ_terms J_iᵀ G(θ) J_i + M0_i."""
    M = None
    for t in metric.terms:
        J = t.J[rows]  # (c, d, n)
        G = t.G(theta)  # (d, d) or (N, d, d)
        if t.per_sample:
            GJ = np.matmul(G[rows], J)
        else:
            c, d, n = J.shape
            GJ = (G @ np.swapaxes(J, 0, 1).reshape(d, c * n)).reshape(d, c, n).swapaxes(0, 1)
        term = np.matmul(np.swapaxes(J, 1, 2), GJ)
        M = term if M is None else M + term
    if metric.M0 is not None:
        M = metric.M0[rows].copy() if M is None else M + metric.M0[rows]
    return M  # symmetric up to rounding; the Cholesky factorisation reads the lower triangle only


def _as_slice(indices: tuple[int, ...]):
    """A slice when the indices are consecutive (cheap in-place updates), else the index list."""
    if indices and list(indices) == list(range(indices[0], indices[0] + len(indices))):
        return slice(indices[0], indices[0] + len(indices))
    return list(indices)


def _apply_quad(metric, w: np.ndarray, rows: slice, out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(out − [M_ik w_i]_k (c, n, p), Σ_i w_iᵀ M_ik w_i (p,)) in one pass over the metric's factors.

    With out = 0 these are ``−metric.apply(w, rows)`` and ``metric.quad(w, rows).sum(0)``; u_i = J_i w_i
    and E_k u_i are shared between the two. ``out`` (c, n, p) is updated in place.
    """
    c, n = w.shape
    out = np.zeros((c, n, metric.n_params)) if out is None else out
    wMw = np.zeros(metric.n_params)
    for t in metric.terms:
        J = t.J[rows]  # (c, d, n)
        u = np.einsum("cdn,cn->cd", J, w)  # (c, d)
        d = u.shape[1]
        if t.per_sample:
            Eu = np.einsum("ckde,ce->ckd", t.E[rows], u)  # (c, k, d)
        else:
            k = t.E.shape[0]
            Eu = (u @ t.E.transpose(2, 0, 1).reshape(d, k * d)).reshape(c, k, d)  # E symmetric
        idx = _as_slice(t.indices)
        out[:, :, idx] -= np.matmul(np.swapaxes(J, 1, 2), np.swapaxes(Eu, 1, 2))  # J_iᵀ E_k u_i
        wMw[idx] += np.einsum("ckd,cd->k", Eu, u)
    return out, wMw


@dataclass(frozen=True)
class _Derivatives:
    f: float
    grad: np.ndarray | None = None  # (p,)
    hess: np.ndarray | None = None  # (p, p)


def dual_metric_derivatives(
    problem: IdentificationProblem, theta: np.ndarray, order: int = 2, chunk: int = 4096
) -> _Derivatives:
    """f (and ∇f, ∇²f for order 2) accumulated over chunks of samples (memory O(chunk·n·p)).

    Raises _NotPositiveDefinite when some M_i(θ) is not positive definite.
    """
    N, n, p = problem.N, problem.n, problem.p
    theta = np.asarray(theta, dtype=float)
    f = 0.0
    grad = np.zeros(p) if order else None
    hess = np.zeros((p, p)) if order else None
    for start in range(0, N, chunk):
        rows = slice(start, min(start + chunk, N))
        Y = problem.Y[rows]  # (c, n, p)
        c = Y.shape[0]
        r = (Y.reshape(c * n, p) @ theta).reshape(c, n) - problem.tau[rows]  # (c, n)
        L = _cholesky(_metric_chunk(problem.metric, theta, rows))  # M_i = L_i L_iᵀ
        if not order:
            z = _forward(L, r)  # L⁻¹ r
            f += float(np.sum(z * z))
            continue
        Li = _tri_inverse(L)  # (c, n, n)
        z = np.einsum("cab,cb->ca", Li, r)  # L⁻¹ r
        f += float(np.sum(z * z))
        w = np.einsum("cba,cb->ca", Li, z)  # M⁻¹ r = L⁻ᵀ L⁻¹ r
        D, wMw = _apply_quad(problem.metric, w, rows, out=Y.copy())  # D = Y_i − [M_ik w_i]_k, Σ_i w_iᵀ M_ik w_i
        grad += 2.0 * (w.reshape(-1) @ Y.reshape(-1, p)) - wMw
        Z = np.matmul(Li, D).reshape(-1, p)  # L⁻¹ (Y_i − M_ik w_i)
        hess += 2.0 * (Z.T @ Z)
    if not np.isfinite(f):
        raise _NotPositiveDefinite
    return _Derivatives(f, grad, None if hess is None else 0.5 * (hess + hess.T))


def _objective(problem, theta, chunk) -> float:
    """f(θ), +inf outside the domain."""
    try:
        return dual_metric_derivatives(problem, theta, order=0, chunk=chunk).f
    except _NotPositiveDefinite:
        return np.inf


def _force_scale(problem, theta, chunk) -> float:
    """Σ τ_iᵀ M_i(θ)⁻¹ τ_i: the size of the measured forces in the dual metric (the objective's scale)."""
    total = 0.0
    for start in range(0, problem.N, chunk):
        rows = slice(start, start + chunk)
        L = np.linalg.cholesky(problem.metric.evaluate(theta, rows))
        z = np.linalg.solve(L, problem.tau[rows][..., None])
        total += float(np.sum(z * z))
    return total


# --- starting point -----------------------------------------------------------------------------
def _ols(problem: IdentificationProblem, chunk: int) -> np.ndarray:
    """Unconstrained least squares from the sufficient statistics (min-norm where rank deficient)."""
    stats = statistics(problem, chunk=chunk)
    return _solve_psd(stats.H, stats.g, rtol=1e-10)


def _clip_psd(C: np.ndarray, eps: float = 1e-2) -> np.ndarray:
    lam, U = np.linalg.eigh(C)
    top = np.abs(lam).max()
    top = top if top > 0 else 1.0
    return (U * np.maximum(lam, eps * top)) @ U.T


def _central_point(theta_ols: np.ndarray, cons: _Constraints, eps: float = 1e-2) -> np.ndarray:
    """A strictly feasible point near θ_ols: each block's matrix with its eigenvalues lifted to ≥ eps·λ_max."""
    theta = theta_ols.copy()
    for c in cons.lmis:
        k, m, _ = c.V.shape
        target = _clip_psd(c.C(theta), eps) - c.C0
        theta[c.idx] = np.linalg.lstsq(c.V.reshape(k, m * m).T, target.reshape(-1), rcond=None)[0]
    if len(cons.h):
        for j in range(len(cons.h)):
            g = cons.G[j]
            i = int(np.flatnonzero(g)[0])
            s = g[i] * theta[i] + cons.h[j]
            scale = max(abs(theta[i]), abs(cons.h[j]), 1e-6)
            if s < 1e-2 * scale:
                theta[i] += (1e-2 * scale - s) / g[i]
    return theta


def _phase_one(problem, cons: _Constraints, theta_ref: np.ndarray, samples: np.ndarray) -> tuple[np.ndarray, float]:
    """max t s.t. C_b(θ) ⪰ t·c_b I, Gθ + h ≥ t·c, M_i(θ) ⪰ t·m_i I (i in samples), t ≤ 1.

    A small conic problem (size p plus the listed samples), solved by cvxpy only when the cheap
    start fails. Returns (θ, t); t ≤ 0 means no strictly feasible θ exists for these samples.
    """
    import cvxpy as cp

    from dualid.estimators.base import parameter_scale, solve_cvxpy

    s = parameter_scale(problem)
    phi = cp.Variable(problem.p)
    t = cp.Variable()
    theta = cp.multiply(s, phi)
    cons_list = [t <= 1, cp.norm(phi - theta_ref / s, "inf") <= 1e6]
    for c in cons.lmis:
        k, m, _ = c.V.shape
        scale = float(np.abs(c.V * s[c.idx, None, None]).sum(axis=0).max())
        C = c.C0 + cp.reshape(c.V.reshape(k, m * m).T @ theta[c.idx], (m, m), order="C")
        cons_list.append(0.5 * (C + C.T) >> t * scale * np.eye(m))
    if len(cons.h):
        scale = np.abs(cons.G * s).sum(axis=1)
        cons_list.append(cons.G @ theta + cons.h >= t * scale)
    if len(samples):
        M0, Mk = problem.metric.basis(samples)
        n = problem.n
        for i in range(len(samples)):
            scale = float(np.abs(Mk[i] * s[:, None, None]).sum(axis=0).max()) or 1.0
            Mi = M0[i] + cp.reshape(Mk[i].reshape(problem.p, n * n).T @ theta, (n, n), order="C")
            cons_list.append(0.5 * (Mi + Mi.T) >> t * scale * np.eye(n))
    cvx = cp.Problem(cp.Maximize(t), cons_list)
    solved = solve_cvxpy(cvx, phi, "CLARABEL", None, what="dual-metric phase I")
    return s * solved.value, float(t.value)


def _not_pd_samples(problem, theta, chunk, limit=50) -> np.ndarray:
    """Indices of (up to limit of the worst) samples where M_i(θ) is not positive definite."""
    bad, worst = [], []
    for start in range(0, problem.N, chunk):
        rows = slice(start, min(start + chunk, problem.N))
        lam = np.linalg.eigvalsh(problem.metric.evaluate(theta, rows))[:, 0]
        scale = np.abs(lam).max() if lam.size else 1.0
        i = np.flatnonzero(lam <= 1e-12 * scale)
        bad.append(start + i)
        worst.append(lam[i])
    bad, worst = np.concatenate(bad), np.concatenate(worst)
    return bad[np.argsort(worst)[:limit]]


def _energy_ls(problem: IdentificationProblem, chunk: int) -> np.ndarray:
    """min-norm argmin Σ (v_iᵀ r_i)²: v_iᵀr_i is the same in every chart, so is this θ."""
    stats = energy_statistics(problem, chunk=chunk)
    return _solve_psd(stats.H, stats.g, rtol=1e-10)


def _frozen_metric_ls(problem: IdentificationProblem, theta_c: np.ndarray, chunk: int) -> np.ndarray | None:
    """min-norm argmin Σ r_iᵀ M_i(θ_c)⁻¹ r_i (the metric frozen at θ_c): chart-invariant; None if some
    M_i(θ_c) is not positive definite."""
    p = problem.p
    H, g = np.zeros((p, p)), np.zeros(p)
    for start in range(0, problem.N, chunk):
        rows = slice(start, start + chunk)
        try:
            L = np.linalg.cholesky(problem.metric.evaluate(theta_c, rows))
        except np.linalg.LinAlgError:
            return None
        Z = np.linalg.solve(L, problem.Y[rows])  # L⁻¹ Y_i (n, p)
        z = np.linalg.solve(L, problem.tau[rows][..., None])[..., 0]
        H += np.einsum("nap,naq->pq", Z, Z)
        g += np.einsum("nap,na->p", Z, z)
    return _solve_psd(H, g, rtol=1e-10)


def starting_point(problem, cons: _Constraints, chunk: int) -> tuple[np.ndarray, str]:
    """A strictly feasible θ with every M_i(θ) ≻ 0, computed from chart-invariant quantities only.

    The energy least-squares θ picks a central point θ_c (each block's eigenvalues lifted); the
    frozen-metric estimate argmin Σ rᵀM(θ_c)⁻¹r is then moved toward θ_c until it is strictly
    feasible. Both estimates are the same in every chart, and Newton steps are affine-invariant in θ,
    so the whole iteration (and hence the chosen point of a non-unique optimal face) does not
    depend on the coordinates, units or scaling of the data. Falls back to the OLS seed (and to a
    phase-I problem) only when that fails.
    """
    for seed_name, seed in (("energy", _energy_ls), ("ols", _ols)):
        theta_seed = seed(problem, chunk)
        theta_c = _central_point(theta_seed, cons)
        if cons.margin(theta_c) <= 0 or not np.isfinite(_objective(problem, theta_c, chunk)):
            continue
        theta_f = _frozen_metric_ls(problem, theta_c, chunk) if seed_name == "energy" else theta_seed
        target, label = (theta_f, f"{seed_name}→frozen-metric→central") if theta_f is not None else (theta_seed, f"{seed_name}→central")
        # θ(β) = θ_c + β (target − θ_c), β ≤ 0.9 of the way to the constraint boundary, every M_i ≻ 0
        d = target - theta_c
        beta = min(1.0, 0.9 * cons.max_step(theta_c, d))
        line = theta_c
        while beta > 1e-3:
            if np.isfinite(_objective(problem, theta_c + beta * d, chunk)):
                line = theta_c + beta * d
                break
            beta *= 0.5
        # or the target with its blocks' eigenvalues lifted (it keeps the target's well-determined directions,
        # where the segment toward θ_c can stop far from it): whichever has the smaller f
        lifted = _central_point(target, cons)
        f_line = _objective(problem, line, chunk)
        f_lifted = _objective(problem, lifted, chunk) if cons.margin(lifted) > 0 else np.inf
        return (lifted, f"{label}→lifted") if f_lifted < f_line else (line, label)
    theta_c = _central_point(_ols(problem, chunk), cons)
    # phase I: a small conic problem over the constraints and the samples where M_i(θ_c) is not ≻ 0
    samples = np.zeros(0, dtype=int)
    if cons.margin(theta_c) > 0:
        samples = _not_pd_samples(problem, theta_c, chunk)
    for _ in range(20):
        try:
            theta_c, t = _phase_one(problem, cons, theta_c, samples)
        except SolverError as exc:
            raise SolverError(
                f"dual-metric Newton: phase I failed ({exc}); the constraints may admit no strictly feasible θ",
                status=exc.status,
            ) from exc
        if t <= 1e-9:
            if len(samples):
                raise MetricError(
                    f"dual-metric Newton: no θ satisfying the constraints makes M_i(θ) positive definite at "
                    f"samples {samples[:10].tolist()} (phase-I margin {t:.3g} ≤ 0); check the metric's "
                    "constant part and the parameter bounds"
                )
            raise SolverError(
                "dual-metric Newton: the constraints (physical consistency and bounds) admit no strictly "
                f"feasible θ (phase-I margin {t:.3g} ≤ 0)",
                status="infeasible",
            )
        more = _not_pd_samples(problem, theta_c, chunk)
        if not len(more):
            return theta_c, "phase-I"
        samples = np.union1d(samples, more)
    raise MetricError("dual-metric Newton: phase I did not find θ with every M_i(θ) positive definite")


# --- the interior-point method ------------------------------------------------------------------
def _solve_psd(K: np.ndarray, b: np.ndarray, rtol: float = 1e-13) -> np.ndarray:
    """K⁺ b for K ⪰ 0 (Jacobi-scaled; directions with eigenvalue < rtol·max are left out)."""
    d = _jacobi(K)
    lam, U = np.linalg.eigh(K / np.outer(d, d))
    keep = lam > rtol * max(lam.max(), 1e-300)
    x = U[:, keep] @ ((U[:, keep].T @ (b / d)) / lam[keep])
    return x / d


def _jacobi(K: np.ndarray) -> np.ndarray:
    """√diag(K), with (numerically) empty columns given the largest scale so they drop out."""
    d = np.sqrt(np.abs(np.diag(K)))
    top = d.max() if d.size and d.max() > 0 else 1.0
    d[d <= 1e-7 * top] = top
    return d


class _NewtonSystem:
    """Solves K x = b for the PSD Newton matrix K: Jacobi-scaled Cholesky of K + δ·diag(K), δ = 1e-12 (a
    Levenberg term that leaves non-identifiable directions with a zero step instead of failing); eigen
    pseudo-inverse if even that is not positive definite numerically."""

    def __init__(self, K: np.ndarray, levenberg: float = 1e-12):
        self.d = _jacobi(K)
        Ks = K / np.outer(self.d, self.d)
        Ks[np.diag_indices_from(Ks)] += levenberg
        try:
            self.L = np.linalg.cholesky(Ks)
            self.U = None
        except np.linalg.LinAlgError:
            lam, U = np.linalg.eigh(Ks)
            keep = lam > 1e-13 * max(lam.max(), 1e-300)
            self.L, self.U, self.lam = None, U[:, keep], lam[keep]

    def solve(self, b: np.ndarray) -> np.ndarray:
        from scipy.linalg import solve_triangular

        bs = b / self.d
        if self.L is not None:
            x = solve_triangular(self.L.T, solve_triangular(self.L, bs, lower=True), lower=False)
        else:
            x = self.U @ ((self.U.T @ bs) / self.lam)
        return x / self.d


def _dual_direction(cons: _Constraints, Z, z, Cinv, s, d, target):
    """HKM direction: ΔZ = σμ C⁻¹ − Z − sym(Z ΔC C⁻¹); Δz = σμ/s − z − (z/s) G d."""
    dZ = []
    for c, Zb, Ci in zip(cons.lmis, Z, Cinv):
        X = Zb @ c.dC(d) @ Ci
        dZ.append(target * Ci - Zb - 0.5 * (X + X.T))
    dz = target / s - z - (z / s) * (cons.G @ d) if len(s) else np.zeros(0)
    return dZ, dz


def _dual_max_step(Z, z, dZ, dz) -> float:
    alpha = np.inf
    for Zb, dZb in zip(Z, dZ):
        alpha = min(alpha, _max_step_psd(Zb, dZb))
    neg = dz < 0
    if neg.any():
        alpha = min(alpha, float(np.min(-z[neg] / dz[neg])))
    return alpha


def _gap(cons: _Constraints, theta, Z, z) -> float:
    gap = sum(float(np.sum(c.C(theta) * Zb)) for c, Zb in zip(cons.lmis, Z))
    if len(z):
        gap += float((cons.G @ theta + cons.h) @ z)
    return gap


def _barrier(cons: _Constraints, theta) -> float:
    """−Σ log det C_b(θ) − Σ log s_j(θ); +inf outside the interior."""
    val = 0.0
    for c in cons.lmis:
        sign, logdet = np.linalg.slogdet(c.C(theta))
        if sign <= 0:
            return np.inf
        val -= logdet
    if len(cons.h):
        s = cons.G @ theta + cons.h
        if np.any(s <= 0):
            return np.inf
        val -= float(np.sum(np.log(s)))
    return val


def fit_dual_metric_newton(
    problem: IdentificationProblem,
    *,
    constrained: bool = True,
    tol: float = 1e-9,
    max_iter: int = 100,
    chunk: int = 4096,
    warm_start_samples: int = 50_000,
    method: str = "dual_metric",
    verbose: bool = False,
) -> IdentificationResult:
    """Dual-metric least squares by a primal–dual interior-point Newton method (see module doc).

    tol: relative tolerance on f for (duality gap + squared Newton decrement of the Lagrangian);
    chunk: samples per pass (memory O(chunk·n·p)); raises SolverError after max_iter iterations.
    warm_start_samples: when N > 4× this, first solve on an evenly strided subsample of about this
    size (to a loose tolerance, 1e-4) and start the full problem from its θ, with the dual variables
    re-centred there at a small gap; 0 disables it.
    """
    t0 = time.perf_counter()
    p = problem.p
    cons = build_constraints(problem.parameters, constrained)
    if constrained:
        lo = np.asarray(problem.parameters.lower if problem.parameters.lower is not None else [-np.inf] * p)
        hi = np.asarray(problem.parameters.upper if problem.parameters.upper is not None else [np.inf] * p)
        bad = np.flatnonzero(lo >= hi)
        if len(bad):
            k = int(bad[0])
            raise SolverError(
                f"dual-metric Newton: the bounds admit no strictly feasible θ: {problem.parameters.names[k]} has "
                f"lower bound {lo[k]:g} ≥ upper bound {hi[k]:g}",
                status="infeasible",
            )
    warm, failed_warm = None, ""
    if warm_start_samples and problem.N > 4 * warm_start_samples:
        sub = problem.subset(slice(0, None, problem.N // warm_start_samples))
        theta, start = starting_point(sub, cons, chunk)
        try:
            th, _, _, info_sub = _interior_point(sub, cons, theta, None, None, 1e-4, max_iter, chunk, verbose)
            der = dual_metric_derivatives(problem, th, 2, chunk)  # M_i(θ) ≻ 0 on every sample?
            warm = (th, der)
            start = f"warm start from {sub.N} samples ({info_sub['iterations']} iterations)"
        except SolverError as exc:  # recorded in info["start"]; the cold start below decides
            warm, failed_warm = None, f"warm start from {sub.N} samples failed ({exc.status}); "
        except _NotPositiveDefinite:
            warm, failed_warm = None, f"warm start from {sub.N} samples left some M_i(θ) indefinite; "
    if warm is not None:
        # primal warm start; duals re-centred at θ with a small gap (1e-3 f): the subsample's duals sit too
        # close to its own boundary for the full problem and would jam the iterations
        try:
            theta, Z, z, info = _interior_point(problem, cons, warm[0], None, None, tol, max_iter, chunk, verbose,
                                                der=warm[1], gap0=1e-3)
        except SolverError as exc:  # the subsample's optimum can sit near a boundary the full data move away from
            warm = None
            failed_warm = f"{start} failed ({exc.status}); "
    if warm is None:
        theta, start = starting_point(problem, cons, chunk)
        theta, Z, z, info = _interior_point(problem, cons, theta, None, None, tol, max_iter, chunk, verbose)
        start = failed_warm + start
    f = info.pop("objective")
    info["start"] = start
    return IdentificationResult(
        method, theta, problem.parameters, f, "optimal", "newton", time.perf_counter() - t0, info["iterations"],
        constrained, info,
    )


def _interior_point(problem, cons: _Constraints, theta, Z, z, tol, max_iter, chunk, verbose, der=None, gap0=1.0,
                    objective=None, f_scale=None):
    """Primal–dual iterations from a strictly feasible θ (and dual Z, z, or None: centred at θ, gap0·f).

    Returns (θ, Z, z, info) at relative gap ≤ tol; raises SolverError otherwise. objective(θ, order) → _Derivatives
    (raising _NotPositiveDefinite outside its domain) replaces the dual-metric f, with f_scale its size
    (then problem is unused): the same method for any smooth convex f under these constraints.
    """
    p = len(theta)
    if objective is None:
        def objective(th, order):
            return dual_metric_derivatives(problem, th, order, chunk)
    nu = cons.size  # barrier parameter: μ = gap / ν on the central path
    der = objective(theta, 2) if der is None else der
    f_start = der.f
    if f_scale is None:
        f_scale = _force_scale(problem, theta, chunk)
    f_scale = max(f_start, f_scale)  # exact data drive f → 0
    if Z is None:
        mu = gap0 * max(der.f, 1e-300) / max(nu, 1)  # dual start on the central path: Z_b = μ C_b⁻¹, z = μ / s
        Z = [mu * np.linalg.inv(c.C(theta)) for c in cons.lmis]
        z = mu / (cons.G @ theta + cons.h) if len(cons.h) else np.zeros(0)
    history, n_evals = [], 0
    for it in range(max_iter + 1):
        if der is None:
            der = objective(theta, 2)
        f, grad, K = der.f, der.grad, der.hess.copy()
        Cinv = [np.linalg.inv(c.C(theta)) for c in cons.lmis]
        s = cons.G @ theta + cons.h
        r_dual = grad.copy()  # ∇f − A*(Z), the Lagrangian's gradient
        barrier_grad = np.zeros(p)  # A*(C⁻¹) = −∇(barrier)
        for c, Zb, Ci in zip(cons.lmis, Z, Cinv):
            r_dual[c.idx] -= np.einsum("kab,ba->k", c.V, Zb)
            barrier_grad[c.idx] += np.einsum("kab,ba->k", c.V, Ci)
            K[np.ix_(c.idx, c.idx)] += np.einsum("kab,bc,lcd,da->kl", c.V, Zb, c.V, Ci)
        if len(s):
            r_dual -= cons.G.T @ z
            barrier_grad += cons.G.T @ (1.0 / s)
            K += cons.G.T @ ((z / s)[:, None] * cons.G)
        system = _NewtonSystem(0.5 * (K + K.T))
        gap = _gap(cons, theta, Z, z)
        kkt = float(max(r_dual @ system.solve(r_dual), 0.0))  # squared Newton decrement of the Lagrangian
        f_ref = max(f, 1e-12 * f_scale, 1e-300)
        history.append(f)
        if verbose:
            print(f"newton {it:3d}: f {f:.15g} gap {gap:.3g} kkt {kkt:.3g}")
        if gap + kkt <= tol * f_ref:
            info = {"objective": f, "iterations": it, "duality_gap": gap, "kkt_residual": float(np.sqrt(kkt)),
                    "relative_gap": (gap + kkt) / f_ref, "objective_start": f_start,
                    "objective_evaluations": n_evals, "f_history": history}
            return theta, Z, z, info
        if it == max_iter:
            break
        # centring: Mehrotra's heuristic σ = (μ_aff / μ)³ from the affine-scaling (σ = 0) predictor
        mu = gap / nu if nu else 0.0
        sigma = 0.0
        if nu:
            d_aff = system.solve(-grad)
            a_p = min(1.0, cons.max_step(theta, d_aff))
            dZa, dza = _dual_direction(cons, Z, z, Cinv, s, d_aff, 0.0)
            a_d = min(1.0, _dual_max_step(Z, z, dZa, dza))
            mu_aff = _gap(cons, theta + a_p * d_aff, [Zb + a_d * dZb for Zb, dZb in zip(Z, dZa)], z + a_d * dza) / nu
            sigma = float(np.clip((max(mu_aff, 0.0) / mu) ** 3, 0.05, 0.5))
        target = sigma * mu
        rhs = -grad + target * barrier_grad  # −∇ of the merit φ = f + target · barrier
        d = system.solve(rhs)
        slope = -float(rhs @ d)
        alpha = min(1.0, 0.99 * cons.max_step(theta, d)) if nu else 1.0
        phi0 = f + target * _barrier(cons, theta)
        der_trial, first = None, True
        while True:  # backtracking: every C_b ≻ 0, every Cholesky of M_i succeeds, Armijo on φ
            n_evals += 1
            trial = theta + alpha * d
            if first:
                # the first trial is usually accepted: evaluate all derivatives there, for the next iteration
                try:
                    der_trial = objective(trial, 2)
                    phi1 = der_trial.f
                except _NotPositiveDefinite:
                    der_trial, phi1 = None, np.inf
            else:
                der_trial = None
                try:
                    phi1 = objective(trial, 0).f
                except _NotPositiveDefinite:
                    phi1 = np.inf
            first = False
            if np.isfinite(phi1):
                phi1 += target * _barrier(cons, trial)
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
        dZ, dz = _dual_direction(cons, Z, z, Cinv, s, d, target)
        alpha_dual = min(1.0, 0.99 * _dual_max_step(Z, z, dZ, dz))
        # separate primal and dual step lengths: with one common length the primal step (blocked by a nearly
        # active block) and the dual step (blocked by a Z_b near its boundary) throttle each other in turn and
        # the iteration crawls at α ≈ 0.05–0.15 (106 iterations on the DFKI pendubot, 37–42 on arm7)
        theta, der = trial, der_trial
        Z = [_repair_psd(Zb + alpha_dual * dZb) for Zb, dZb in zip(Z, dZ)]  # PD up to rounding
        z = z + alpha_dual * dz
        if verbose:
            print(f"            sigma {sigma:.3g} alpha {alpha:.3g} alpha_dual {alpha_dual:.3g}")
    raise SolverError(
        f"dual-metric Newton: no convergence in {max_iter} iterations; relative gap reached "
        f"{(gap + kkt) / f_ref:.3g} (duality gap {gap:.3g}, KKT residual {np.sqrt(kkt):.3g}, tol {tol:g})",
        status="max_iterations",
    )
