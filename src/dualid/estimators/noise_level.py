"""The noise levels of ``dm``'s physical noise model, estimated from the residuals: Σ_τ (torque) and Σ_a (acceleration).

Structures: "pooled" (Σ_τ diagonal, Σ_a = σ_a² I: the same encoders and differentiation filter on every joint),
"diagonal" (both diagonal), "highpass" (diagonal, from first differences of consecutive residuals) — all solved by
Fisher scoring in the log-variances with the floor term ν ψ/v (``_diagonal``) — and "full" (below).

At a fixed θ the residuals r_i = Y_i θ − τ_i are modelled as independent, zero-mean, with covariance

    C_i = Σ_τ + M_i(θ) Σ_a M_i(θ)

Both are full (n, n) covariances, estimated by a regularised Gaussian likelihood: minimise

    (1/N) Σ_i [log det C_i + r_iᵀ C_i⁻¹ r_i]  +  (ν/N) Σ_{X ∈ {Σ_τ, Σ_a}} [tr(Ψ_X X⁻¹) + log det X]

The second term is an inverse-Wishart prior with ν pseudo-samples (``PRIOR_SAMPLES``) and scale Ψ_X = ε × the level
X would have if it alone explained the residual: Ψ_τ = ε Σ̂ (Σ̂ = mean r_i r_iᵀ) and Ψ_a = ε mean M_i⁻¹ Σ̂ M_i⁻¹. A free
likelihood can reach +∞ by driving a variance to 0 (weights of 1e12 on some coordinate on real logs); tr(Ψ X⁻¹)
grows without bound as any variance of X goes to 0, so the estimate stays away from 0 by an amount set by how much
the data contradict the source (with the data saying "no such noise", X ends near ε·Ψ·ν/N-ish levels, not at 0).

Chart equivariance: every quantity transforms covariantly under a constant linear change of coordinates B (Σ̂, M_i
and Σ_τ as Bᵀ(·)B; M_i⁻¹ Σ̂ M_i⁻¹ and Σ_a as B⁻¹(·)B⁻ᵀ), so the minimiser does. To make the numerical solve
equivariant too, it runs in a canonical chart fixed by the data: V with Vᵀ Σ̂ V = I and Vᵀ M̄ V diagonal (M̄ = mean
M_i; the generalised eigenvectors), unique up to the signs of its columns, which the Cholesky parametrisation and
L-BFGS do not see. ``dm`` calls this in the problem's sensor chart, so charts recorded by ``in_coordinates``
(configuration-dependent ones too) are covered as well.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from dualid.errors import MetricError
from dualid.problem import strided_rows

NOISE_SAMPLES = 5_000  # the two (n, n) covariances from at most this many evenly strided samples
PRIOR_SAMPLES = 10.0  # ν: the prior's weight, in samples
PRIOR_SHARE = 1e-2  # ε: the prior's scale, as a share of the all-torque / all-acceleration levels


@dataclass(frozen=True)
class NoiseLevels:
    """Σ_τ and Σ_a in the chart of the problem they were estimated on, with the share of the mean residual
    covariance each explains (torque_share + acceleration_share = 1; invariant numbers)."""

    sigma_tau: np.ndarray  # (n, n) torque (covector) covariance
    sigma_a: np.ndarray  # (n, n) acceleration (vector) covariance
    torque_share: float  # mean_i tr(C_i⁻¹ Σ_τ) / n
    acceleration_share: float  # mean_i tr(C_i⁻¹ M_i Σ_a M_i) / n
    samples: int  # samples the estimate used

    def in_chart(self, B: np.ndarray) -> "NoiseLevels":
        """The same levels in the chart q = φ(q̃), B = ∂φ/∂q̃ constant (n, n)."""
        Bi = np.linalg.inv(B)
        return NoiseLevels(B.T @ self.sigma_tau @ B, Bi @ self.sigma_a @ Bi.T, self.torque_share,
                           self.acceleration_share, self.samples)


def _vech_index(n: int):
    return np.tril_indices(n)


def _shares(M, S, A) -> tuple[float, float]:
    n = S.shape[0]
    MAM = M @ A @ M
    Ci = np.linalg.inv(S + MAM)
    t = float(np.mean(np.einsum("cab,ba->c", Ci, S))) / n
    a = float(np.mean(np.einsum("cab,cba->c", Ci, MAM))) / n
    return t, a


def estimate_noise(problem, theta: np.ndarray, *, prior_samples: float = PRIOR_SAMPLES,
                   prior_share: float = PRIOR_SHARE, max_samples: int = NOISE_SAMPLES,
                   start: NoiseLevels | None = None, structure: str = "diagonal") -> NoiseLevels:
    """Σ_τ, Σ_a from the residuals at θ (module doc). MetricError if some M_i(θ) is not positive definite."""
    rows = strided_rows(problem.N, max_samples)
    sub = problem.subset(rows) if rows != slice(0, None, 1) else problem
    r = sub.residual(theta)
    M = sub.metric.evaluate(theta)
    N, n = r.shape
    try:
        Minv = np.linalg.inv(np.linalg.cholesky(M))  # L⁻¹
    except np.linalg.LinAlgError:
        raise MetricError("noise levels: M_i(θ) is not positive definite at some sample") from None
    Minv = np.swapaxes(Minv, 1, 2) @ Minv  # M⁻¹ = L⁻ᵀ L⁻¹
    Sr = r.T @ r / N
    if structure == "diagonal":
        psi = prior_share * np.concatenate([np.diag(Sr), np.diag(np.mean(Minv @ Sr @ Minv, axis=0))])
        return _diagonal(r, [M], psi, prior_samples, start)
    if structure == "pooled":  # one acceleration variance for every joint (same encoders and filter)
        psi = prior_share * np.concatenate([np.diag(Sr), [np.mean(np.diag(np.mean(Minv @ Sr @ Minv, axis=0)))]])
        return _diagonal(r, [M], psi, prior_samples, start, pooled=True)
    if structure == "highpass":
        return _highpass(problem, theta, prior_samples, prior_share, max_samples, start)
    return _full(r, M, Minv, Sr, prior_samples, prior_share, start)


def _full(r: np.ndarray, M: np.ndarray, Minv: np.ndarray, Sr: np.ndarray, prior_samples: float, prior_share: float,
          start: NoiseLevels | None) -> NoiseLevels:
    """The full-covariance estimate (structure "full"): Σ_τ, Σ_a by L-BFGS on their Cholesky factors, in the
    canonical chart of (Σ̂_r, mean M) where the prior Ψ is isotropic."""
    N, n = r.shape
    Mbar = M.mean(axis=0)
    lam, V = _canonical(Sr, Mbar)
    Vt = V.T
    rc = r @ V  # Vᵀ r_i
    Mc = Vt @ M @ V  # Vᵀ M_i V
    Mci = np.linalg.solve(V, np.linalg.solve(V, Minv).swapaxes(1, 2)).swapaxes(1, 2)  # V⁻¹ M⁻¹ V⁻ᵀ
    Mci = 0.5 * (Mci + np.swapaxes(Mci, 1, 2))
    psi_s = prior_share * np.eye(n)  # Ψ_τ = ε Σ̂ (Σ̂ = I here)
    psi_a = prior_share * np.mean(Mci @ Mci, axis=0)  # ε mean M⁻¹ Σ̂ M⁻¹
    psi_a = 0.5 * (psi_a + psi_a.T)
    tri = _vech_index(n)
    m = len(tri[0])
    weight = prior_samples / N

    def unpack(x):
        Ls = np.zeros((n, n))
        La = np.zeros((n, n))
        Ls[tri] = x[:m]
        La[tri] = x[m:]
        return Ls, La

    def fun(x):
        Ls, La = unpack(x)
        S, A = Ls @ Ls.T, La @ La.T
        C = S + Mc @ A @ Mc
        try:
            Lc = np.linalg.cholesky(C)
            LS = np.linalg.cholesky(S)
            LA = np.linalg.cholesky(A)
        except np.linalg.LinAlgError:
            return np.inf, np.zeros_like(x)
        Ci = np.linalg.inv(C)
        w = np.einsum("cab,cb->ca", Ci, rc)
        val = (2 * np.sum(np.log(np.diagonal(Lc, axis1=1, axis2=2))) + np.sum(w * rc)) / N
        G = (Ci - w[:, :, None] * w[:, None, :]).mean(axis=0)  # ∂/∂S
        GA = np.einsum("cab,cbd,cde->ae", Mc, Ci - w[:, :, None] * w[:, None, :], Mc) / N  # ∂/∂A
        Si, Ai = np.linalg.inv(S), np.linalg.inv(A)
        val += weight * (np.sum(Si * psi_s) + np.sum(Ai * psi_a))
        G = G - weight * Si @ psi_s @ Si
        GA = GA - weight * Ai @ psi_a @ Ai
        gS = 2 * (0.5 * (G + G.T)) @ Ls
        gA = 2 * (0.5 * (GA + GA.T)) @ La
        return val, np.concatenate([gS[tri], gA[tri]])

    if start is not None:
        S0 = Vt @ start.sigma_tau @ V
        Vi = np.linalg.inv(V)
        A0 = Vi @ start.sigma_a @ Vi.T
    else:
        S0 = 0.5 * np.eye(n)
        A0 = 0.5 * np.mean(Mci @ Mci, axis=0)
    x0 = np.concatenate([np.linalg.cholesky(0.5 * (S0 + S0.T))[tri], np.linalg.cholesky(0.5 * (A0 + A0.T))[tri]])
    sol = minimize(fun, x0, jac=True, method="L-BFGS-B", options={"maxiter": 500, "gtol": 1e-9, "ftol": 1e-13})
    Ls, La = unpack(sol.x)
    S, A = Ls @ Ls.T, La @ La.T
    t, a = _shares(Mc, S, A)
    Vi = np.linalg.inv(V)
    sigma_tau = Vi.T @ S @ Vi
    sigma_a = V @ A @ V.T
    return NoiseLevels(0.5 * (sigma_tau + sigma_tau.T), 0.5 * (sigma_a + sigma_a.T), t, a, N)


def _canonical(Sr: np.ndarray, Mbar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(λ, V): Mbar V = Sr V diag(λ), Vᵀ Sr V = I (scipy's generalised symmetric eigenproblem)."""
    from scipy.linalg import eigh

    n = Sr.shape[0]
    scale = np.trace(Sr) / n if np.trace(Sr) > 0 else 1.0
    Sr = Sr + 1e-12 * scale * np.eye(n)  # exact data: a residual covariance of rounding size
    lam, V = eigh(Mbar, Sr)
    return lam, V


