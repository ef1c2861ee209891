"""DualMetric's solver options: validation in the constructor, the recorded fallback chain, captured warnings,
and ``optimal_inaccurate`` reported instead of passed off as optimal."""

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
        ({"solver": "qp"}, r"solver must be one of \('newton', 'cvxpy'\), got 'qp'"),
        ({"solver": "sdp_scs"}, r"got 'sdp_scs' \(for SCS: solver='cvxpy', cvxpy_solver='SCS'\)"),
        ({"cvxpy_solver": "MOSEK"}, r"cvxpy_solver must be one of \('CLARABEL', 'SCS'\), got 'MOSEK'"),
        ({"fallback": ("cvxpy", "ipopt")}, r"fallback: expected solver names from .*, got \['ipopt'\]"),
        ({"fallback": 3}, r"fallback: expected a tuple of solver names, got 3"),
        ({"tol": 0.0}, r"tol: expected a relative tolerance in \(0, 1\), got 0.0"),
        ({"tol": "tight"}, r"tol: expected a relative tolerance in \(0, 1\), got 'tight'"),
        ({"max_iter": 0}, r"max_iter: expected a positive integer, got 0"),
        ({"max_iter": 2.5}, r"max_iter: expected a positive integer, got 2.5"),
        ({"solver_options": {"maxiter": 5}}, r"solver_options: the Newton solver accepts .*, got \['maxiter'\]"),
        ({"tol": 1e-6, "solver_options": {"tol": 1e-8}}, r"tol: given both as an argument and in solver_options"),
    ],
)
def test_bad_options_raise_a_typed_error_in_the_constructor(kwargs, message):
    with pytest.raises(SolverOptionError, match=message) as exc:
        DualMetric(**kwargs)
    assert isinstance(exc.value, DualidError) and isinstance(exc.value, ValueError)


def test_a_single_fallback_name_is_accepted_as_a_string():
    assert DualMetric(fallback="newton").fallback == ("newton",)


def test_newton_failure_falls_back_to_the_sdp_and_says_so(problem):
    result = DualMetric(max_iter=2, allow_unidentifiable=True).fit(problem)  # Newton cannot converge in 2 iterations
    assert result.solver == "sdp/CLARABEL" and result.status == "optimal"
    assert result.info["fallback_used"] is True
    assert result.info["fallback_reason"].startswith("newton failed (max_iterations): dual-metric Newton: no convergence in 2")
    assert result.info["solver_chain"].endswith("→ sdp/CLARABEL optimal")
    reference = DualMetric(allow_unidentifiable=True).fit(problem)
    assert reference.info["fallback_used"] is False and reference.info["solver_chain"] == "newton optimal"
    np.testing.assert_allclose(result.objective, reference.objective, rtol=1e-6)


def test_tol_and_max_iter_reach_the_newton_solver(problem):
    loose = DualMetric(tol=1e-3, fallback=(), allow_unidentifiable=True).fit(problem)
    tight = DualMetric(tol=1e-11, fallback=(), allow_unidentifiable=True).fit(problem)
    assert loose.iterations < tight.iterations
    assert loose.info["relative_gap"] <= 1e-3 and tight.info["relative_gap"] <= 1e-11


def test_without_fallback_the_failure_is_raised_with_every_attempt(problem):
    with pytest.raises(SolverError, match=r"every solver failed: newton failed \(max_iterations\)") as exc:
        DualMetric(max_iter=2, fallback=(), allow_unidentifiable=True).fit(problem)
    assert exc.value.status == "all_solvers_failed"


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


def test_optimal_inaccurate_is_reported_and_its_warning_captured(problem, inaccurate_sdp):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning reaching the caller fails the test
        result = DualMetric(solver="cvxpy", fallback=(), allow_unidentifiable=True).fit(problem)
    assert result.status == "optimal_inaccurate"
    assert "UserWarning: Solution may be inaccurate" in result.info["solver_warnings"]
    assert result.info["solver_chain"] == "sdp/CLARABEL optimal_inaccurate"


def test_optimal_inaccurate_tries_the_next_solver(problem, inaccurate_sdp):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = DualMetric(solver="cvxpy", fallback=("newton",), allow_unidentifiable=True).fit(problem)
    assert result.solver == "newton" and result.status == "optimal"
    assert result.info["fallback_reason"].startswith("cvxpy returned optimal_inaccurate")


def test_optimal_inaccurate_comes_back_labelled_when_the_next_solver_fails(problem, inaccurate_sdp, monkeypatch):
    def failing_newton(problem, **kwargs):
        raise SolverError("dual-metric Newton: line search failed", status="line_search_failed")

    monkeypatch.setattr(dual_metric, "fit_dual_metric_newton", failing_newton)
    result = DualMetric(solver="cvxpy", fallback=("newton",), allow_unidentifiable=True).fit(problem)
    assert result.status == "optimal_inaccurate" and result.solver == "sdp/CLARABEL"
    assert result.info["solver_chain"] == (
        "cvxpy returned optimal_inaccurate (objective " + f"{result.objective:.10g}) → newton failed "
        "(line_search_failed): dual-metric Newton: line search failed → sdp/CLARABEL optimal_inaccurate"
    )


def test_no_sdp_fallback_on_large_problems(problem, monkeypatch):
    monkeypatch.setattr(dual_metric, "SDP_FALLBACK_MAX_N", 10)
    with pytest.raises(SolverError, match=r"newton failed \(max_iterations\).*; then cvxpy skipped \(N = 30 > 10"):
        DualMetric(max_iter=2, allow_unidentifiable=True).fit(problem)
