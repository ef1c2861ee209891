"""Uncertainty of the base parameters β = C θ (dualid.identifiability) at an estimator's optimum.

Every estimator minimises f(θ) = Σ_i f_i(θ) (+ γ R(θ) for logdet/pullback). At θ̂ the sandwich

    cov(β̂) ≈ H⁻¹ B H⁻¹ · K/(K − r),     B = Σ_b (g_b − ḡ)(g_b − ḡ)ᵀ,   g_b = Σ_{i ∈ block b} ∇f_i(θ̂)

with H the objective's Hessian and ḡ the mean block gradient (zero at an interior unregularised optimum;
−γ∇R/K with a prior, the multipliers' share with active constraints), is taken in the coordinates
x = (β, u): θ = θ̂ + E β + Z u with E a right inverse of C and Z a basis of C's null space (both in
column-scaled units). Directions of u without curvature (eigenvalues of H_uu below FLAT_RTOL × H's
largest: the data terms do not see u) drop out; a regulariser curves u, and then H⁻¹'s β-block is the
inverse of the Schur complement (the prior's profile). Blocks (contiguous segments or runs) let the
residuals be correlated within a block; one sample per block is the heteroscedasticity-robust form.
The Hessian and per-sample gradients are:

- quadratic (ols, wls, energy, logdet/pullback data term): f_i = r_iᵀW_i r_i,
  ∇f_i = 2 Y_iᵀW_i r_i, H = 2 Σ Y_iᵀW_i Y_i, with the weight the estimator used (recorded in its result);
- dm-paper: f_i = r_iᵀM_i(θ)⁻¹r_i, ∇f_i = 2 Y_iᵀw_i − [w_iᵀM_ik w_i]_k (w_i = M_i⁻¹r_i), H the exact
  Hessian 2 Σ D_iᵀM_i⁻¹D_i, D_i = Y_i − [M_ik w_i]_k (estimators.newton.objective);
- dm: f_i = r_iᵀC_i(θ)⁻¹r_i with its estimated noise model C_i = Σ_τ + M_iΣ_aM_i (held fixed),
  ∇f_i = 2 Y_iᵀw_i − 2 [u_iᵀM_ik w_i]_k (w_i = C_i⁻¹r_i, u_i = Σ_aM_iw_i), H the Hessian of
  estimators.noise_model (with Σ_a = 0 that is WLS's); where its check returned WLS, WLS's quadratic form;
- logdet: + γ tr(C⁻¹V_k C⁻¹V_l) per block; pullback: + 2γ g_b; the data term's per-sample gradients are
  taken at its own (unregularised) minimiser, where the residuals are the noise: at θ̂ they would also
  carry the prior's systematic pull, which is not sampling variation for a fixed design.

Active constraints: a block whose constraint matrix C_b(θ̂) has eigenvalues ≤ ACTIVE_TOL·λ_max (for
scalar blocks, nonnegative and diagonal drag, λ_max is at least ‖τ‖/‖A_k‖, the value that alone would explain
all of τ), and a parameter at a bound within ACTIVE_TOL relative, is active; they are always detected and
recorded (``active``). constraints="ignore" (default): the intervals are those of the unconstrained local
fit at θ̂ (when the truth is inside the feasible set and a constraint is active only because of noise, the
projection of the estimate onto the set does not make its error larger in the Hessian's norm, so these are
the ones that keep their coverage; benchmarks/coverage.py). constraints="project": the equations
v_aᵀ C_b(θ) v_c = 0 of the near-null eigenvectors define the active set's tangent, and the sandwich is
restricted to it: intervals conditional on those constraints being active in truth (a parameter known to
sit on its bound), which under-cover when the activity is due to noise.

``kind="model"`` (quadratic methods only) is the textbook 2σ̂²H⁻¹, σ̂² = f(θ̂)/(N·n − r), valid when W is
the inverse noise covariance up to a scale and the samples are independent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.special

from dualid.errors import ConfigError, DualidError, SolverError
from dualid.estimators.least_squares import OLS, WLS, EnergyLS, RegularizedWLS
from dualid.estimators.result import IdentificationResult
from dualid.evaluation.objective_terms import derivatives, unwrap
from dualid.identifiability import BaseParameters
from dualid.linalg import pinv_psd
from dualid.problem import IdentificationProblem

LEVEL = 0.95
ACTIVE_TOL = 1e-6  # constraint eigenvalue / block scale at or below which a constraint counts as active
FLAT_RTOL = 1e-11  # eigenvalue of H along the null space, relative to H's largest, below which it is roundoff
KINDS = ("sandwich", "model", "bootstrap")


@dataclass(frozen=True, eq=False)
class BaseUncertainty:
    """β̂, its covariance and (level) intervals per base parameter, and how they were obtained."""

    method: str
    base: BaseParameters
    values: np.ndarray  # (r,) β̂ = C θ̂
    covariance: np.ndarray  # (r, r)
    lower: np.ndarray  # (r,)
    upper: np.ndarray  # (r,)
    kind: str  # "sandwich", "model" or "bootstrap"
    blocks: int  # gradient blocks (sandwich), resampled blocks (bootstrap) or samples (model)
    level: float = LEVEL
    active: tuple[str, ...] = ()  # constraints active at θ̂ (detected whether or not the intervals use them)
    conditional: bool = False  # True: projected on the active constraints' tangent (constraints="project")
    resamples: int = 0  # bootstrap only
    failures: int = 0  # bootstrap refits that failed (not dropped silently: counted here)
    note: str = ""

    def __post_init__(self) -> None:
        for name in ("values", "covariance", "lower", "upper"):
            a = np.array(getattr(self, name), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @property
    def std_error(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def records(self) -> list[dict]:
        """One dict per base parameter: name, unit, expression, value, std_error, lower, upper."""
        return [
            {"name": b.name, "unit": b.unit, "expression": b.expression(), "value": float(v), "std_error": float(se),
             "lower": float(lo), "upper": float(hi)}
            for b, v, se, lo, hi in zip(self.base.items, self.values, self.std_error, self.lower, self.upper)
        ]

    def summary(self) -> str:
        """One sentence: kind, blocks, level, active constraints, bootstrap failures."""
        what = {"sandwich": f"sandwich H⁻¹BH⁻¹ over {self.blocks} blocks",
                "model": "textbook 2σ̂²H⁻¹ (independent samples, W the inverse noise covariance)",
                "bootstrap": f"block bootstrap, {self.resamples} resamples of {self.blocks} blocks, "
                             f"{self.failures} failed refits"}[self.kind]
        text = f"{int(round(100 * self.level))} % intervals, {what}"
        if self.active and self.conditional:
            text += f"; conditional on {len(self.active)} active constraints ({', '.join(self.active)})"
        elif self.active:
            text += (f"; {len(self.active)} constraints active at the estimate ({', '.join(self.active)}), not "
                     "used: intervals of the unconstrained local fit")
        return text + (f"; {self.note}" if self.note else "")


# --- blocks -----------------------------------------------------------------------------------
def block_labels(N: int, blocks) -> np.ndarray:
    """(N,) block index per sample: None → one per sample; an int K → K contiguous segments of (nearly)
    equal length; a sequence of index arrays → those groups (every sample in exactly one)."""
    if blocks is None:
        return np.arange(N)
    if isinstance(blocks, (int, np.integer)) and not isinstance(blocks, bool):
        if not 1 <= blocks <= N:
            raise ConfigError(f"blocks: expected an integer in 1..{N} (the number of samples), got {blocks}")
        return (np.arange(N) * int(blocks)) // N
    labels = np.full(N, -1)
    for b, idx in enumerate(blocks):
        labels[np.asarray(idx, dtype=int)] = b
    if np.any(labels < 0):
        raise ConfigError(f"blocks: {int(np.sum(labels < 0))} of {N} samples are in no block")
    return labels


def run_segments(lengths, per_run: int) -> list[np.ndarray]:
    """Contiguous blocks: each run (its length in samples, in order) split into ``per_run`` segments."""
    out, start = [], 0
    for n_run in lengths:
        k = max(1, min(int(per_run), int(n_run)))
        out += [start + seg for seg in np.array_split(np.arange(int(n_run)), k)]
        start += int(n_run)
    return out


# --- active constraints -------------------------------------------------------------------------
def active_constraints(problem: IdentificationProblem, theta: np.ndarray, tol: float = ACTIVE_TOL):
    """(A (k, p), names): gradients of the active constraints' equations at θ (module docstring)."""
    rows, names = [], []
    P = problem.parameters
    col = np.linalg.norm(problem.Y.reshape(-1, P.p), axis=0)
    signal = np.linalg.norm(problem.tau) / np.where(col > 0, col, np.inf)  # θ_k that alone explains all of τ
    for b in P.blocks:
        V = b.constraint_basis
        if V is None:
            continue
        shift = P.margin_shift(b)  # with a margin the constraint is C_b(θ) − ε·C_b(θ_ref) ⪰ 0 (scale: C_b(θ)'s)
        C = b.constraint_matrix(theta)
        lam, U = np.linalg.eigh(C if shift is None else C - shift)
        size = float(np.abs(lam).max() if shift is None else np.abs(np.linalg.eigvalsh(C)).max())
        if b.kind in ("nonnegative", "drag_diagonal"):  # scalars: no other eigenvalue to compare with
            size = max(size, float(np.max(signal[list(b.indices)])))
        act = np.flatnonzero(lam <= tol * max(size, 1e-300))
        for x, a in enumerate(act):
            for c in act[x:]:
                row = np.zeros(P.p)
                row[list(b.indices)] = np.einsum("i,kij,j->k", U[:, a], V, U[:, c])
                rows.append(row)
        if len(act):
            names.append(f"{b.name} ({len(act)} zero eigenvalue{'s' if len(act) > 1 else ''})")
    for label, bound in (("lower", P.lower), ("upper", P.upper)):
        if bound is None:
            continue
        bound = np.asarray(bound)
        hit = np.isfinite(bound) & (np.abs(theta - bound) <= tol * np.maximum(np.abs(bound), np.abs(theta)).clip(1e-12))
        for k in np.flatnonzero(hit):
            row = np.zeros(P.p)
            row[k] = 1.0
            rows.append(row)
            names.append(f"{P.names[k]} at its {label} bound")
    return (np.array(rows) if rows else np.zeros((0, P.p))), tuple(names)


