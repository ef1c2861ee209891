"""The feasible-GLS dual-metric fit (estimators/gls.py): invariance, closed forms, (Σ, κ) estimation, errors.

Invariance: the problem remembers the chart its forces were measured in (sensor_chart); the
estimator works there, so its fit is the same after any change of coordinates that the problem
records — nonlinear, configuration-dependent charts and unit scalings 1e-6…1e6 alike.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dualid import WLS
from dualid.errors import ConfigError, DataError, DualidError
from dualid.estimators.gls import FeasibleGLS, full_likelihood_estimate, likelihood_estimate, moment_estimate
from dualid.problem import build_problem
from dualid.systems import pan_tilt
from tests.factories import drag_problem, random_chart
from tests.test_invariance import _tilt, charts, rel

FIT = settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow])
seeds = st.integers(0, 2**31 - 1)
MODELS = ("likelihood", "moments")


def unit_chart(rng, n):
    return np.diag(10.0 ** rng.uniform(-6, 6, n))


# --- the problem remembers its sensor chart --------------------------------------------------
def test_in_coordinates_composes_the_sensor_chart_and_returns_to_it():
    rng = np.random.default_rng(1)
    problem, _ = drag_problem(rng, N=20, n=3, noise=0.3)
    assert problem.sensor_chart is None and problem.in_sensor_chart() is problem
    B1, B2 = random_chart(rng, 20, 3, per_sample=True), random_chart(rng, 20, 3, per_sample=False)
    moved = problem.in_coordinates(B1).in_coordinates(B2)
    np.testing.assert_allclose(moved.sensor_chart, B1 @ B2, rtol=1e-13, atol=1e-13)
    back = moved.in_sensor_chart()
    assert back.sensor_chart is None
    for a, b in ((back.Y, problem.Y), (back.tau, problem.tau), (back.v, problem.v)):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10)
    th = rng.uniform(0.5, 2, problem.p)
    np.testing.assert_allclose(back.metric.evaluate(th), problem.metric.evaluate(th), rtol=1e-10, atol=1e-10)
    # subsets and concatenation keep each sample's chart
    np.testing.assert_array_equal(moved.subset([3, 5]).sensor_chart, moved.sensor_chart[[3, 5]])
    both = type(problem).concatenate([problem, moved])
    np.testing.assert_array_equal(both.sensor_chart[:20], np.broadcast_to(np.eye(3), (20, 3, 3)))
    np.testing.assert_array_equal(both.sensor_chart[20:], moved.sensor_chart)


def test_sensor_chart_is_checked():
    rng = np.random.default_rng(0)
    problem, _ = drag_problem(rng, N=5, n=3)
    with pytest.raises(DataError, match="sensor_chart"):
        type(problem)(problem.Y, problem.tau, problem.metric, problem.v, problem.parameters, sensor_chart=np.zeros((5, 3, 3)))
    with pytest.raises(DataError, match="sensor_chart"):
        type(problem)(problem.Y, problem.tau, problem.metric, problem.v, problem.parameters, sensor_chart=np.ones((4, 3, 3)))


# --- invariance ------------------------------------------------------------------------------
@FIT
@given(seeds)
def test_fit_is_the_same_in_every_chart(seed):
    rng = np.random.default_rng(seed)
    problem, _ = drag_problem(rng, N=40, n=3, noise=0.3)
    for model in MODELS:
        est = FeasibleGLS(covariance_model=model)
        base = est.fit(problem)
        cs = charts(rng, problem)
        cs["units_extreme"] = np.diag([1e-6, 1.0, 1e6])
        cs["composed"] = None
        for name, B in cs.items():
            other = (problem.in_coordinates(random_chart(rng, problem.N, 3, True)).in_coordinates(unit_chart(rng, 3))
                     if B is None else problem.in_coordinates(B))
            fit = est.fit(other)
            assert rel(fit.theta, base.theta) < 1e-6, (model, name)
            assert rel(fit.objective, base.objective) < 1e-6, (model, name)
            assert abs(fit.info["kappa"] - base.info["kappa"]) <= 1e-6 * max(base.info["kappa"], 1e-12), (model, name)
        # WLS, which cannot know where the data came from, moves under the per-sample chart
        B = random_chart(rng, problem.N, 3, per_sample=True)
        assert rel(WLS().fit(problem.in_coordinates(B)).theta, WLS().fit(problem).theta) > 1e-3


@pytest.fixture(scope="module")
def pan_tilt_problem():
    model, train, _, _ = pan_tilt.dataset(2, n_train=1, n_test=0, duration=3)
    return build_problem(model, train).subset(slice(0, None, 3))


def test_pan_tilt_nonlinear_charts_and_units(pan_tilt_problem):
    """tilt → sin(tilt), pan → pan + tilt² (configuration dependent), and degrees / 1e-6 / 1e6 units."""
    problem = pan_tilt_problem
    q_tilt = _tilt(problem)
    B_sin = np.zeros((problem.N, 2, 2))
    B_sin[:, 0, 0] = 1.0
    B_sin[:, 1, 1] = 1.0 / np.cos(q_tilt)
    B_mix = np.zeros((problem.N, 2, 2))
    B_mix[:, 0, 0] = B_mix[:, 1, 1] = 1.0
    B_mix[:, 0, 1] = -2.0 * q_tilt
    charts_ = {"sin": B_sin, "mix": B_mix, "degrees": np.diag([np.pi / 180] * 2), "1e-6/1e6": np.diag([1e-6, 1e6])}
    for model in MODELS:
        est = FeasibleGLS(covariance_model=model)
        base = est.fit(problem)
        for name, B in charts_.items():
            fit = est.fit(problem.in_coordinates(B))
            assert rel(fit.theta, base.theta) < 1e-6, (model, name)
            assert rel(fit.objective, base.objective) < 1e-6, (model, name)


# --- closed forms ----------------------------------------------------------------------------
def gls_closed_form(problem, W):
    """θ = (Σ Y_iᵀ W_i Y_i)⁻¹ Σ Y_iᵀ W_i τ_i, W (N, n, n)."""
    H = np.einsum("nap,nab,nbq->pq", problem.Y, W, problem.Y)
    g = np.einsum("nap,nab,nb->p", problem.Y, W, problem.tau)
    return np.linalg.solve(H, g)


def test_kappa_zero_is_wls_with_the_given_sensor_covariance():
    rng = np.random.default_rng(3)
    problem, _ = drag_problem(rng, N=60, n=3, noise=0.3)
    sigma = np.array([0.5, 2.0, 0.1])
    for constrained in (False, True):
        fit = FeasibleGLS(sigma=sigma, kappa=0.0, constrained=constrained).fit(problem)
        wls = WLS(covariance=np.diag(sigma), constrained=constrained).fit(problem)
        assert rel(fit.theta, wls.theta) < 1e-6
    W = np.broadcast_to(np.diag(1 / sigma), (problem.N, 3, 3))
    assert rel(FeasibleGLS(sigma=sigma, kappa=0.0, constrained=False).fit(problem).theta, gls_closed_form(problem, W)) < 1e-9
    # in a re-charted problem the given Σ is still the sensor chart's: the fit does not move
    moved = problem.in_coordinates(random_chart(rng, problem.N, 3, per_sample=True))
    assert rel(FeasibleGLS(sigma=sigma, kappa=0.0).fit(moved).theta, FeasibleGLS(sigma=sigma, kappa=0.0).fit(problem).theta) < 1e-6


def test_sigma_zero_is_the_frozen_metric_fit():
    rng = np.random.default_rng(4)
    problem, theta = drag_problem(rng, N=60, n=3, noise=0.3)
    ref = rng.uniform(0.5, 2.0, problem.p)
    W = np.linalg.inv(problem.metric.evaluate(ref))
    fit = FeasibleGLS(sigma=np.zeros(3), kappa=2.5, theta_ref=ref, constrained=False).fit(problem)
    assert rel(fit.theta, gls_closed_form(problem, W)) < 1e-9
    assert fit.objective == pytest.approx(np.einsum("na,nab,nb->", problem.residual(fit.theta), W / 2.5, problem.residual(fit.theta)), rel=1e-9)


def test_result_records_the_covariance_model_and_the_guard():
    rng = np.random.default_rng(5)
    problem, _ = drag_problem(rng, N=60, n=3, noise=0.3)
    info = FeasibleGLS(select="none").fit(problem).info  # the GLS fit's own record (dm's choice: test_weight_cv)
    assert info["pilot"] == "wls" and info["covariance_model"] == "likelihood" and info["feedback"] is False
    assert len(info["sigma_diag"]) == 3 and info["kappa"] >= 0
    assert 0 < info["metric_ratio_min"] <= 1 <= info["metric_ratio_max"] and info["degenerate"] is False


# --- (Σ, κ) estimation ----------------------------------------------------------------------
@pytest.mark.parametrize("kappa", [0.0, 0.5, 3.0])
def test_sigma_kappa_are_recovered_from_residuals_with_that_covariance(kappa):
    rng = np.random.default_rng(6)
    N, n = 4000, 3
    A = rng.normal(size=(N, n, n))
    M = A @ np.swapaxes(A, 1, 2) / n + 0.1 * np.eye(n)
    sigma = np.array([0.3, 1.0, 2.0])
    C = kappa * M + np.diag(sigma)
    r = np.einsum("nab,nb->na", np.linalg.cholesky(C), rng.normal(size=(N, n)))
    s_ml, k_ml, _ = likelihood_estimate(r, M, 1e-9)
    np.testing.assert_allclose(s_ml, sigma, rtol=0.15, atol=0.05)
    assert k_ml == pytest.approx(kappa, abs=0.1 + 0.1 * kappa)
    s_mm, k_mm = moment_estimate(r, M)
    np.testing.assert_allclose(s_mm, sigma, rtol=0.25, atol=0.1)
    assert k_mm == pytest.approx(kappa, abs=0.2 + 0.2 * kappa)


@pytest.mark.parametrize("kappa", [0.0, 0.5, 3.0])
def test_full_sigma_and_kappa_are_recovered_by_maximum_likelihood(kappa):
    rng = np.random.default_rng(7)
    N, n = 4000, 3
    A = rng.normal(size=(N, n, n))
    M = A @ np.swapaxes(A, 1, 2) / n + 0.1 * np.eye(n)
    R = rng.normal(size=(n, n))
    sigma = R @ R.T / n + 0.2 * np.eye(n)  # correlated sensor covariance
    C = kappa * M + sigma
    r = np.einsum("nab,nb->na", np.linalg.cholesky(C), rng.normal(size=(N, n)))
    S, k, info = full_likelihood_estimate(r, M, 1e-9)
    np.testing.assert_allclose(S, sigma, atol=0.1 + 0.05 * kappa)
    assert k == pytest.approx(kappa, abs=0.1 + 0.1 * kappa)
    assert np.allclose(S, S.T) and np.linalg.eigvalsh(S)[0] > 0
    # never below the κ = 0 model (the sample covariance), which is one of its starts
    assert info["sigma_kappa_nll"] <= info["sigma_kappa_kappa0"]["nll"] + 1e-12
    # the diagonal model cannot represent the correlation: it recovers neither Σ's off-diagonal nor κ as well
    s_d, k_d, _ = likelihood_estimate(r, M, 1e-9)
    assert np.max(np.abs(S - sigma)) < np.max(np.abs(np.diag(s_d) - sigma))


def test_full_sigma_is_the_default_and_carries_the_correlation_of_the_residuals():
    """Joint-correlated sensor noise: the default full Σ̂ has the correlation, the diagonal model none."""
    rng = np.random.default_rng(8)
    problem, _ = drag_problem(rng, N=400, n=3, noise=0.0)
    Lc = np.array([[1.0, 0, 0], [0.9, 0.4, 0], [0.5, -0.3, 0.2]])
    noisy = type(problem)(problem.Y, problem.tau + rng.normal(size=(400, 3)) @ Lc.T * 0.05, problem.metric,
                          problem.v, problem.parameters)
    res = FeasibleGLS(select="none").fit(noisy)  # the GLS fit's own Σ (dm's choice: test_weight_cv)
    assert res.info["sigma_structure"] == "full"
    S = np.array(res.info["sigma"])
    assert abs(S[0, 1]) > 0.3 * np.sqrt(S[0, 0] * S[1, 1])  # the correlation is in the model
    diag = FeasibleGLS(sigma_structure="diagonal", select="none").fit(noisy)  # the GLS fit's own Σ (no choice)
    assert diag.info["sigma_structure"] == "diagonal" and np.count_nonzero(np.array(diag.info["sigma"]) - np.diag(diag.info["sigma_diag"])) == 0


# --- value type and errors -------------------------------------------------------------------
def test_estimator_is_a_hashable_value():
    a = FeasibleGLS(sigma=np.array([1.0, 2.0]), kappa=0, solver_options={"max_iter": 50})
    b = FeasibleGLS(sigma=[1.0, 2.0], kappa=0.0, solver_options={"max_iter": 50})
    assert a == b and hash(a) == hash(b) and len({a, b, FeasibleGLS()}) == 2
    assert FeasibleGLS().name == "dm"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"pilot": "nls"}, "pilot"),
        ({"covariance_model": "ml"}, "covariance_model"),
        ({"sigma_structure": "block"}, "sigma_structure"),
        ({"sigma": [1.0, 1.0], "kappa": -1.0}, "kappa"),
        ({"sigma": [1.0, 1.0], "kappa": float("nan")}, "kappa"),
        ({"sigma": [1.0, 1.0], "kappa": True}, "kappa"),
        ({"sigma": [1.0, -1.0], "kappa": 0.0}, "sigma"),
        ({"sigma": [[1.0, 2.0], [2.0, 1.0]], "kappa": 0.0}, "sigma"),
        ({"sigma": np.ones((2, 3)), "kappa": 0.0}, "sigma"),
        ({"sigma": [1.0, 1.0]}, "sigma and kappa"),
        ({"kappa": 1.0}, "sigma and kappa"),
        ({"theta_ref": [1.0, float("inf")]}, "theta_ref"),
        ({"sigma_floor": 0.0}, "sigma_floor"),
        ({"guard_bound": 1.0}, "guard_bound"),
    ],
)
def test_constructor_errors(kwargs, match):
    with pytest.raises(ConfigError, match=match):
        FeasibleGLS(**kwargs)
    assert issubclass(ConfigError, DualidError)


def test_fit_time_shape_errors():
    rng = np.random.default_rng(7)
    problem, _ = drag_problem(rng, N=30, n=3, noise=0.3)
    with pytest.raises(ConfigError, match="theta_ref"):
        FeasibleGLS(theta_ref=np.ones(4)).fit(problem)
    with pytest.raises(ConfigError, match="sigma"):
        FeasibleGLS(sigma=np.ones(2), kappa=0.0).fit(problem)


def test_newton_and_cvxpy_paths_agree():
    rng = np.random.default_rng(8)
    problem, _ = drag_problem(rng, N=60, n=3, noise=0.3)
    for kw in ({}, {"sigma": np.array([0.5, 2.0, 0.1]), "kappa": 0.7, "theta_ref": rng.uniform(0.5, 2, 9)}):
        newton = FeasibleGLS(**kw).fit(problem)
        cvx = FeasibleGLS(solver="CLARABEL", **kw).fit(problem)
        assert newton.solver == "newton" and cvx.solver == "CLARABEL"
        if not kw:  # the pilot is dualid's Newton fit whatever the solver, and the label says so to a Clarabel user
            assert (newton.info["pilot"], cvx.info["pilot"]) == ("wls", "wls (by dualid's Newton method on the closed set)")
        assert rel(newton.theta, cvx.theta) < 1e-5
        assert rel(newton.objective, cvx.objective) < 1e-7
    with pytest.raises(ConfigError, match="solver"):
        FeasibleGLS(solver="MOSEK")
