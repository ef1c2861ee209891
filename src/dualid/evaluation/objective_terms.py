"""The Hessian and the per-block gradient sums of each estimator's objective at its optimum: the two terms of the
sandwich covariance of ``evaluation.uncertainty`` (its module doc lists the formulas per estimator)."""

from __future__ import annotations

import numpy as np

from dualid.errors import ConfigError, MetricError
from dualid.estimators.dual_metric import DualMetric
from dualid.estimators.least_squares import OLS, WLS, EnergyLS, RegularizedWLS, covariance_weight
from dualid.estimators.newton.objective import NotPositiveDefinite, dual_metric_derivatives
from dualid.estimators.noise_dm import NoiseModelDM
from dualid.estimators.noise_model import noise_model_covariance, noise_model_derivatives
from dualid.estimators.result import IdentificationResult
from dualid.evaluation.guards import Guarded
from dualid.linalg import pinv_psd
from dualid.model.consistency import prior_blocks, pullback_metric
from dualid.problem import IdentificationProblem


def unwrap(estimator):
    return estimator.estimator if isinstance(estimator, Guarded) else estimator


def _weights(problem: IdentificationProblem, result: IdentificationResult, est):
    """(problem in the chart of the fit, W (n, n) or per-sample C_i⁻¹ as Cholesky factors, energy flag)."""
    if isinstance(est, OLS):
        return problem, np.eye(problem.n), None
    if isinstance(est, EnergyLS):
        return problem, None, None
    if isinstance(est, (WLS, RegularizedWLS)):
        S = result.info.get("covariance_matrix")
        if S is None:
            W, _ = covariance_weight(problem, est.covariance, est)
        else:
            W = np.linalg.inv(np.asarray(S, dtype=float))
        return problem, 0.5 * (W + W.T), None
    if isinstance(est, NoiseModelDM):  # dm returned WLS (its noise check): its weight, in the sensor chart
        if "covariance_matrix" not in result.info:
            raise ConfigError("uncertainty (dm): the result does not record the covariance its WLS fit used "
                              "(info['covariance_matrix']); fit it again with this version of dualid")
        return problem.in_sensor_chart(), np.linalg.inv(np.asarray(result.info["covariance_matrix"], dtype=float)), None
    raise ConfigError(f"uncertainty: no sandwich for estimator {type(est).__name__} (method {result.method!r}); "
                           "supported: OLS, WLS, EnergyLS, RegularizedWLS, NoiseModelDM (dm), DualMetric (dm-paper); "
                           "use the block bootstrap (dualid.bootstrap; in a fit config: "
                           "uncertainty: {method: bootstrap})")


def derivatives(problem: IdentificationProblem, result: IdentificationResult, estimator,
                labels: np.ndarray, chunk: int = 8192) -> tuple[np.ndarray, np.ndarray, float]:
    """(H (p, p) the Hessian of the estimator's objective at θ̂, G (K, p) the per-block sums of the data
    term's per-sample gradients, f the data term at θ̂)."""
    est = unwrap(estimator)
    theta = np.asarray(result.theta, dtype=float)
    K = int(labels.max()) + 1
    G = np.zeros((K, problem.p))
    fallback = result.noise.choice.split(":")[0] if isinstance(est, NoiseModelDM) and result.noise is not None else ""
    if isinstance(est, DualMetric) or fallback == "dm-paper":  # dm that returned its pilot, the paper's optimum
        try:
            d = dual_metric_derivatives(problem, theta, order=2, chunk=chunk)
        except NotPositiveDefinite:
            raise MetricError("uncertainty (dm-paper): M_i(θ̂) is not positive definite at some sample") from None
        for start in range(0, problem.N, chunk):
            rows = slice(start, start + chunk)
            r = problem.Y[rows] @ theta - problem.tau[rows]
            w = np.linalg.solve(problem.metric.evaluate(theta, rows), r[..., None])[..., 0]
            g = 2.0 * np.einsum("nap,na->np", problem.Y[rows], w) - problem.metric.quad(w, rows)
            np.add.at(G, labels[rows], g)
        return d.hess, G, d.f
    if isinstance(est, NoiseModelDM) and result.noise is not None and fallback != "wls":
        return _noise_model_pass(problem.in_sensor_chart(), result, theta, labels, G, chunk)
    chart, W, L = _weights(problem, result, est)
    H, f = _quadratic_pass(chart, W, L, theta, labels, G, chunk)
    if isinstance(est, RegularizedWLS):
        # the per-sample gradients at the data term's own minimiser (one Newton step on the quadratic): there the
        # residuals are the noise, whereas at θ̂ they also carry the prior's systematic pull (fixed design)
        theta_data = theta - pinv_psd(H)[0] @ G.sum(axis=0)
        G[:] = 0.0
        _quadratic_pass(chart, W, L, theta_data, labels, G, chunk)
        H = H + float(result.info["gamma"]) * _regularizer_hessian(est, problem, theta)
    return 0.5 * (H + H.T), G, f


