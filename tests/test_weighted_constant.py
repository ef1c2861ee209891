"""A constant weight in the weighted Newton fit (estimators/newton/weighted.py) is factored once.

dm's OLS and WLS pilots, and its final fit when κ = 0, minimise Σ r_iᵀ C⁻¹ r_i with one C for every sample;
the weight then returns a single (1, n, n) block. The fit must whiten with one Cholesky of C (not one per sample
and pass: 8.87 → 13.96 s for dm at N = 10⁶ on the benchmark Crazyflie), give the same θ̂ and objective as the
per-sample path, and record which path ran (info["weight"]). Also: the weighted fit's info carries no arrays (the
iterates' diverging direction by parameter name).
"""

import json

import numpy as np
import pytest

from dualid.errors import MetricError
from dualid.estimators.least_squares import residual_covariance
from dualid.estimators.newton import weighted
from dualid.estimators.newton.weighted import fit_weighted_newton, weighted_objective
from dualid.estimators.quadratic_fit import fit_weighted
from tests.factories import drag_problem
from tests.test_invariance import rel


def _spd(rng, n):
    A = rng.standard_normal((n, n))
    return A @ A.T + n * np.eye(n)


@pytest.fixture
def cholesky_calls(monkeypatch):
    """Every np.linalg.cholesky argument's shape during the test."""
    shapes, real = [], np.linalg.cholesky

    def spy(a, *args, **kwargs):
        shapes.append(np.shape(a))
        return real(a, *args, **kwargs)

    monkeypatch.setattr(np.linalg, "cholesky", spy)
    return shapes


def _batched(shapes, n):
    """Per-sample factorisations of (c, n, n) weights (the dual-metric passes' shape), c > 1."""
    return [s for s in shapes if len(s) == 3 and s[1:] == (n, n) and s[0] > 1]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_constant_weight_gives_the_per_sample_fit(seed):
    rng = np.random.default_rng(seed)
    problem, _ = drag_problem(rng, N=300, n=3, noise=0.3)
    C = _spd(rng, problem.n)
    one = fit_weighted_newton(problem, lambda block, rows: C[None], chunk=64)
    each = fit_weighted_newton(problem, lambda block, rows: np.broadcast_to(C, (len(range(block.N)[rows]), 3, 3)),
                               chunk=64)
    assert one.info["weight"] == "constant" and each.info["weight"] == "per-sample"
    assert rel(one.theta, each.theta) < 1e-10
    assert abs(one.objective - each.objective) <= 1e-10 * each.objective
    # and the objective is Σ r_iᵀ C⁻¹ r_i at θ̂ (independent: a dense solve)
    r = problem.residual(one.theta)
    assert one.objective == pytest.approx(float(np.sum(r * np.linalg.solve(C, r.T).T)), rel=1e-12)


def test_constant_weight_is_factored_once_per_fit(cholesky_calls):
    rng = np.random.default_rng(3)
    problem, _ = drag_problem(rng, N=500, n=3, noise=0.3)
    C = _spd(rng, problem.n)
    result = fit_weighted_newton(problem, lambda block, rows: C[None], chunk=64)  # 8 blocks, two passes
    assert result.info["weight"] == "constant"
    assert _batched(cholesky_calls, problem.n) == []
    assert cholesky_calls.count((problem.n, problem.n)) == 1  # the LMI blocks of drag_problem are 4×4 (n = 3)
    cholesky_calls.clear()
    fit_weighted_newton(problem, lambda block, rows: np.broadcast_to(C, (len(range(block.N)[rows]), 3, 3)), chunk=64)
    assert len(_batched(cholesky_calls, problem.n)) == 2 * 8  # the per-sample path: every block of both passes


def test_a_changing_constant_is_refactored():
    """A weight that returns a different (1, n, n) block per block of rows is still right (factored per change)."""
    rng = np.random.default_rng(4)
    problem, _ = drag_problem(rng, N=200, n=3, noise=0.3)
    C1, C2 = _spd(rng, 3), _spd(rng, 3)

    def by_block(block, rows):
        return C1[None] if rows.start < 100 else C2[None]

    def per_sample(block, rows):
        idx = np.arange(block.N)[rows]
        return np.where((idx < 100)[:, None, None], C1, C2)

    theta = rng.uniform(0.5, 2.0, problem.p)
    f_one = weighted_objective(problem, by_block, theta, chunk=50)
    f_each = weighted_objective(problem, per_sample, theta, chunk=50)
    assert f_one == pytest.approx(f_each, rel=1e-12)


def test_constant_weight_not_positive_definite_names_every_sample():
    rng = np.random.default_rng(5)
    problem, _ = drag_problem(rng, N=40, n=3)
    C = np.diag([1.0, -2.0, 3.0])
    with pytest.raises(MetricError) as err:
        fit_weighted_newton(problem, lambda block, rows: C[None], what="the test weight")
    assert str(err.value) == ("the test weight must be positive definite at every sample, but it is not at 40 of 40 "
                              "samples (smallest eigenvalue -2); give a positive-definite Σ or a pilot with a "
                              "positive-definite metric")


def test_weighted_info_names_the_diverging_direction(monkeypatch):
    """The interior point's candidate direction (an array over θ) reaches result.info as parameter names."""
    rng = np.random.default_rng(7)
    problem, _ = drag_problem(rng, N=100, n=3, noise=0.3)
    names = problem.parameters.names
    real = weighted.run_interior_point

    def with_candidate(*args, **kwargs):
        theta, Z, z, info = real(*args, **kwargs)
        d = np.zeros(problem.p)
        d[[2, 5]] = [0.6, -0.8]
        info.update(diverging_candidate=d, optimum_at_infinity=True, diverging_direction=d)
        return theta, Z, z, info

    monkeypatch.setattr(weighted, "run_interior_point", with_candidate)
    result = fit_weighted_newton(problem, lambda block, rows: np.eye(3)[None])
    assert result.info["diverging_candidate"] == [names[5], names[2]]
    assert result.info["diverging_direction"] == f"-0.800·{names[5]} +0.600·{names[2]}"
    json.dumps(result.info)  # JSON-friendly: no arrays


@pytest.mark.parametrize("constant", [True, False])
def test_the_weight_is_evaluated_once_per_block_and_pass(constant):
    """Two passes (statistics, objective), each evaluating C_i once per block (Σ + κ M_i(θ_ref) costs a metric
    evaluation per sample)."""
    rng = np.random.default_rng(8)
    problem, _ = drag_problem(rng, N=500, n=3, noise=0.3)
    C, calls = _spd(rng, 3), []

    def weight(block, rows):
        calls.append(rows)
        return C[None] if constant else np.broadcast_to(C, (len(range(block.N)[rows]), 3, 3))

    fit_weighted_newton(problem, weight, chunk=64)
    assert len(calls) == 2 * 8