# --- the sandwich -------------------------------------------------------------------------------
def sandwich(H: np.ndarray, G: np.ndarray, base: BaseParameters, scale: np.ndarray,
             A: np.ndarray | None = None) -> np.ndarray:
    """cov(β̂) (r, r) from the Hessian H (p, p), per-block gradients G (K, p) (None: return H's β-block
    inverse, the "bread" alone) and active-constraint gradients A (k, p); scale (p,) the column norms."""
    r, p = base.rank, base.parameters.p
    s_ind = scale[list(base.independent)]
    Ct = base.C * s_ind[:, None] / scale[None, :]  # β̃ = s_ind β in φ = s θ
    Z = scipy.linalg.null_space(Ct) if r < p else np.zeros((p, 0))
    T = np.hstack([base.embed(), Z]) / scale[:, None]  # θ − θ̂ = T (β̃, u)
    Hx = T.T @ H @ T
    Gx = None if G is None else G @ T
    Ax = np.zeros((0, p)) if A is None or not len(A) else A @ T
    # split u into curved directions (a prior, or a metric that sees them) and flat ones (the data's null
    # space: eigenvalues of H_uu at roundoff level relative to H); flat ones only absorb the constraints
    w, U = np.linalg.eigh(0.5 * (Hx[r:, r:] + Hx[r:, r:].T)) if r < p else (np.zeros(0), np.zeros((0, 0)))
    curved = w > FLAT_RTOL * max(float(np.abs(np.linalg.eigvalsh(0.5 * (Hx + Hx.T))).max()), 1e-300)
    R = np.zeros((p, r + int(curved.sum())))  # (β, u_curved) → x
    R[:r, :r] = np.eye(r)
    R[r:, r:] = U[:, curved]
    Ac, Af = Ax @ R, Ax[:, r:] @ U[:, ~curved]
    if Af.size and np.abs(Af).max() > 0:  # a constraint a flat direction can satisfy restricts nothing
        Uf = scipy.linalg.orth(Af)
        Ac = Ac - Uf @ (Uf.T @ Ac)
    Q = R @ (scipy.linalg.null_space(Ac, rcond=1e-9) if len(Ac) and np.abs(Ac).max() > 0 else np.eye(R.shape[1]))
    Hy_pinv, _ = pinv_psd(Q.T @ Hx @ Q)
    if Gx is None:
        cov_y = Hy_pinv
    else:
        Gy = Gx @ Q
        Gy = Gy - Gy.mean(axis=0)  # the estimating equation's fluctuation: Σ_b g_b = −γ∇R (prior) or the
        # constraints' multipliers at θ̂, not zero, and not noise
        cov_y = Hy_pinv @ (Gy.T @ Gy) @ Hy_pinv
    cov = (Q @ cov_y @ Q.T)[:r, :r]
    return 0.5 * (cov + cov.T) / np.outer(s_ind, s_ind)