def _diagonal(r, Ms, psi, prior_samples, start, s_mult=1.0, pooled=False) -> NoiseLevels:
    """Diagonal Σ_τ, Σ_a in the problem's chart (independent sensors per joint). The model of Cov(r_i) is
    s_mult Σ_τ + Σ_j M_ij Σ_a M_ij over the metrics Ms (one for raw residuals; two, and s_mult = 2, for differences):
    linear in the 2n variances v, C_i = Σ_t v_t a_it a_itᵀ over rank-one terms a_it (√s_mult e_j, and the columns of
    each M_ij). Solved by Fisher scoring in x = log v (Fisher information ½ Σ_i (a_itᵀ C_i⁻¹ a_iu)² summed per variance;
    a change of units is a translation in x, so the iterates are equivariant under it), with a backtracking line
    search on the penalised negative log-likelihood. Scoring, not a first-order method: the likelihood is nearly
    flat along "torque noise ↔ acceleration noise" on a joint whose inertia hardly varies, and L-BFGS stopped
    early in that valley (3 nats from the optimum on the authors' example, enough to move θ̂ far)."""
    N, n = r.shape
    weight = prior_samples / N
    eye = np.broadcast_to(np.sqrt(s_mult) * np.eye(n), (N, n, n))
    # rank-one factors: (N, T, n) with T = n (torque) + n·len(Ms) (acceleration: column j of each M)
    a = np.concatenate([eye] + [np.swapaxes(M, 1, 2) for M in Ms], axis=1)
    acc = np.full(n, n) if pooled else n + np.arange(n)
    m = n + (1 if pooled else n)  # number of variances
    owner = np.concatenate([np.arange(n)] + [acc] * len(Ms))  # variance index of each factor
    E = np.zeros((len(owner), m))
    E[np.arange(len(owner)), owner] = 1.0

    def evaluate(x, order):
        v = np.exp(x)
        C = np.matmul(np.swapaxes(a, 1, 2), a * v[owner][None, :, None])
        try:
            Lc = np.linalg.cholesky(C)
        except np.linalg.LinAlgError:
            return np.inf, None, None
        Ci = np.linalg.inv(C)
        w = np.einsum("cab,cb->ca", Ci, r)
        val = (2 * np.sum(np.log(np.diagonal(Lc, axis1=1, axis2=2))) + np.sum(w * r)) / N + weight * float(np.sum(psi / v))
        if not order:
            return val, None, None
        K = np.matmul(np.matmul(a, Ci), np.swapaxes(a, 1, 2))  # a_tᵀ C⁻¹ a_u
        aw = np.einsum("cti,ci->ct", a, w)  # a_tᵀ C⁻¹ r
        gv = E.T @ (np.einsum("ctt->t", K) - np.einsum("ct,ct->t", aw, aw)) / N  # ∂/∂v of the mean nll
        F = E.T @ (K * K).sum(axis=0) @ E / N  # Fisher information of the mean nll (×2: nll = −2 log L)
        grad = v * gv - weight * psi / v
        hess = np.outer(v, v) * F + np.diag(weight * psi / v)
        return val, grad, hess

    if start is not None:
        va = np.diag(start.sigma_a)
        x = np.log(np.concatenate([np.diag(start.sigma_tau), [va.mean()] if pooled else va]))
    else:
        x = np.log(psi * 50)
    val, grad, hess = evaluate(x, 1)
    for _ in range(100):
        step = -np.linalg.solve(hess + 1e-12 * np.trace(hess) * np.eye(m), grad)
        dec = -float(grad @ step)
        if dec < 1e-12:
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
        val, grad, hess = evaluate(x, 1)
    v = np.exp(x)
    S, A = np.diag(v[:n]), np.diag(v[acc])
    t, ac = _shares(Ms[0], S, A)
    return NoiseLevels(S, A, t, ac, N)


