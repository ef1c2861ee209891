"""Is the residual the modelled noise? A held-out check of ``dm``'s noise model against WLS.

Under regressor noise the attenuated least-squares fit predicts *noisy* held-out torque better than a consistent fit,
so held-out torque alone cannot choose between them. But the noise model predicts by how much. For a θ fitted on
other samples and a held-out sample with measured Y_i = Y*_i + ΔY_i (ΔY_i θ = M_i(θ) δa_i for acceleration noise):

    E[r_iᵀ W r_i] = ‖Y*_i (θ − θ*)‖²_W + tr(W Σ_τ) + tr(W M_i(θ) Σ_a M_i(θ))
    ‖Y*_i Δ‖²_W ≈ ‖Y_i Δ‖²_W − tr(W M̄_i(Δ) Σ_a M̄_i(Δ))       (M̄(Δ) = M(Δ) − M(0), the linear part)

with θ* ≈ the full-data fit θ̂; for the consistent fit the first term is its estimation variance, about p/(n N_train)
of the noise (a half fit that moved far from θ̂ in directions the data barely see is what the check is for). The
check fits WLS (weight W = Σ̂⁻¹, Σ̂ the diagonal of the residual covariance at θ̂) and dm (noise levels fixed) on
each of two contiguous halves of the samples, both unconstrained from θ̂ (WLS in one exact Newton step, dm in
NEWTON_STEPS damped ones), and scores both on the other half in W. ``excess`` is the measured held-out gap dm − WLS
minus the gap the noise model predicts, over WLS's held-out loss: near 0 (± sampling) when
the residual is the modelled noise, positive when dm predicts held-out torque worse than its own noise model
explains — a residual that is not noise (unmodelled torques that the fit tried to absorb by moving M(θ)). On the
authors' 3-DoF example (N = 1,000, regressor noise, 3 % torque noise) the measured and predicted gaps were 2.7–3.8 %
and agreed to ≤ 0.25 %. The noise model is rejected (``dm`` returns WLS, and says so) when the excess is both
relevant (> EXCESS_TOL) and significant (> Z_REJECT standard errors, from contiguous blocks of held-out samples).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dualid.estimators.newton.noise_objective import (noise_model_covariance, noise_model_derivatives,
                                                        noise_model_objective)
from dualid.estimators.newton.objective import CHUNK
from dualid.problem import IdentificationProblem

EXCESS_TOL = 0.01  # the noise model is rejected when dm's held-out loss exceeds its prediction by > 1 % of WLS's …
Z_REJECT = 2.0  # … and by more than this many standard errors of that excess (a significant and a relevant excess)
NEWTON_STEPS = 2  # damped Newton steps of each half's dm fit from the full-data fit
BLOCKS = 20  # contiguous blocks of held-out samples for the standard error


@dataclass(frozen=True)
class NoiseCheck:
    excess: float  # (measured − predicted held-out gap dm − WLS) / WLS held-out loss, summed over the two folds
    standard_error: float  # of excess, from contiguous blocks
    measured_gap: float  # (dm − WLS held-out loss) / WLS held-out loss
    predicted_gap: float  # the same, as the noise model predicts it
    rejected: bool  # excess > max(EXCESS_TOL, Z_REJECT × standard_error)


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


def _refit(problem, theta, S, A, chunk, steps: int = NEWTON_STEPS) -> np.ndarray:
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
    folds = (np.arange(half), np.arange(half, problem.N))
    measured, predicted, base = [], [], 0.0
    for train_rows, test_rows in (folds, folds[::-1]):
        train, test = problem.subset(train_rows), problem.subset(test_rows)
        th_w, th_d = _wls_step(train, theta, W), _refit(train, theta, S, A, chunk)
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
