"""The noise levels of ``dm``'s physical noise model, estimated from the residuals: Σ_τ (torque) and Σ_a (acceleration).

At a fixed θ the residuals r_i = Y_i θ − τ_i are modelled as independent, zero-mean, with covariance

    C_i = Σ_τ + M_i(θ) Σ_a M_i(θ),   Σ_τ = diag(v_1 … v_n),   Σ_a = σ_a² D

Σ_τ has a variance per joint (its own sensor); Σ_a one level σ_a² on the fixed shape D = diag(mean_i v_i²) (one
noise source, the encoders and differentiation filter, at a level relative to each coordinate's own motion). Both
are covariant under a change of unit of any coordinate (q_j → c_j q_j scales τ_j by 1/c_j and v_j by c_j, so that
v_j → v_j / c_j², D_jj → c_j² D_jj and σ_a² stays), so the estimate, and ``dm``'s fit, are equivariant under
per-coordinate units (a joint logged in degrees, torques in N·mm) as well as under the charts the problem records
(``dm`` works in the sensor chart). σ_a² I in one unit would not be: it would weigh a joint logged in degrees 3e3×
differently. On the authors' 3-DoF example this shape also fits better than σ_a² I (mean geodesic error at N = 100
0.155 vs 0.174 with both noises, 0.114 vs 0.145 with encoder noise).

The levels maximise a regularised Gaussian likelihood, (1/N) Σ_i [log det C_i + r_iᵀ C_i⁻¹ r_i] + (ν/N) Σ_t ψ_t / v_t,
with ν = PRIOR_SAMPLES pseudo-samples at ψ = PRIOR_SHARE × the level each variance would have if it alone explained
the residual: a free likelihood reaches +∞ by driving a variance to 0 (weights of 1e12 on real logs); ν ψ / v keeps
every torque variance away from 0 by an amount the data must overcome.

Whether the acceleration noise is there at all is a test, not a prior: the likelihood with σ_a² free is compared
with the likelihood at Σ_a = 0 (Σ_τ alone, closed form). Unless twice the log-likelihood ratio exceeds
LR_ACCELERATION, Σ_a = 0 (``dm`` is then WLS with the estimated Σ_τ): a residual that is torque noise alone keeps no
spurious acceleration noise, whose Deming term would inflate M(θ).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.errors import MetricError
from dualid.problem import strided_rows

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

    def in_chart(self, B: np.ndarray) -> "NoiseLevels":
        """The same levels in the chart q = φ(q̃), B = ∂φ/∂q̃ constant (n, n)."""
        Bi = np.linalg.inv(B)
        return NoiseLevels(B.T @ self.sigma_tau @ B, Bi @ self.sigma_a @ Bi.T, self.torque_share,
                           self.acceleration_share, self.samples, self.likelihood_ratio)


def _shares(M, S, A) -> tuple[float, float]:
    n = S.shape[0]
    MAM = M @ A @ M
    Ci = np.linalg.inv(S + MAM)
    t = float(np.mean(np.einsum("cab,ba->c", Ci, S))) / n
    a = float(np.mean(np.einsum("cab,cba->c", Ci, MAM))) / n
    return t, a


def given_levels(problem, theta: np.ndarray, sigma_tau: np.ndarray, sigma_a: np.ndarray,
                 max_samples: int = NOISE_SAMPLES) -> NoiseLevels:
    """Levels given by the user, with the share of the residual each explains at θ (on at most ``max_samples``
    evenly strided samples)."""
    rows = strided_rows(problem.N, max_samples)
    M = problem.metric.evaluate(theta, rows)
    t, a = _shares(M, np.asarray(sigma_tau, dtype=float), np.asarray(sigma_a, dtype=float))
    return NoiseLevels(np.asarray(sigma_tau, dtype=float), np.asarray(sigma_a, dtype=float), t, a, M.shape[0])


def estimate_noise(problem, theta: np.ndarray, start: NoiseLevels | None = None,
                   max_samples: int = NOISE_SAMPLES) -> NoiseLevels:
    """Σ_τ, Σ_a from the residuals at θ (module doc). MetricError if some M_i(θ) is not positive definite."""
    rows = strided_rows(problem.N, max_samples)
    sub = problem.subset(rows) if rows != slice(0, None, 1) else problem
    r = sub.residual(theta)
    M = sub.metric.evaluate(theta)
    N, n = r.shape
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
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
    Mi = np.linalg.inv(M)
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
    t, a = _shares(M, S, A)
    return NoiseLevels(S, A, t, a, N, lr)


def _scoring(r, a, owner, psi, weight, x) -> tuple[np.ndarray, float]:
    """The variances v (one per owner index) minimising the penalised mean negative log-likelihood of C_i = Σ_t
    v_owner(t) a_it a_itᵀ (rank-one factors a_it, the rows of a[i]), and the mean nll of the data alone there.
    Fisher scoring in x = log v (a change of units is a translation in x, so the iterates are equivariant under it),
    with a backtracking line search: the likelihood is nearly flat along "torque noise ↔ acceleration noise" on a
    joint whose inertia hardly varies, where a first-order method stops early."""
    N, n = r.shape
    m = len(psi)
    E = np.zeros((len(owner), m))
    E[np.arange(len(owner)), owner] = 1.0

    def evaluate(x, order):
        v = np.exp(x)
        C = np.matmul(np.swapaxes(a, 1, 2), a * v[owner][None, :, None])
        try:
            Lc = np.linalg.cholesky(C)
        except np.linalg.LinAlgError:
            return np.inf, np.inf, None, None
        Ci = np.linalg.inv(C)
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
