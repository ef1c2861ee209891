"""``dm``'s physical noise model (docs/estimators.md): its objective, the estimate of its noise levels, the held-out check.

The objective. f(θ) = Σ r_iᵀ C_i(θ)⁻¹ r_i, r_i = Y_i θ − τ_i, C_i(θ) = Σ_τ + M_i(θ) Σ_a M_i(θ): torque noise (Σ_τ, a
covector covariance) and acceleration noise inside Y_i (Σ_a, a vector covariance) give the residual at the true θ
this covariance. With w_i = C_i⁻¹ r_i, u_i = Σ_a M_i w_i, P_i = [M_ik w_i]_k and Q_i = [M_ik u_i]_k (n × p), and
D_i = Y_i − C_ik w_i = Y_i − Q_i − M_i Σ_a P_i:

    ∂f/∂θ_k       = Σ_i 2 Y_ikᵀ w_i − 2 u_iᵀ M_ik w_i
    ∂²f/∂θ_k∂θ_l  = Σ_i 2 D_ikᵀ C_i⁻¹ D_il − 2 P_ikᵀ Σ_a P_il        (M affine in θ: exact)

The first term is PSD (the Gauss–Newton part); f is not convex, so the Hessian handed to the interior point is the
exact one where it is positive definite and the Gauss–Newton part otherwise. f is the same in every chart when Σ_τ
and Σ_a are carried covariantly (Σ_τ' = BᵀΣ_τB, Σ_a' = B⁻¹Σ_aB⁻ᵀ).

The noise levels, from the residuals at a fixed θ: Σ_τ = diag(v_1 … v_n), a variance per joint (its own sensor), and
Σ_a = σ_a² D, one level on the fixed shape D = diag(mean_i v_i²) (one source, the encoders and differentiation
filter, relative to each coordinate's own motion). Both are covariant under a change of unit of any coordinate
(q_j → c_j q_j: v_j → v_j / c_j², D_jj → c_j² D_jj, σ_a² stays), so the estimate and ``dm``'s fit are equivariant under
per-coordinate units; σ_a² I would weigh a joint logged in degrees 3e3× differently. The levels maximise a
regularised Gaussian likelihood, (1/N) Σ_i [log det C_i + r_iᵀ C_i⁻¹ r_i] + (ν/N) Σ_t ψ_t / v_t, with ν =
PRIOR_SAMPLES pseudo-samples at ψ = PRIOR_SHARE × the level each variance would have if it alone explained the
residual (a free likelihood reaches +∞ by driving a variance to 0). Acceleration noise is a test, not a prior: unless
twice the log-likelihood ratio against Σ_a = 0 exceeds LR_ACCELERATION, Σ_a = 0 (``dm`` is then WLS).

The check: is the residual the modelled noise? Under regressor noise the attenuated least-squares fit predicts noisy
held-out torque better than a consistent fit, but the noise model predicts by how much. For a θ fitted on other
samples and a held-out sample with measured Y_i = Y*_i + ΔY_i (ΔY_i θ = M_i(θ) δa_i):

    E[r_iᵀ W r_i] = ‖Y*_i (θ − θ*)‖²_W + tr(W Σ_τ) + tr(W M_i(θ) Σ_a M_i(θ))
    ‖Y*_i Δ‖²_W ≈ ‖Y_i Δ‖²_W − tr(W M̄_i(Δ) Σ_a M̄_i(Δ))       (M̄(Δ) = M(Δ) − M(0), the linear part)

with θ* ≈ the full-data fit θ̂ (for the consistent fit the first term is its estimation variance, about p/(n N_train)
of the noise). WLS (W = Σ̂⁻¹, Σ̂ the residual covariance at θ̂) and dm (levels fixed) are fitted on
each of two contiguous halves, unconstrained from θ̂ (WLS in one exact Newton step, dm in NEWTON_STEPS damped ones),
and scored on the other half in W. ``excess`` is the measured held-out gap dm − WLS minus the predicted one, over
WLS's held-out loss: near 0 when the residual is the modelled noise, positive when it is not (unmodelled torques the
fit tried to absorb by moving M(θ)). The noise model is rejected (``dm`` says so and falls back) when the excess is
both relevant (> EXCESS_TOL) and significant (> Z_REJECT standard errors, from contiguous blocks of samples).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.errors import MetricError
from dualid.estimators.newton.objective import CHUNK, Derivatives, value_or_inf
from dualid.linalg import NotPositiveDefinite, cholesky_batch, cholesky_inverse, forward_substitute, tri_inverse
from dualid.problem import IdentificationProblem, additive, sample_blocks, strided_rows

def noise_model_covariance(M: np.ndarray, sigma_tau: np.ndarray, sigma_a: np.ndarray) -> np.ndarray:
    """C_i = Σ_τ + M_i Σ_a M_i for M (c, n, n)."""
    C = sigma_tau + M @ sigma_a @ M
    return 0.5 * (C + np.swapaxes(C, 1, 2))


def noise_model_derivatives(problem, theta: np.ndarray, sigma_tau: np.ndarray, sigma_a: np.ndarray, order: int = 2,
                            chunk: int = CHUNK) -> Derivatives:
    """f (and ∇f and the Hessian for order 2; see the module doc), accumulated over chunks of samples.

    Raises NotPositiveDefinite when some C_i(θ) is not positive definite (Σ_τ singular and M_i(θ) singular)."""
    f, grad, gn, neg = noise_model_sums(problem, np.asarray(theta, dtype=float), sigma_tau, sigma_a, order, chunk)
    if not np.isfinite(f):
        raise NotPositiveDefinite
    if not order:
        return Derivatives(f)
    gn = 0.5 * (gn + gn.T)
    exact = gn - 0.5 * (neg + neg.T)
    return Derivatives(f, grad, exact if _positive_definite(exact) else gn)


@additive
def noise_model_sums(problem, theta: np.ndarray, sigma_tau: np.ndarray, sigma_a: np.ndarray, order: int,
                     chunk: int) -> tuple:
    """(f, ∇f, Gauss–Newton part, negative part) summed over the samples (None beyond f for order 0): one pass,
    run where the data live on a problem spread over partitions."""
    p = problem.p
    f = 0.0
    grad = np.zeros(p) if order else None
    gn = np.zeros((p, p)) if order else None
    neg = np.zeros((p, p)) if order else None
    for block, rows, _ in sample_blocks(problem, chunk):
        Y = block.Y[rows]
        c, n = Y.shape[0], Y.shape[1]
        r = (Y.reshape(c * n, p) @ theta).reshape(c, n) - block.tau[rows]
        flat = not order and not np.any(sigma_a)  # f with C_i = Σ_τ at every sample: one factor, no M_i(θ)
        M = np.zeros((1, n, n)) if flat else block.metric.evaluate(theta, rows)
        L = np.broadcast_to(cholesky_batch(noise_model_covariance(M, sigma_tau, sigma_a)), (c, n, n))
        if not order:
            z = forward_substitute(L, r)
            f += float(np.sum(z * z))
            continue
        Li = tri_inverse(L)
        z = np.einsum("cab,cb->ca", Li, r)
        f += float(np.sum(z * z))
        w = np.einsum("cba,cb->ca", Li, z)  # C⁻¹ r
        u = np.einsum("cab,cb->ca", M, w) @ sigma_a  # Σ_a M w (Σ_a symmetric)
        P = block.metric.apply(w, rows)  # [M_k w]_k (c, n, p)
        Q = block.metric.apply(u, rows)  # [M_k u]_k
        grad += 2.0 * (w.reshape(-1) @ Y.reshape(-1, p)) - 2.0 * np.einsum("ca,cak->k", u, P)
        SP = np.matmul(sigma_a, P)  # Σ_a P (c, n, p)
        D = Y - Q - np.matmul(M, SP)
        Z = np.matmul(Li, D).reshape(-1, p)
        gn += 2.0 * (Z.T @ Z)
        neg += 2.0 * (P.reshape(-1, p).T @ SP.reshape(-1, p))
    return f, grad, gn, neg


def _positive_definite(K: np.ndarray) -> bool:
    d = np.sqrt(np.abs(np.diag(K)))
    d[d == 0] = 1.0
    try:
        np.linalg.cholesky(K / np.outer(d, d) - 1e-10 * np.eye(len(K)))
    except np.linalg.LinAlgError:
        return False
    return True


def noise_model_objective(problem, theta, sigma_tau, sigma_a, chunk: int = CHUNK) -> float:
    """f(θ), +inf where some C_i(θ) is not positive definite."""
    return value_or_inf(lambda th, order: noise_model_derivatives(problem, th, sigma_tau, sigma_a, order, chunk), theta)


@additive
def noise_model_scale(problem, theta, sigma_tau, sigma_a, chunk: int = CHUNK) -> float:
    """Σ τ_iᵀ C_i(θ)⁻¹ τ_i: the size of the measured forces in the noise model's metric (the objective's scale)."""
    total = 0.0
    for block, rows, _ in sample_blocks(problem, chunk):
        L = cholesky_batch(noise_model_covariance(block.metric.evaluate(theta, rows), sigma_tau, sigma_a))
        z = forward_substitute(L, block.tau[rows])
        total += float(np.sum(z * z))
    return total


# --- the noise levels ----------------------------------------------------------------------------------------------

NOISE_SAMPLES = 5_000  # the levels from at most this many evenly strided samples
PRIOR_SAMPLES = 10.0  # ν: the prior's weight, in samples
PRIOR_SHARE = 1e-2  # ε: the prior's scale, as a share of the all-torque / all-acceleration levels
SCORING_TOL = 1e-6  # Newton decrement (mean negative log-likelihood per sample) at which scoring stops
LR_ACCELERATION = 10.0  # twice the log-likelihood ratio Σ_a free vs Σ_a = 0 needed to keep acceleration noise


@dataclass(frozen=True)
class NoiseLevels:
    """Σ_τ and Σ_a in the chart of the problem they were estimated on, with the share of the mean residual
    covariance each explains (torque_share + acceleration_share = 1; invariant numbers)."""

    sigma_tau: np.ndarray  # (n, n) torque (covector) covariance
    sigma_a: np.ndarray  # (n, n) acceleration (vector) covariance
    torque_share: float  # mean_i tr(C_i⁻¹ Σ_τ) / n
    acceleration_share: float  # mean_i tr(C_i⁻¹ M_i Σ_a M_i) / n
    samples: int  # samples the estimate used
    likelihood_ratio: float = float("nan")  # 2 log L(Σ_a free) − 2 log L(Σ_a = 0)

def _shares(M, S, A) -> tuple[float, float]:
    n = S.shape[0]
    MAM = M @ A @ M
    try:  # C_i = Σ_τ + M_i Σ_a M_i from MAM (the Cholesky factor reads its lower triangle)
        Ci = cholesky_inverse(cholesky_batch(S + MAM))
    except NotPositiveDefinite:  # given levels with Σ_τ singular where M_i Σ_a M_i is
        raise MetricError("noise levels: Σ_τ + M_i Σ_a M_i is not positive definite at some sample") from None
    t = float(np.mean(np.einsum("cab,ba->c", Ci, S))) / n
    a = float(np.mean(np.einsum("cab,cba->c", Ci, MAM))) / n
    return t, a


def given_levels(problem, theta: np.ndarray, sigma_tau: np.ndarray, sigma_a: np.ndarray,
                 max_samples: int = NOISE_SAMPLES) -> NoiseLevels:
    """Levels given by the user, with the share of the residual each explains at θ (on at most ``max_samples``
    evenly strided samples)."""
    S, A = np.asarray(sigma_tau, dtype=float), np.asarray(sigma_a, dtype=float)
    M = problem.metric.evaluate(theta, strided_rows(problem.N, max_samples))
    return NoiseLevels(S, A, *_shares(M, S, A), M.shape[0])


def estimate_noise(problem, theta: np.ndarray, start: NoiseLevels | None = None,
                   max_samples: int = NOISE_SAMPLES) -> NoiseLevels:
    """Σ_τ, Σ_a from the residuals at θ (module doc). MetricError if some M_i(θ) is not positive definite."""
    rows = strided_rows(problem.N, max_samples)
    sub = problem.subset(rows) if rows != slice(0, None, 1) else problem
    r = sub.residual(theta)
    M = sub.metric.evaluate(theta)
    N, n = r.shape
    try:
        Mi = cholesky_inverse(cholesky_batch(M))
    except NotPositiveDefinite:
        raise MetricError("noise levels: M_i(θ) is not positive definite at some sample") from None
    s = np.mean(r * r, axis=0)
    D = np.mean(sub.v**2, axis=0)  # the shape of Σ_a: each coordinate's mean squared velocity
    weight = PRIOR_SAMPLES / N
    v0 = s + weight * PRIOR_SHARE * s  # Σ_a = 0: the penalised torque-only variances, closed form
    nll0 = float(np.sum(np.log(v0) + s / v0))
    if not np.all(np.isfinite(D)) or not D.max() > 0:
        return NoiseLevels(np.diag(v0), np.zeros((n, n)), 1.0, 0.0, N)
    # rank-one factors of C_i = Σ_j v_j e_j e_jᵀ + σ_a² Σ_j D_j m_ij m_ijᵀ (m_ij column j of M_i)
    factors = np.concatenate([np.broadcast_to(np.eye(n), (N, n, n)),
                              np.swapaxes(M, 1, 2) * np.sqrt(D)[None, :, None]], axis=1)
    owner = np.concatenate([np.arange(n), np.full(n, n)])
    # ψ: the all-torque levels s and the all-acceleration level of σ_a², mean_j (mean_i M_i⁻¹ diag(s) M_i⁻¹)_jj / D_j
    all_a = float(np.mean(np.einsum("cjk,k,cjk->j", Mi, s, Mi) / N / np.where(D > 0, D, np.inf)))
    psi = PRIOR_SHARE * np.concatenate([s, [all_a]])
    if start is not None and start.acceleration_share > 0:
        k = int(np.argmax(D))  # Σ_a = σ_a² diag(D): σ_a² from its largest entry
        x0 = np.log(np.concatenate([np.diag(start.sigma_tau), [start.sigma_a[k, k] / D[k]]]))
    else:
        x0 = np.log(np.concatenate([0.5 * s, [0.5 * all_a]]))
    v, nll = _scoring(r, factors, owner, psi, weight, x0)
    lr = N * (nll0 - nll)
    if not lr > LR_ACCELERATION:
        return NoiseLevels(np.diag(v0), np.zeros((n, n)), 1.0, 0.0, N, lr)
    S, A = np.diag(v[:n]), v[n] * np.diag(D)
    return NoiseLevels(S, A, *_shares(M, S, A), N, lr)


def _scoring(r, a, owner, psi, weight, x) -> tuple[np.ndarray, float]:
    """The variances v (one per owner index) minimising the penalised mean negative log-likelihood of C_i = Σ_t
    v_owner(t) a_it a_itᵀ (rank-one factors a_it, the rows of a[i]), and the mean nll of the data alone there: Fisher
    scoring in x = log v (equivariant under units) with a backtracking line search (the likelihood is nearly flat
    along "torque noise ↔ acceleration noise" where a joint's inertia hardly varies)."""
    N, n = r.shape
    m = len(psi)
    E = np.zeros((len(owner), m))
    E[np.arange(len(owner)), owner] = 1.0

    def evaluate(x, order):
        v = np.exp(x)
        C = np.matmul(np.swapaxes(a, 1, 2), a * v[owner][None, :, None])
        try:
            Lc = cholesky_batch(C)
        except NotPositiveDefinite:
            return np.inf, np.inf, None, None
        Ci = cholesky_inverse(Lc)
        w = np.einsum("cab,cb->ca", Ci, r)
        data = (2 * np.sum(np.log(np.diagonal(Lc, axis1=1, axis2=2))) + np.sum(w * r)) / N
        val = data + weight * float(np.sum(psi / v))
        if not order:
            return val, data, None, None
        K = np.matmul(np.matmul(a, Ci), np.swapaxes(a, 1, 2))  # a_tᵀ C⁻¹ a_u
        aw = np.einsum("cti,ci->ct", a, w)  # a_tᵀ C⁻¹ r
        gv = E.T @ (np.einsum("ctt->t", K) - np.einsum("ct,ct->t", aw, aw)) / N  # ∂/∂v of the mean nll
        F = E.T @ (K * K).sum(axis=0) @ E / N  # Fisher information of the mean nll (×2: nll = −2 log L)
        grad = v * gv - weight * psi / v
        hess = np.outer(v, v) * F + np.diag(weight * psi / v)
        return val, data, grad, hess

    val, data, grad, hess = evaluate(x, 1)
    for _ in range(50):
        step = -np.linalg.solve(hess + 1e-12 * np.trace(hess) * np.eye(m), grad)
        dec = -float(grad @ step)
        if dec < SCORING_TOL or np.max(np.abs(step)) < 1e-9:
            break
        t = 1.0
        while t > 1e-8:
            trial = evaluate(x + t * step, 0)[0]
            if trial <= val - 1e-4 * t * dec:
                break
            t *= 0.5
        else:
            break
        x = x + t * step
        val, data, grad, hess = evaluate(x, 1)
    return np.exp(x), data


# --- the held-out check -------------------------------------------------------------------------------------------

EXCESS_TOL = 0.01  # the noise model is rejected when dm's held-out loss exceeds its prediction by > 1 % of WLS's …
Z_REJECT = 2.0  # … and by more than this many standard errors of that excess (a significant and a relevant excess)
Z_DECISIVE = 3.0  # a rejection by this many, at Newton steps from the pilot: ``dm`` makes no constrained solve (on 556
# two-round fits no first-round rejection beyond 3 standard errors was accepted after the second, one beyond 2.2 was;
# on 934 fits every early rejection beyond 3 was one after the first round too)
NEWTON_STEPS = 2  # damped Newton steps of each half's dm fit from the full-data fit
BLOCKS = 20  # contiguous blocks of held-out samples for the standard error


@dataclass(frozen=True)
class NoiseCheck:
    excess: float  # (measured − predicted held-out gap dm − WLS) / WLS held-out loss, summed over the two folds
    standard_error: float  # of excess, from contiguous blocks
    measured_gap: float  # (dm − WLS held-out loss) / WLS held-out loss
    predicted_gap: float  # the same, as the noise model predicts it
    rejected: bool  # excess > max(EXCESS_TOL, Z_REJECT × standard_error)

    @property
    def decisive(self) -> bool:
        """Rejected by more than Z_DECISIVE standard errors."""
        return self.excess > max(EXCESS_TOL, Z_DECISIVE * self.standard_error)


def _loss(problem, theta, W) -> np.ndarray:
    """Per sample r_iᵀ W r_i."""
    r = problem.residual(theta)
    return np.einsum("ia,ab,ib->i", r, W, r)


def _predicted(problem, theta, theta_ref, W, S, A, train_size: int | None = None) -> np.ndarray:
    """Per held-out sample, the loss the noise model predicts for θ. With train_size (the consistent fit): the noise
    terms plus its estimation variance, p/train_size of the noise per sample (not its measured distance to θ̂, which
    is what the check tests); without (WLS): the noise terms plus its measured distance to θ̂, noise removed."""
    C = noise_model_covariance(problem.metric.evaluate(theta), S, A)
    noise = np.einsum("ab,iba->i", W, C)
    if train_size is not None:
        return noise * (1.0 + problem.p / (problem.n * train_size))
    d = np.asarray(theta) - np.asarray(theta_ref)
    Ml = problem.metric.evaluate(d) - problem.metric.evaluate(np.zeros_like(d))
    Yd = problem.Y @ d
    seen = np.einsum("ia,ab,ib->i", Yd, W, Yd)
    noise_in_seen = np.einsum("ab,iba->i", W, Ml @ A @ Ml)
    return noise + seen - noise_in_seen


def _newton_step(theta: np.ndarray, grad: np.ndarray, hess: np.ndarray) -> np.ndarray:
    """θ − H⁺ g, H⁺ the pseudo-inverse of the column-scaled H (directions the data do not see are not moved)."""
    d = np.sqrt(np.abs(np.diag(hess)))
    d[d == 0] = 1.0
    step = np.linalg.lstsq(hess / np.outer(d, d), grad / d, rcond=1e-10)[0] / d
    return np.asarray(theta) - step


def newton_refit(problem, theta, S, A, chunk: int = CHUNK, steps: int = NEWTON_STEPS) -> np.ndarray:
    """dm's fit of problem at fixed noise levels: damped Newton steps from θ (unconstrained)."""
    der = noise_model_derivatives(problem, theta, S, A, 2, chunk)
    for _ in range(steps):
        trial = _newton_step(theta, der.grad, der.hess)
        for _ in range(30):
            f = noise_model_objective(problem, trial, S, A, chunk)
            if f <= der.f:
                break
            trial = 0.5 * (trial + theta)
        else:
            return theta
        theta = trial
        der = noise_model_derivatives(problem, theta, S, A, 2, chunk)
    return theta


def _wls_step(problem, theta, W) -> np.ndarray:
    """The unconstrained WLS fit of problem in the weight W, as one (exact) Newton step from θ."""
    Y = problem.Y.reshape(-1, problem.p)
    WY = np.einsum("ab,ibk->iak", W, problem.Y).reshape(-1, problem.p)
    r = problem.residual(theta).reshape(-1)
    return _newton_step(theta, 2.0 * WY.T @ r, 2.0 * WY.T @ Y)


def check_noise_model(problem: IdentificationProblem, theta: np.ndarray, S: np.ndarray, A: np.ndarray,
                      W: np.ndarray, chunk: int = CHUNK) -> NoiseCheck | None:
    """The two-fold check (module doc). Each half's fits start from the full-data θ̂, unconstrained: WLS in one exact
    Newton step (its objective is quadratic), dm in NEWTON_STEPS damped ones: the check costs a few evaluations of
    the objective's derivatives instead of four fits. None when a half is too small to fit (fewer equations than twice the
    parameters)."""
    half = problem.N // 2
    if half * problem.n < 2 * problem.p:
        return None
    halves = (problem.subset(np.arange(half)), problem.subset(np.arange(half, problem.N)))
    measured, predicted, base = [], [], 0.0
    for train, test in (halves, halves[::-1]):
        th_w, th_d = _wls_step(train, theta, W), newton_refit(train, theta, S, A, chunk)
        lw = _loss(test, th_w, W)
        measured.append(_loss(test, th_d, W) - lw)
        predicted.append(_predicted(test, th_d, theta, W, S, A, train.N) - _predicted(test, th_w, theta, W, S, A))
        base += float(lw.sum())
    e = np.concatenate(measured) - np.concatenate(predicted)  # per held-out sample
    excess = float(e.sum()) / base
    # its standard error from BLOCKS contiguous blocks (neighbouring residuals are correlated by filters)
    sums = np.array([b.sum() for b in np.array_split(e, BLOCKS)])
    se = float(np.sqrt(BLOCKS / (BLOCKS - 1) * np.sum((sums - sums.mean()) ** 2))) / base
    measured_gap = float(np.concatenate(measured).sum()) / base
    predicted_gap = float(np.concatenate(predicted).sum()) / base
    return NoiseCheck(excess, se, measured_gap, predicted_gap, bool(excess > max(EXCESS_TOL, Z_REJECT * se)))
