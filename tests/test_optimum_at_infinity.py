"""The dual-metric objective whose infimum is at infinity (DFKI Joint1's mass): flagged, not silent."""

import warnings
from pathlib import Path

import numpy as np
import pytest

from dualid.errors import OptimumAtInfinityWarning, SolverError
from dualid.estimators.dual_metric import DualMetric
from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.parameters import ParameterBlock, ParameterSpace
from dualid.problem import IdentificationProblem


def _problem(identifiable_mass: bool, loose: bool = True) -> IdentificationProblem:
    """n = 1, θ = (a, m): τ_i = a y_i (+ m z_i) + noise. On the samples of group A the metric is M_i = m (a mass
    that loosens without bound), on group B a constant 1. With z = 0 the mass does not enter the forces, so
    f = S_A(a)/m + S_B(a) falls toward S_B as m → ∞: the infimum is at infinity. With z ≠ 0 it is finite."""
    rng = np.random.default_rng(0)
    N = 400
    y = rng.normal(size=N)
    z = rng.normal(size=N) if identifiable_mass else np.zeros(N)
    tau = 2.0 * y + 0.5 * z + 0.1 * rng.normal(size=N)
    group_a = np.arange(N) < N // 2 if loose else np.ones(N, bool)
    J = group_a.astype(float)[:, None, None]  # M_i = J_i² m + M0_i
    M0 = (~group_a).astype(float)[:, None, None]
    metric = AffineMetric(2, (MetricTerm((1,), np.ones((1, 1, 1)), J),), M0)
    space = ParameterSpace(("a", "m"), ("N", "kg"), (ParameterBlock("body", "nonnegative", (1,)),))
    return IdentificationProblem(np.stack([y, z], axis=1)[:, None, :], tau[:, None], metric, np.ones((N, 1)), space)


def test_the_flag_fires_where_the_objective_keeps_falling_as_the_mass_grows():
    problem = _problem(identifiable_mass=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = DualMetric(solver="newton", fallback=(), allow_unidentifiable=True, tol=1e-6).fit(problem)
    assert result.info["optimum_at_infinity"] is True
    assert result.info["diverging_direction"].startswith("+1.000·m")  # the mass, growing
    assert result.theta[1] > 1e3 * abs(result.theta[0])  # stopped far out on the ray
    assert "OptimumAtInfinityWarning" in result.info["solver_warnings"]  # recorded in the result, not printed
    assert not [w for w in caught if issubclass(w.category, OptimumAtInfinityWarning)]
    # the decrease is real: further out along the direction the objective is lower still
    farther = result.theta + np.array([0.0, 10 * result.theta[1]])
    assert problem.dual_metric_objective(farther) < result.objective


def test_no_flag_at_a_finite_optimum():
    result = DualMetric(solver="newton", fallback=(), tol=1e-6).fit(_problem(identifiable_mass=True))
    assert result.info["optimum_at_infinity"] is False
    assert "diverging_direction" not in result.info


def test_a_pure_ray_with_no_floor_is_an_error_naming_the_cause():
    # every sample's metric is the mass: f = S(a)/m → 0, Newton never meets its relative tolerance
    problem = _problem(identifiable_mass=False, loose=False)
    with pytest.raises(SolverError, match="the objective keeps decreasing while θ grows without bound") as info:
        DualMetric(solver="newton", allow_unidentifiable=True, max_iter=60).fit(problem)
    assert info.value.status == "optimum_at_infinity"


@pytest.mark.skipif(not (Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data").is_dir(),
                    reason="the DFKI example data are not present")
def test_dfki_joint1_mass_is_flagged_and_a_mass_bound_removes_the_flag():
    from tests.test_newton_convergence import _dfki_problem

    problem = _dfki_problem(mass_bound=None)
    result = DualMetric(allow_unidentifiable=True, fallback=()).fit(problem)
    assert result.info["optimum_at_infinity"] is True
    assert result.info["diverging_direction"].startswith("+1.000·Joint1.m")
    assert result.info["objective_pushed_out"] < result.objective  # lower still with Joint1.m ≥ 10× θ̂'s
    bounded = DualMetric(allow_unidentifiable=True, fallback=()).fit(_dfki_problem(mass_bound=5.0))
    assert bounded.info["optimum_at_infinity"] is False
