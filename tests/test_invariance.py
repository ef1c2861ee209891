"""Coordinate invariance: under q = φ(q̃), B = ∂φ/∂q̃, τ̃ = Bᵀτ, Ỹ = BᵀY, M̃ = BᵀMB.

- the dual-metric objective and minimiser are the same in every chart, unit and scaling;
- the energy objective too; covariance-WLS only under constant linear changes; OLS in none.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dualid import OLS, WLS, DualMetric, EnergyLS
from dualid.problem import build_problem
from dualid.systems import pan_tilt
from tests.factories import drag_problem, random_chart

FIT = settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
seeds = st.integers(0, 2**31 - 1)


def charts(rng, problem):
    """A constant linear change, a configuration-dependent one, and a unit scaling over 1e-6..1e6."""
    N, n = problem.N, problem.n
    scaling = np.diag(10.0 ** rng.uniform(-6, 6, n))
    return {
        "constant": random_chart(rng, N, n, per_sample=False),
        "per_sample": random_chart(rng, N, n, per_sample=True),
        "units": scaling,
    }


def rel(a, b):
    return np.linalg.norm(np.asarray(a) - np.asarray(b)) / max(np.linalg.norm(b), 1e-300)


@settings(max_examples=25, deadline=None)
@given(seeds)
def test_dual_metric_and_energy_objectives_are_the_same_in_every_chart(seed):
    rng = np.random.default_rng(seed)
    problem, theta = drag_problem(rng, N=15, n=3, noise=0.3)
    for name, B in charts(rng, problem).items():
        other = problem.in_coordinates(B)
        for th in (theta, rng.uniform(0.1, 3.0, problem.p)):
            assert rel(other.dual_metric_objective(th), problem.dual_metric_objective(th)) < 1e-9, name
            e, e_other = (np.einsum("na,na->n", q.v, q.residual(th)) for q in (problem, other))
            assert rel(e_other, e) < 1e-9, name


@FIT
@given(seeds)
def test_dual_metric_minimiser_is_the_same_in_every_chart_while_ols_moves(seed):
    rng = np.random.default_rng(seed)
    problem, _ = drag_problem(rng, N=40, n=3, noise=0.3)
    dm = DualMetric(solver="newton").fit(problem)
    ols = OLS().fit(problem)
    for name, B in charts(rng, problem).items():
        other = problem.in_coordinates(B)
        dm_other = DualMetric(solver="newton").fit(other)
        assert rel(dm_other.theta, dm.theta) < 1e-6, name
        assert rel(dm_other.objective, dm.objective) < 1e-6, name
    # OLS moves under a change of units (a random chart may be close to a multiple of a rotation, which it does not see)
    units = problem.in_coordinates(np.diag([1e3, 1.0, 1e-3]))
    assert rel(OLS().fit(units).theta, ols.theta) > 1e-3


@settings(max_examples=3, deadline=None)
@given(seeds)
def test_the_sdp_reference_is_invariant_to_its_accuracy(seed):
    """The interior-point SDP stops at a relative gap of ~1e-10: θ agrees to ~1e-5 on a flat optimum."""
    rng = np.random.default_rng(seed)
    problem, _ = drag_problem(rng, N=40, n=3, noise=0.3)
    dm = DualMetric(solver="cvxpy").fit(problem)
    for name, B in charts(rng, problem).items():
        other = DualMetric(solver="cvxpy").fit(problem.in_coordinates(B))
        assert rel(other.objective, dm.objective) < 1e-6, name
        assert rel(other.theta, dm.theta) < 1e-4, name


@FIT
@given(seeds)
def test_energy_minimiser_is_the_same_in_every_chart(seed):
    rng = np.random.default_rng(seed)
    problem, _ = drag_problem(rng, N=40, n=3, noise=0.3)
    energy = EnergyLS().fit(problem)
    for name, B in charts(rng, problem).items():
        other = EnergyLS().fit(problem.in_coordinates(B))
        assert rel(other.theta, energy.theta) < 1e-6, name
        assert rel(other.objective, energy.objective) < 1e-6, name


@FIT
@given(seeds)
def test_covariance_wls_is_invariant_only_under_constant_linear_changes(seed):
    rng = np.random.default_rng(seed)
    problem, _ = drag_problem(rng, N=40, n=3, noise=0.3)
    sigma = np.diag(rng.uniform(0.5, 2.0, 3))
    wls = WLS(covariance=sigma).fit(problem)
    B = random_chart(rng, problem.N, 3, per_sample=False)
    moved = WLS(covariance=B.T @ sigma @ B).fit(problem.in_coordinates(B))  # Σ̃ = BᵀΣB
    assert rel(moved.theta, wls.theta) < 1e-6
    B_i = random_chart(rng, problem.N, 3, per_sample=True)
    assert rel(WLS(covariance=sigma).fit(problem.in_coordinates(B_i)).theta, wls.theta) > 1e-3


@pytest.fixture(scope="module")
def pan_tilt_problem():
    model, train, _, _ = pan_tilt.dataset(2, n_train=1, n_test=0, duration=3)
    return build_problem(model, train).subset(slice(0, None, 3))


def test_pan_tilt_nonlinear_reparameterizations(pan_tilt_problem):
    """Real charts of the pan–tilt: tilt → sin(tilt), and pan → pan + tilt² (configuration dependent)."""
    problem = pan_tilt_problem
    q_tilt = _tilt(problem)
    B_sin = np.zeros((problem.N, 2, 2))  # q = (ψ̃, arcsin s̃): ∂q/∂q̃ = diag(1, 1/cos φ)
    B_sin[:, 0, 0] = 1.0
    B_sin[:, 1, 1] = 1.0 / np.cos(q_tilt)
    B_mix = np.zeros((problem.N, 2, 2))  # q = (ψ̃ − φ̃², φ̃): ∂q/∂q̃ = [[1, −2φ], [0, 1]]
    B_mix[:, 0, 0] = B_mix[:, 1, 1] = 1.0
    B_mix[:, 0, 1] = -2.0 * q_tilt
    B_deg = np.diag([np.pi / 180, np.pi / 180])  # angles in degrees
    dm, ols = DualMetric(solver="newton").fit(problem), OLS().fit(problem)
    for name, B in {"sin": B_sin, "mix": B_mix, "degrees": B_deg}.items():
        other = problem.in_coordinates(B)
        dm_other = DualMetric(solver="newton").fit(other)
        assert rel(dm_other.theta, dm.theta) < 1e-6, name
        assert rel(dm_other.objective, dm.objective) < 1e-6, name
        if name != "degrees":  # a uniform scale of all coordinates leaves OLS unchanged too
            # |tilt| < 0.7 rad here, so the chart is mild; OLS still moves ~1e9× more than DM
            assert rel(OLS().fit(other).theta, ols.theta) > 1e-4, name


def _tilt(problem):
    """The tilt angle at each sample, recovered from the metric: M = m L² diag(cos²φ, 1)."""
    M = problem.metric.evaluate(np.array([1.0, 0.0, 0.0]))
    return np.arccos(np.sqrt(np.clip(M[:, 0, 0] / M[:, 1, 1], 0, 1)))


def test_dual_metric_picks_the_same_point_of_a_non_unique_optimum_in_every_chart():
    """With a null space (floating base: mass can move between bodies) the optimum is a face; the
    Newton solver starts from chart-invariant estimates, so it returns the same θ in every chart."""
    from tests.test_newton import crazyflie_like, rigid_body_problem

    problem, _ = rigid_body_problem(crazyflie_like(), 80, seed=3, noise=0.05)
    assert problem.identifiability().rank < problem.p
    rng = np.random.default_rng(0)
    base = DualMetric(allow_unidentifiable=True).fit(problem)
    for name, B in charts(rng, problem).items():
        other = DualMetric(allow_unidentifiable=True).fit(problem.in_coordinates(B))
        # along the flat face only the barrier holds θ, so rounding moves it ~1e-6 (an OLS start: ~1e-2)
        assert rel(other.theta, base.theta) < 1e-5, name


@settings(max_examples=4, deadline=None)
@given(seeds)
def test_sdp_and_newton_agree_to_1e6_in_every_chart(seed):
    """Both DM solvers, every chart (incl. units over 1e-6…1e6): the same objective and predictions Yθ to 1e-6.
    The SDP works in a chart whitened at a chart-invariant point with a residual-sized slack scale."""
    rng = np.random.default_rng(seed)
    problem, _ = drag_problem(rng, N=40, n=3, noise=0.3)
    newton = DualMetric(solver="newton").fit(problem)
    for name, B in {"identity": np.eye(problem.n), **charts(rng, problem)}.items():
        other = problem.in_coordinates(B)
        sdp = DualMetric(solver="cvxpy", fallback=()).fit(other)
        assert sdp.status == "optimal", name
        assert rel(sdp.objective, newton.objective) < 1e-6, name
        assert rel(other.Y @ sdp.theta, other.Y @ newton.theta) < 1e-6, name
