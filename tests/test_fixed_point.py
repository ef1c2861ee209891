"""The bounded fixed point (estimators/fixed_point.py): limits, invariance, errors."""

import dataclasses

import numpy as np
import pytest

from dualid import WLS
from dualid.errors import ConfigError
from dualid.estimators.fixed_point import BoundedFixedPoint
from dualid.estimators.gls import FeasibleGLS
from tests.factories import drag_problem, random_chart
from tests.test_invariance import rel


def test_bound_one_is_the_frozen_pilot_metric_fit():
    rng = np.random.default_rng(0)
    problem, _ = drag_problem(rng, N=60, n=3, noise=0.3)
    pilot = WLS().fit(problem).theta
    frozen = FeasibleGLS(sigma=np.zeros(3), kappa=1.0, theta_ref=pilot).fit(problem)
    fit = BoundedFixedPoint(bound=1.0).fit(problem)
    assert rel(fit.theta, frozen.theta) < 1e-6
    assert fit.info["converged"]


def test_fixed_point_is_invariant_and_stays_inside_its_bound():
    rng = np.random.default_rng(1)
    problem, _ = drag_problem(rng, N=60, n=3, noise=0.3)
    est = BoundedFixedPoint(bound=3.0)
    base = est.fit(problem)
    for B in (random_chart(rng, problem.N, 3, True), np.diag([1e-6, 1.0, 1e6])):
        assert rel(est.fit(problem.in_coordinates(B)).theta, base.theta) < 1e-6
    assert base.info["feedback"] == "bounded" and not base.info["degenerate"]


@pytest.mark.parametrize("kwargs", [{"bound": 0.5}, {"damping": 0.0}, {"damping": 1.5}, {"max_iter": 0},
                                    {"max_iter": 2.5}, {"tol": -1.0}, {"pilot": "x"},
                                    {"warm_start_samples": -1}, {"warm_start_samples": 1.5},
                                    {"warm_start_samples": True}])
def test_constructor_errors(kwargs):
    with pytest.raises(ConfigError):
        BoundedFixedPoint(**kwargs)
    assert BoundedFixedPoint() == BoundedFixedPoint() and hash(BoundedFixedPoint())


def test_subsample_warm_start_reaches_the_cold_fixed_point():
    # N > 4 × warm_start_samples: the damped outer iterations on every 20th sample, then all samples from there;
    # residuals shaped by another θ's metric, so the fixed point moves off the OLS pilot and the bound clips
    rng = np.random.default_rng(2)
    problem, theta = drag_problem(rng, N=2000, n=3, theta=np.array([0.05, 1, 1, 1, 1, 1, 1, 1, 1.0]))
    other = theta.copy()
    other[0] = 3.0
    L = np.linalg.cholesky(problem.metric.evaluate(other))
    problem = dataclasses.replace(problem, tau=problem.tau + 3.0 * np.einsum("nab,nb->na", L, rng.standard_normal((2000, 3))))
    cold = BoundedFixedPoint(bound=1.05, pilot="ols", warm_start_samples=0).fit(problem)
    warm = BoundedFixedPoint(bound=1.05, pilot="ols", warm_start_samples=100).fit(problem)
    assert "warm_start_samples" not in cold.info and cold.info["converged"] and cold.info["clipped_fraction"] > 0.1
    assert warm.info["warm_start_samples"] == 100 and warm.info["converged"] and warm.info["converged_subsample"]
    assert warm.info["iterations_outer"] == warm.info["iterations_outer_full"] < cold.info["iterations_outer"]
    assert warm.info["iterations_outer_subsample"] >= 2 and warm.info["damping_full"] == 1.0
    assert abs(warm.info["clipped_fraction"] - cold.info["clipped_fraction"]) < 0.01
    assert rel(warm.theta, cold.theta) < 1e-5  # both stop at steps < tol = 1e-5 from opposite sides
    assert abs(warm.objective - cold.objective) < 1e-5 * cold.objective
    # the reported objective (computed in the pencil pass) is Σ r_iᵀ M̄_i⁻¹ r_i with M̄_i the clipped pencil: against
    # scipy's generalised eigenproblem at θ̂ (the last fit's weight is one step < tol older)
    from scipy.linalg import eigh

    from dualid.estimators.least_squares import OLS

    ref = OLS().fit(problem).theta  # the pilot by another solver: Clarabel, certified (the pilot is Newton's; ~1e-10)
    M, M_ref, r = problem.metric.evaluate(warm.theta), problem.metric.evaluate(ref), problem.residual(warm.theta)
    f = 0.0
    for i in range(problem.N):
        lam, V = eigh(M[i], M_ref[i])  # Vᵀ M_ref V = I, Vᵀ M V = Λ: M̄⁻¹ = V clip(Λ)⁻¹ Vᵀ
        f += float(np.sum((V.T @ r[i]) ** 2 / np.clip(lam, 1 / 1.05, 1.05)))
    assert abs(warm.objective - f) < 1e-4 * f and abs(cold.objective - f) < 1e-4 * f
    # the guard's ratios come from the last pencil pass: those of guard_info at θ̂ against the pilot
    from dualid.estimators.metric_guard import guard_info

    guard = guard_info(problem, warm.theta, ref, 100.0, "pilot (ols)")
    for key in ("metric_ratio_min", "metric_ratio_max"):
        assert abs(warm.info[key] - guard[key]) < 1e-8  # the two pilots differ by ~1e-10 (their solvers' tolerance)
    assert warm.info["degenerate"] == guard["degenerate"]
    # invariant as the cold fit (the subsample is the same samples in every chart)
    for B in (random_chart(rng, problem.N, 3, True), np.diag([1e-6, 1.0, 1e6])):
        moved = BoundedFixedPoint(bound=1.05, pilot="ols", warm_start_samples=100).fit(problem.in_coordinates(B))
        assert rel(moved.theta, warm.theta) < 1e-6
    # no warm start at or below 4 × warm_start_samples
    assert "warm_start_samples" not in BoundedFixedPoint(bound=1.05, pilot="ols", warm_start_samples=500).fit(problem).info
