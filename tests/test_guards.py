"""The metric guard (metric_guard.py; evaluation/guards.py): generalised eigenvalues of M_i(θ̂) against M_i(θ_ref)."""

import numpy as np
import pytest
import scipy.linalg

from dualid import OLS, WLS, DualMetric
from dualid.errors import ConfigError, MetricError
from dualid.evaluation.guards import Guarded, with_guard
from dualid.metric_guard import DEFAULT_BOUND, generalized_eigenvalues, guard_info
from tests.factories import drag_problem, random_chart
from tests.test_newton import crazyflie_like, rigid_body_problem


def test_generalized_eigenvalues_match_scipy_and_every_chart():
    rng = np.random.default_rng(0)
    problem, theta = drag_problem(rng, N=30, n=3, noise=0.3)
    other = rng.uniform(0.1, 5.0, problem.p)
    lam = generalized_eigenvalues(problem, other, theta)
    M, M_ref = problem.metric.evaluate(other), problem.metric.evaluate(theta)
    ref = np.stack([scipy.linalg.eigh(M[i], M_ref[i], eigvals_only=True) for i in range(problem.N)])
    np.testing.assert_allclose(lam, ref, rtol=1e-10)
    for B in (random_chart(rng, problem.N, 3, True), np.diag([1e-6, 1.0, 1e6])):
        np.testing.assert_allclose(generalized_eigenvalues(problem.in_coordinates(B), other, theta), lam, rtol=1e-8)


@pytest.fixture(scope="module")
def crazyflie_problem():
    return rigid_body_problem(crazyflie_like(), 120, seed=1, noise=0.02)


def test_a_massless_pendulum_is_flagged_and_the_truth_is_not(crazyflie_problem):
    problem, theta = crazyflie_problem
    wls = WLS(allow_unidentifiable=True).fit(problem)
    truth = guard_info(problem, theta, wls.theta)
    assert not truth["degenerate"] and 1 / DEFAULT_BOUND < truth["metric_ratio_min"] <= truth["metric_ratio_max"] < DEFAULT_BOUND
    ghost = theta.copy()
    ghost[20:30] *= 1e-8  # the pendulum (third body) made massless: the Crazyflie DM ghost
    info = guard_info(problem, ghost, wls.theta)
    assert info["degenerate"] and info["metric_ratio_min"] < 1e-6
    blown = theta.copy()
    blown[20:30] *= 1e3
    assert guard_info(problem, blown, wls.theta)["degenerate"]


def test_guard_travels_with_any_estimator(crazyflie_problem):
    problem, theta = crazyflie_problem
    est = Guarded(OLS(allow_unidentifiable=True), reference=theta)
    assert est == Guarded(OLS(allow_unidentifiable=True), reference=list(theta)) and hash(est)
    result = est.fit(problem)
    assert result.info["degenerate"] is False and result.info["metric_guard_reference"] == "given θ_ref"
    result = Guarded(DualMetric(allow_unidentifiable=True)).fit(problem)
    assert result.info["metric_guard_reference"] == "wls" and "metric_ratio_min" in result.info
    moved = with_guard(result, problem, theta * 1e-6, reference="scaled")
    assert moved.info["degenerate"] and moved.info["metric_ratio_min"] > 1e5
    assert "degenerate" not in result.info or result.info is not moved.info


def test_singular_reference_and_bad_bound_are_errors(crazyflie_problem):
    problem, theta = crazyflie_problem
    massless = theta.copy()
    massless[20:30] = 0.0
    with pytest.raises(MetricError, match="reference metric"):
        guard_info(problem, theta, massless)
    with pytest.raises(ConfigError, match="bound: expected a finite number > 1"):
        guard_info(problem, theta, theta, bound=0.5)
    with pytest.raises(ConfigError, match="Guarded: estimator must have a fit"):
        Guarded(object())