def _intervals(values, cov, df, level):
    q = scipy.special.stdtrit(max(df, 1), 0.5 + level / 2)  # Student t quantile, as scipy.stats.t.ppf
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return values - q * se, values + q * se


def base_uncertainty(problem: IdentificationProblem, result: IdentificationResult, estimator,
                     base: BaseParameters | None = None, blocks=None, kind: str = "sandwich",
                     level: float = LEVEL, constraints: str = "ignore") -> BaseUncertainty:
    """The covariance and intervals of the base parameters at ``result`` of ``estimator`` (module
    docstring). base: the regrouping (default: the problem's own); blocks: see ``block_labels``;
    constraints: "ignore" or "project" on the tangent of the active constraints (module docstring)."""
    if kind not in ("sandwich", "model"):
        raise ConfigError(f"kind: expected 'sandwich' or 'model' (bootstrap: dualid.estimators.bootstrap), "
                          f"got {kind!r}")
    if constraints not in ("ignore", "project"):
        raise ConfigError(f"constraints: expected 'ignore' or 'project', got {constraints!r}")
    if not 0 < level < 1:
        raise ConfigError(f"level: expected a probability in (0, 1), got {level!r}")
    base = base or problem.identifiability().base
    theta = np.asarray(result.theta, dtype=float)
    labels = block_labels(problem.N, blocks)
    K, r = int(labels.max()) + 1, base.rank
    if kind == "sandwich" and K <= r:
        raise ConfigError(f"uncertainty: {K} blocks for {r} base parameters; the sandwich needs more blocks "
                               "than base parameters (use shorter segments or kind='model')")
    H, G, f = derivatives(problem, result, estimator, labels)
    A, active = active_constraints(problem, theta) if result.constrained else (None, ())
    conditional = constraints == "project" and bool(active)
    A = A if conditional else None
    scale = np.linalg.norm(problem.Y.reshape(-1, problem.p), axis=0)
    scale[scale == 0] = 1.0
    values = base.values(theta)
    if kind == "model":
        if not isinstance(unwrap(estimator), (OLS, WLS, EnergyLS)) or isinstance(unwrap(estimator), RegularizedWLS):
            raise ConfigError(f"uncertainty: kind='model' is for the quadratic estimators, not {result.method!r}")
        dof = (problem.N if isinstance(unwrap(estimator), EnergyLS) else problem.N * problem.n) - r
        cov = 2.0 * f / max(dof, 1) * sandwich(H, None, base, scale, A)
        lo, hi = _intervals(values, cov, dof, level)
        return BaseUncertainty(result.method, base, values, cov, lo, hi, kind, problem.N, level, active, conditional)
    cov = sandwich(H, G, base, scale, A) * (K / (K - r))
    lo, hi = _intervals(values, cov, K - r, level)
    return BaseUncertainty(result.method, base, values, cov, lo, hi, kind, K, level, active, conditional)