def _noise_model_pass(sensor, result, theta, labels, G, chunk) -> tuple[np.ndarray, np.ndarray, float]:
    """dm's (H, G, f) at θ̂ with its noise model held fixed (module doc), in the sensor chart it was estimated in."""
    S, A = np.asarray(result.noise.sigma_tau), np.asarray(result.noise.sigma_a)
    try:
        d = noise_model_derivatives(sensor, theta, S, A, order=2, chunk=chunk)
    except NotPositiveDefinite:
        raise MetricError("uncertainty (dm): the noise model's covariance is not positive definite") from None
    for start in range(0, sensor.N, chunk):
        rows = slice(start, start + chunk)
        Y = sensor.Y[rows]
        M = sensor.metric.evaluate(theta, rows)
        w = np.linalg.solve(noise_model_covariance(M, S, A), (Y @ theta - sensor.tau[rows])[..., None])[..., 0]
        u = np.einsum("cab,cb->ca", M, w) @ A
        g = 2.0 * np.einsum("nap,na->np", Y, w) - 2.0 * np.einsum("ca,cak->ck", u, sensor.metric.apply(w, rows))
        np.add.at(G, labels[rows], g)
    return 0.5 * (d.hess + d.hess.T), G, d.f


def _quadratic_pass(chart, W, L, theta, labels, G, chunk) -> tuple[np.ndarray, float]:
    """(H = 2 Σ Y_iᵀW_iY_i, f = Σ r_iᵀW_i r_i) at θ; the per-sample gradients 2 Y_iᵀW_i r_i added to G by block."""
    H = np.zeros((chart.p, chart.p))
    f = 0.0
    for start in range(0, chart.N, chunk):
        rows = slice(start, start + chunk)
        Y, r = chart.Y[rows], chart.Y[rows] @ theta - chart.tau[rows]
        if W is None and L is None:  # energy: W_i = v_i v_iᵀ
            e = np.einsum("nap,na->np", Y, chart.v[rows])
            y = np.einsum("na,na->n", r, chart.v[rows])
            H += 2.0 * e.T @ e
            g = 2.0 * e * y[:, None]
            f += float(y @ y)
        else:
            if L is not None:  # whiten: C_i = L_i L_iᵀ
                Y = np.linalg.solve(L[rows], Y)
                r = np.linalg.solve(L[rows], r[..., None])[..., 0]
                WY, Wr = Y, r
            else:
                WY, Wr = np.einsum("ab,nbp->nap", W, Y), r @ W
            H += 2.0 * np.einsum("nap,naq->pq", Y, WY)
            g = 2.0 * np.einsum("nap,na->np", Y, Wr)
            f += float(np.sum(r * Wr))
        np.add.at(G, labels[rows], g)
    return H, f


def _regularizer_hessian(est: RegularizedWLS, problem: IdentificationProblem, theta: np.ndarray) -> np.ndarray:
    """∇²R at θ: logdet Σ_b tr(C_b⁻¹V_k C_b⁻¹V_l) (its trace term is linear); pullback 2 g_b."""
    Hr = np.zeros((problem.p, problem.p))
    for idx, V, C0 in prior_blocks(est.regularizer, problem.parameters, np.asarray(est.theta0)):
        if est.regularizer == "logdet":
            Hb = pullback_metric(V, np.tensordot(theta[idx], V, axes=1))
        else:
            Hb = 2.0 * pullback_metric(V, C0)
        Hr[np.ix_(idx, idx)] += Hb
    return Hr
