"""The weighted Newton fit argmin Σ r_iᵀ C⁻¹ r_i for one constant C (estimators/newton/weighted.py: OLS, WLS and the
closed-set fits of ``quadratic_fit.closed_fit``): against the conic reference on the whitened problem, C factored once
per fit, a typed error for a C that is not positive definite, and no arrays in its info (the iterates' diverging
direction by parameter name)."""

import json

import numpy as np
import pytest

from dualid.errors import MetricError
from dualid.estimators.newton import weighted
from dualid.estimators.newton.weighted import fit_weighted_newton, weighted_objective, whitener
from dualid.estimators.quadratic_fit import fit_weighted
from tests.factories import drag_problem
from tests.test_invariance import rel


def _spd(rng, n):
    A = rng.standard_normal((n, n))
    return A @ A.T + n * np.eye(n)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_weighted_fit_is_the_conic_fit_of_the_whitened_problem(seed):
    rng = np.random.default_rng(seed)
    problem, _ = drag_problem(rng, N=300, n=3, noise=0.3)
    C = _spd(rng, problem.n)
    common = {"constrained": True, "solver": "newton", "solver_options": {}, "allow_unidentifiable": False}
    newton = fit_weighted(problem, C, "wls", common, {})
    conic = fit_weighted(problem, C, "wls", {**common, "solver": "CLARABEL"}, {})
    assert rel(problem.Y @ newton.theta, problem.Y @ conic.theta) < 1e-6
    assert newton.objective <= conic.objective * (1 + 1e-9)
    r = problem.residual(newton.theta)  # the objective is Σ r_iᵀ C⁻¹ r_i at θ̂ (independent: a dense solve)
    assert newton.objective == pytest.approx(float(np.sum(r * np.linalg.solve(C, r.T).T)), rel=1e-12)
    assert weighted_objective(problem, whitener(problem, C), newton.theta, chunk=50) == pytest.approx(
        newton.objective, rel=1e-12)


def test_the_constant_weight_is_factored_once_per_fit(monkeypatch):
    shapes, real = [], np.linalg.cholesky

    def spy(a, *args, **kwargs):
        shapes.append(np.shape(a))
        return real(a, *args, **kwargs)

    monkeypatch.setattr(np.linalg, "cholesky", spy)
    rng = np.random.default_rng(3)
    problem, _ = drag_problem(rng, N=500, n=3, noise=0.3)
    fit_weighted_newton(problem, _spd(rng, problem.n), chunk=64)  # 8 blocks, two passes
    assert shapes.count((problem.n, problem.n)) == 1  # the LMI blocks of drag_problem are 4×4 (n = 3)
    assert not [s for s in shapes if len(s) == 3 and s[1:] == (problem.n, problem.n) and s[0] > 1]


def test_a_weight_not_positive_definite_names_every_sample():
    problem, _ = drag_problem(np.random.default_rng(5), N=40, n=3)
    with pytest.raises(MetricError) as err:
        fit_weighted_newton(problem, np.diag([1.0, -2.0, 3.0]), what="the test weight")
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
    result = fit_weighted_newton(problem, np.eye(3))
    assert result.info["diverging_candidate"] == [names[5], names[2]]
    assert result.info["diverging_direction"] == f"-0.800·{names[5]} +0.600·{names[2]}"
    json.dumps(result.info)  # JSON-friendly: no arrays
