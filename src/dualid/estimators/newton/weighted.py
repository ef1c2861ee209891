"""The interior-point method on a *constant* metric, from sufficient statistics: argmin Σ r_iᵀ C_i⁻¹ r_i.

With M_i(θ) = C_i independent of θ the dual-metric objective is the quadratic

    f(θ) = θᵀHθ − 2gᵀθ + c,   H = Σ Y_iᵀ C_i⁻¹ Y_i,  g = Σ Y_iᵀ C_i⁻¹ τ_i,  c = Σ τ_iᵀ C_i⁻¹ τ_i,

so one pass over the samples (whitened rows L_i⁻¹ Y_i, C_i = L_i L_iᵀ) reduces the fit to a p-sized problem, solved
with the iterations, chart-invariant start and stopping rule of ``fit_dual_metric_newton`` on M_i = C_i: the same θ
up to rounding, for two passes over the data instead of two per iteration. C_i is a function of a block of rows (no
(N, n, n) array); a constant weight (one (1, n, n) block) is factored once per fit (result.info["weight"]).
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable

import numpy as np

from dualid.errors import MetricError
from dualid.estimators.newton.fit import check_bounds
from dualid.estimators.newton.interior_point import direction_label, direction_names, run_interior_point
from dualid.estimators.newton.objective import CHUNK, Derivatives
from dualid.estimators.newton.start import constant_metric_start, toward, toward_start
from dualid.estimators.result import IdentificationResult
from dualid.linalg import forward_substitute, solve_psd, tri_inverse
from dualid.model.closure import on_closure
from dualid.model.consistency import central_point, feasible_set
from dualid.problem import IdentificationProblem, additive, sample_blocks

# (block, rows) → C_i (c, n, n) symmetric positive definite, for the samples ``rows`` of the in-memory ``block``
# (see dualid.problem.sample_blocks; for an in-memory problem the block is the problem itself)
Weight = Callable[[IdentificationProblem, slice], np.ndarray]


def _weight(weight: Weight, block: IdentificationProblem, rows: slice) -> np.ndarray:
    return np.broadcast_to(weight(block, rows), (len(range(block.N)[rows]), block.n, block.n))


def not_positive_definite(problem, what: str, bad: int, low: float) -> MetricError:
    """The error for a weight's covariance that is not ≻ 0 at ``bad`` of the problem's samples."""
    return MetricError(
        f"{what} must be positive definite at every sample, but it is not at {bad} of {problem.N} samples "
        f"(smallest eigenvalue {low:.3g}); give a positive-definite Σ or a pilot with a positive-definite metric"
    )


class _Whitening:
    """(block, rows) → the block's whitened rows (L_i⁻¹ Y_i, L_i⁻¹ τ_i), C_i = L_i L_iᵀ, for one fit: a constant weight
    (one (1, n, n) block) factored once, else a Cholesky per sample. ``kind``: "constant", "per-sample", "mixed" (both,
    by block) or "factor" (the caller's W_i)."""

    def __init__(self, problem: IdentificationProblem, weight: Weight, what: str, whiten=None):
        self.problem, self.weight, self.what, self.whiten = problem, weight, what, whiten
        self.C = self.Li = None  # the constant weight (n, n) and its L⁻¹, once factored
        self.kinds: set[str] = set()

    def on(self, problem) -> "_Whitening":
        """This whitening for the samples of ``problem``: itself, or (for a partition of a spread problem, where this
        whitening arrived without its problem) a copy bound to the partition, keeping the factored weight."""
        if self.problem is problem:
            return self
        other = copy.copy(self)
        other.problem, other.kinds = problem, set()
        return other

    def __getstate__(self) -> dict:  # sent to the workers of a spread problem: the weight, not the problem
        return {**self.__dict__, "problem": None}

    @property
    def kind(self) -> str:
        return "mixed" if len(self.kinds) > 1 else next(iter(self.kinds), "none")

    def _factored(self, block: IdentificationProblem, rows: slice) -> tuple[str, np.ndarray]:
        """(kind, F) for the block's rows, recorded in ``kinds``: the caller's W_i (c, n, n), C_i⁻¹ = W_iᵀ W_i
        ("factor": no Cholesky), the constant weight's L⁻¹ (n, n) ("constant") or the per-sample L_i (c, n, n)."""
        if self.whiten is not None:
            kind, F = "factor", self.whiten(block, rows)
        else:
            C = np.asarray(self.weight(block, rows))
            if C.ndim == 3 and C.shape[0] == 1:
                kind, F = "constant", self._constant(C[0])
            else:
                kind, F = "per-sample", _factor(self.problem, block, self.weight, rows, self.what, C)
        self.kinds.add(kind)
        return kind, F

    def __call__(self, block: IdentificationProblem, rows: slice) -> tuple[np.ndarray, np.ndarray]:
        kind, F = self._factored(block, rows)
        if kind == "constant":
            return np.matmul(F, block.Y[rows]), block.tau[rows] @ F.T
        W = F if kind == "factor" else tri_inverse(F)  # L_i⁻¹ per sample
        return np.matmul(W, block.Y[rows]), np.einsum("cab,cb->ca", W, block.tau[rows])

    def residual(self, block: IdentificationProblem, rows: slice, theta: np.ndarray) -> np.ndarray:
        """The whitened residuals L_i⁻¹ r_i (c, n) at θ: r_i first, then one n-vector per sample to whiten (not Y)."""
        Y = block.Y[rows]
        r = (Y.reshape(-1, Y.shape[-1]) @ theta).reshape(Y.shape[:2]) - block.tau[rows]  # (c, n)
        kind, F = self._factored(block, rows)
        if kind == "constant":
            return r @ F.T
        return np.einsum("cab,cb->ca", F, r) if kind == "factor" else forward_substitute(F, r)

    def _constant(self, C: np.ndarray) -> np.ndarray:
        if self.Li is None or not np.array_equal(C, self.C):
            try:
                L = np.linalg.cholesky(C)
            except np.linalg.LinAlgError:
                L = None
            if L is None or not np.all(np.isfinite(L)):  # the same C at every sample: all of them fail
                raise not_positive_definite(self.problem, self.what, self.problem.N, float(np.linalg.eigvalsh(C)[0]))
            self.C, self.Li = C.copy(), tri_inverse(L[None])[0]
        return self.Li


def _factor(problem, block: IdentificationProblem, weight: Weight, rows: slice, what: str, C: np.ndarray) -> np.ndarray:
    """L (c, n, n), C_i = L_i L_iᵀ, a Cholesky per sample of C = weight(block, rows); MetricError (counting the
    samples of the whole problem) if some C_i is not ≻ 0."""
    c = len(range(block.N)[rows])
    try:
        L = np.linalg.cholesky(np.broadcast_to(C, (c, block.n, block.n)))
    except np.linalg.LinAlgError:
        L = None
    if L is None or not np.all(np.isfinite(L)):
        bad, low = 0, np.inf
        for b, r, _ in sample_blocks(problem, CHUNK):  # the whole count, for the message
            lam = np.linalg.eigvalsh(_weight(weight, b, r))[:, 0]
            bad, low = bad + int(np.sum(~(lam > 0))), min(low, float(lam.min()))
        raise not_positive_definite(problem, what, bad, low)
    return L


def _whitening(problem, weight, what: str, whiten=None) -> _Whitening:
    return weight if isinstance(weight, _Whitening) else _Whitening(problem, weight, what, whiten)


def weighted_statistics(problem: IdentificationProblem, weight: Weight, chunk: int = CHUNK,
                        what: str = "the weight's covariance", energy: bool = False, whiten=None):
    """(H, g, c) = Σ Y_iᵀC_i⁻¹Y_i, Σ Y_iᵀC_i⁻¹τ_i, Σ τ_iᵀC_i⁻¹τ_i accumulated over chunks of samples; with
    energy=True also (H_e, g_e) of the energy residual v_iᵀ r_i, from the same pass. weight: a Weight, or the
    fit's ``_Whitening`` (which keeps a constant weight's factor between passes)."""
    white = _whitening(problem, weight, what, whiten)
    H, g, c, He, ge, kinds = _weighted_sums(problem, white, chunk, energy)
    white.kinds |= kinds
    if energy:
        return 0.5 * (H + H.T), g, c, He, ge
    return 0.5 * (H + H.T), g, c


@additive
def _weighted_sums(problem, white: "_Whitening", chunk: int, energy: bool):
    """(H, g, c, H_e, g_e, the weight kinds seen) summed over the samples, as ``weighted_statistics``."""
    white = white.on(problem)
    p = problem.p
    H, g, c = np.zeros((p, p)), np.zeros(p), 0.0
    He, ge = np.zeros((p, p)), np.zeros(p)
    for block, rows, _ in sample_blocks(problem, chunk):
        if energy:
            e = np.einsum("nap,na->np", block.Y[rows], block.v[rows])
            He += e.T @ e
            ge += e.T @ np.einsum("na,na->n", block.tau[rows], block.v[rows])
        Z, z = white(block, rows)
        Z2, z1 = Z.reshape(-1, p), z.reshape(-1)
        H += Z2.T @ Z2
        g += Z2.T @ z1
        c += float(z1 @ z1)
    return H, g, c, He, ge, white.kinds


def weighted_objective(problem: IdentificationProblem, weight: Weight, theta: np.ndarray, chunk: int = CHUNK) -> float:
    """Σ r_iᵀ C_i⁻¹ r_i from the residuals (no cancellation, unlike θᵀHθ − 2gᵀθ + c); weight as in
    ``weighted_statistics``."""
    white = _whitening(problem, weight, "the weight")
    f, kinds = _weighted_residual_sum(problem, white, theta, chunk)
    white.kinds |= kinds
    return f


@additive
def _weighted_residual_sum(problem, white: "_Whitening", theta: np.ndarray, chunk: int) -> tuple[float, set]:
    white = white.on(problem)
    f = 0.0
    for block, rows, _ in sample_blocks(problem, chunk):
        e = white.residual(block, rows, theta)
        f += float(np.sum(e * e))
    return f, white.kinds


def fit_weighted_newton(
    problem: IdentificationProblem,
    weight: Weight,
    *,
    constrained: bool = True,
    tol: float = 1e-9,
    max_iter: int = 100,
    chunk: int = CHUNK,
    method: str = "dual_metric",
    verbose: bool = False,
    warm_start_samples: int | None = None,  # accepted for option compatibility; unused (no pass per iteration)
    what: str = "the weight's covariance",
    whiten=None,
    objective_pass: bool = True,
    null_step: bool = True,  # False: no move along the null space (a pilot whose θ feeds only its residuals)
) -> IdentificationResult:
    """argmin Σ r_iᵀ C_i⁻¹ r_i under the constraints (module doc); when the cheap start fails, from the weighted
    LS's central point or a phase I on the same (closed) feasible set (``newton.start.constant_metric_start``).
    whiten: (block, rows) → W_i (c, n, n) with C_i⁻¹ = W_iᵀ W_i, when the caller has that factor (no Cholesky);
    objective_pass=False skips the pass for the result's objective (NaN: the caller computes it, e.g. the bounded
    fixed point in its own pass)."""
    t0 = time.perf_counter()
    check_bounds(problem, constrained)
    white = _Whitening(problem, weight, what, whiten)
    H, g, c, H_e, g_e = weighted_statistics(problem, white, chunk, energy=True)
    # parameters f cannot see that only loosen a block: solved on the closed set, then completed (model.closure)
    cons, done = on_closure(feasible_set(problem.parameters, constrained), H, c, problem.parameters.names)
    theta_f = solve_psd(H, g, rtol=1e-10)  # the unconstrained weighted LS (min-norm): the frozen-metric LS
    f_min = max(c - 2.0 * float(g @ theta_f) + float(theta_f @ H @ theta_f), 0.0)

    def f_of(th):
        e = th - theta_f
        return float(e @ H @ e) + f_min

    def objective(th, order):
        if not order:
            return Derivatives(f_of(th))
        return Derivatives(f_of(th), 2.0 * (H @ th - g), 2.0 * H)

    start = None
    theta_c = central_point(solve_psd(H_e, g_e, rtol=1e-10), cons)
    if cons.margin(theta_c) > 0:  # as newton.start.starting_point with the energy seed; every θ is in the domain
        theta0, start = toward(cons, theta_c, theta_f, "energy→frozen-metric→central", f_of)
    if start is None:  # the same closed problem from the weighted LS's central point or phase I (not a fit without
        # the closure: model.closure)
        theta0, start = constant_metric_start(problem, cons, theta_f)
    theta, _, _, info = run_interior_point(problem, cons, theta0, None, None, tol, max_iter, chunk, verbose,
                                        objective=objective, f_scale=c)
    theta = toward_start(theta, theta0, H, cons, f_of) if null_step else theta
    info.pop("objective")
    info.update(start=start, statistics="one pass (H = Σ YᵀC⁻¹Y)", weight=white.kind)
    names = problem.parameters.names  # the iterates' direction by parameter name (no arrays in info), as newton.fit
    if "diverging_candidate" in info:
        info["diverging_candidate"] = direction_names(info["diverging_candidate"], names)
    if "diverging_direction" in info:
        info["diverging_direction"] = direction_label(info["diverging_direction"], names)
    theta, info = done(theta, info)
    f = weighted_objective(problem, white, theta, chunk) if objective_pass else float("nan")
    return IdentificationResult(method, theta, problem.parameters, f, "optimal", "newton", time.perf_counter() - t0,
                                info["iterations"], constrained, info)