def _highpass(problem, theta, prior_samples, prior_share, max_samples, start) -> NoiseLevels:
    """Diagonal levels from first differences of consecutive residuals, Δr_i = r_{i+1} − r_i: the part of the residual
    that follows the motion (a biased θ, smooth unmodelled torques) changes little between neighbouring samples and
    cancels, sensor noise does not. Independent noise gives Cov(Δr_i) = 2Σ_τ + M_i Σ_a M_i + M_{i+1} Σ_a M_{i+1}; noise
    correlated over neighbouring samples by a filter scales both sources alike, which moves neither the ratio of
    the levels nor the fit (f's minimiser depends on Σ_τ, Σ_a only up to a common factor)."""
    N = problem.N
    step = max(1, -(-(N - 1) // max_samples))
    i = np.arange(0, N - 1, step)
    r = problem.residual(theta)
    dr = r[i + 1] - r[i]
    Ma, Mb = problem.metric.evaluate(theta, i), problem.metric.evaluate(theta, i + 1)
    try:
        La, Lb = np.linalg.inv(np.linalg.cholesky(Ma)), np.linalg.inv(np.linalg.cholesky(Mb))
    except np.linalg.LinAlgError:
        raise MetricError("noise levels: M_i(θ) is not positive definite at some sample") from None
    Sd = dr.T @ dr / len(i) / 2
    all_a = sum(np.mean(np.swapaxes(L, 1, 2) @ L @ Sd @ np.swapaxes(L, 1, 2) @ L, axis=0) for L in (La, Lb)) / 2
    psi = prior_share * np.concatenate([np.diag(Sd), np.diag(all_a)])
    return _diagonal(dr, [Ma, Mb], psi, prior_samples, start, s_mult=2.0)
