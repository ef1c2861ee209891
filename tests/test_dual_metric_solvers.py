"""DualMetric's solver options: validation in the constructor, the solver asked for and no other (its failure is a
SolverError), captured warnings, and ``optimal_inaccurate`` reported instead of passed off as optimal."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from dualid import DualMetric
from dualid.errors import DualidError, SolverError, SolverOptionError
from dualid.estimators import dual_metric

from .test_newton import crazyflie_like, rigid_body_problem


@pytest.fixture(scope="module")
def problem():
    return rigid_body_problem(crazyflie_like(), 30, seed=1, noise=0.05)[0]


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"solver": "qp"}, r"solver must be one of 'newton', 'cvxpy', got 'qp'"),
        ({"solver": "sdp"}, r"solver must be one of 'newton', 'cvxpy', got 'sdp'"),
        ({"solver": "sdp_scs"}, r"solver must be one of 'newton', 'cvxpy', got 'sdp_scs'"),
        ({"solver": "cvxpy", "solver_options": {"cvxpy_solver": "MOSEK"}},
         r"solver_options\['cvxpy_solver'\] must be one of CLARABEL, SCS, got 'MOSEK'"),
        ({"tol": 0.0}, r"tol: expected a relative tolerance in \(0, 1\), got 0.0"),
        ({"tol": "tight"}, r"tol: expected a relative tolerance in \(0, 1\), got 'tight'"),
        ({"max_iter": 0}, r"max_iter: expected a positive integer, got 0"),
        ({"max_iter": 2.5}, r"max_iter: expected a positive integer, got 2.5"),
        ({"solver_options": {"maxiter": 5}}, r"solver_options of solver='newton' are .*; got \['maxiter'\]"),
        ({"tol": 1e-6, "solver_options": {"tol": 1e-8}}, r"tol: given both as an argument and in solver_options"),
    ],
)
def test_bad_options_raise_a_typed_error_in_the_constructor(kwargs, message):
    with pytest.raises(SolverOptionError, match=message) as exc:
        DualMetric(**kwargs)
    assert isinstance(exc.value, DualidError) and isinstance(exc.value, ValueError)


def test_there_is_no_fallback_field():
    for old in ({"fallback": ("cvxpy",)}, {"sdp_solver": "SCS"}):
        with pytest.raises(TypeError):
            DualMetric(**old)


def test_the_sdp_by_scs_is_chosen_by_solver_options(problem):
    scs = DualMetric(solver="cvxpy", solver_options={"cvxpy_solver": "SCS"}, allow_unidentifiable=True).fit(problem)
    assert scs.solver == "sdp/SCS"


def test_newton_agrees_with_the_sdp_reference(problem):
    newton = DualMetric(allow_unidentifiable=True).fit(problem)
    sdp = DualMetric(solver="cvxpy", allow_unidentifiable=True).fit(problem)
    assert (newton.solver, sdp.solver) == ("newton", "sdp/CLARABEL")
    assert "solver_chain" not in newton.info and "fallback_used" not in newton.info
    np.testing.assert_allclose(newton.objective, sdp.objective, rtol=1e-6)


def test_tol_and_max_iter_reach_the_newton_solver(problem):
    loose = DualMetric(tol=1e-3, allow_unidentifiable=True).fit(problem)
    tight = DualMetric(tol=1e-11, allow_unidentifiable=True).fit(problem)
    assert loose.iterations < tight.iterations
    assert loose.info["relative_gap"] <= 1e-3 and tight.info["relative_gap"] <= 1e-11


def test_a_newton_failure_is_raised_and_the_sdp_is_not_tried(problem, monkeypatch):
    def never(*args, **kwargs):
        raise AssertionError("the SDP was run")

    monkeypatch.setattr(dual_metric, "fit_dual_metric_sdp", never)
    with pytest.raises(SolverError, match=r"dual-metric Newton: no convergence in 2") as exc:
        DualMetric(max_iter=2, allow_unidentifiable=True).fit(problem)  # Newton cannot converge in 2 iterations
    assert exc.value.status == "max_iterations"


def test_infeasible_problems_do_not_fall_back(problem):
    space = problem.parameters.with_bounds(lower={problem.parameters.names[0]: 2.0}, upper={problem.parameters.names[0]: 1.0})
    with pytest.raises(SolverError, match=r"the bounds admit no strictly feasible θ") as exc:
        DualMetric(allow_unidentifiable=True).fit(dataclasses.replace(problem, parameters=space))
    assert exc.value.status == "infeasible"


def _inaccurate_sdp(problem, **kwargs):
    """The real SDP, then a warning as cvxpy gives it and the status a solver gives when it stalls."""
    result = dual_metric.fit_dual_metric_sdp.__wrapped__(problem, **kwargs)
    warnings.warn("Solution may be inaccurate. Try another solver", UserWarning)
    return dataclasses.replace(result, status="optimal_inaccurate")


@pytest.fixture
def inaccurate_sdp(monkeypatch):
    real = dual_metric.fit_dual_metric_sdp
    _inaccurate_sdp.__wrapped__ = real
    monkeypatch.setattr(dual_metric, "fit_dual_metric_sdp", _inaccurate_sdp)


def test_optimal_inaccurate_is_reported_and_its_warning_captured(problem, inaccurate_sdp, monkeypatch):
    def never(*args, **kwargs):
        raise AssertionError("Newton was run")

    monkeypatch.setattr(dual_metric, "fit_dual_metric_newton", never)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning reaching the caller fails the test
        result = DualMetric(solver="cvxpy", allow_unidentifiable=True).fit(problem)
    assert result.status == "optimal_inaccurate" and result.solver == "sdp/CLARABEL"
    assert "UserWarning: Solution may be inaccurate" in result.info["solver_warnings"]