def bootstrap(problem: IdentificationProblem, result: IdentificationResult, estimator,
              base: BaseParameters | None = None, blocks=None, resamples: int = 200, seed: int = 0,
              level: float = LEVEL) -> BaseUncertainty:
    """Block bootstrap: refit ``estimator`` on ``resamples`` resamples (with replacement, seeded) of the
    blocks; percentile intervals and the covariance of the refitted β; failed refits are counted."""
    if not (isinstance(resamples, (int, np.integer)) and resamples >= 10):
        raise ConfigError(f"resamples: expected an integer ≥ 10, got {resamples!r}")
    base = base or problem.identifiability().base
    labels = block_labels(problem.N, blocks)
    groups = [np.flatnonzero(labels == b) for b in range(int(labels.max()) + 1)]
    rng = np.random.default_rng(seed)
    betas, failures = [], 0
    for _ in range(int(resamples)):
        pick = rng.integers(0, len(groups), len(groups))
        try:
            theta = estimator.fit(problem.subset(np.concatenate([groups[b] for b in pick]))).theta
        except (DualidError, np.linalg.LinAlgError):
            failures += 1
            continue
        betas.append(base.values(theta))
    if len(betas) < 10:
        raise SolverError(f"bootstrap: {failures} of {resamples} refits failed; fewer than 10 succeeded")
    betas = np.array(betas)
    alpha = 100 * (1 - level) / 2
    lo, hi = np.percentile(betas, [alpha, 100 - alpha], axis=0)
    cov = np.cov(betas.T).reshape(base.rank, base.rank)
    return BaseUncertainty(result.method, base, base.values(result.theta), cov, lo, hi, "bootstrap", len(groups),
                           level, resamples=int(resamples), failures=failures, note="percentile intervals")
