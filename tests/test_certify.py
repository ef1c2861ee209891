"""Every cvxpy 'optimal' of a quadratic or regularized fit is certified by dualid's interior point started from it
(estimators.quadratic_newton.polish): a solution above the certified optimum is polished and says by how much, an uncertified one
is reported as optimal_inaccurate, never as optimal."""

from __future__ import annotations

import pytest

from dualid.bench.corpus import problem as corpus_problem
from dualid.errors import SolverError
from dualid.estimators import quadratic_newton as certify
from dualid.estimators.methods import make_estimator

CASE = "crazyflie floating base, 5 %"  # Clarabel solves its OLS fit accurately (a chain's is on the closed set)


def test_a_clarabel_optimal_above_the_optimum_is_polished_and_says_by_how_much(monkeypatch):
    """Clarabel's answer moved 30 % toward the true θ (feasible: the set is convex) and still labelled 'optimal' —
    what Clarabel did on boundary priors in the stress corpus (1e-5 … 4e-2 above), made deterministic."""
    problem, theta_true = corpus_problem(CASE)
    honest = make_estimator("ols", allow_unidentifiable=True, options={"solver": "cvxpy"}).fit(problem)
    assert honest.info["solver_chain"].startswith("CLARABEL optimal (certified by newton: ")
    seen = {}
    polish = certify.polish

    def moved(theta_cvx, stats, parameters, constrained, regularizer, solver, closure=False):
        worse = 0.7 * theta_cvx + 0.3 * theta_true
        seen["f"] = certify.certified_objective(stats, parameters, regularizer)
        seen["worse"], seen["best"] = worse, theta_cvx
        return polish(worse, stats, parameters, constrained, regularizer, solver, closure=closure)

    monkeypatch.setattr(certify, "polish", moved)
    result = make_estimator("ols", allow_unidentifiable=True, options={"solver": "cvxpy"}).fit(problem)
    assert (result.status, result.solver, result.info["fallback_used"]) == ("optimal", "newton", True)
    above = result.info["cvxpy_above_certified"]
    assert result.info["solver_chain"] == f"CLARABEL optimal but {above:.1e} above → newton polished"
    # the polish returns the honest optimum, and 'above' is the moved point's own excess over it
    assert result.objective == pytest.approx(honest.objective, rel=certify.TOL)  # both certified to TOL
    f = seen["f"]
    # (Clarabel's own point is within 1e-9 of the certified optimum)
    assert above == pytest.approx((f(seen["worse"]) - f(seen["best"])) / f(seen["best"]), rel=1e-5, abs=1e-9)
    assert above > 1e-4


def test_a_clarabel_optimal_that_cannot_be_certified_is_reported_inaccurate(monkeypatch):
    problem, _ = corpus_problem(CASE)
    import dualid.estimators.quadratic_newton as qn

    def broken(*args, **kwargs):
        raise SolverError("quadratic Newton: broken for the test", status="max_iterations")

    monkeypatch.setattr(qn, "fit_quadratic_newton", broken)
    result = make_estimator("ols", allow_unidentifiable=True, options={"solver": "cvxpy"}).fit(problem)
    assert result.status == "optimal_inaccurate" and result.solver == "CLARABEL"
    assert result.info["solver_chain"] == "CLARABEL optimal, not certified: newton check failed (max_iterations)"


def test_an_accurate_clarabel_solution_is_kept_and_certified():
    problem, _ = corpus_problem("crazyflie, units 1e3 on q1, 5 %")
    result = make_estimator("ols", allow_unidentifiable=True, options={"solver": "cvxpy"}).fit(problem)
    assert (result.status, result.solver, result.info["fallback_used"]) == ("optimal", "CLARABEL", False)
    assert result.info["solver_chain"].startswith("CLARABEL optimal (certified by newton: ")
    assert result.info["cvxpy_above_certified"] <= 1e-7 and result.info["certified_gap"] <= 1e-9


@pytest.mark.parametrize("method", ["ols", "energy"])
def test_exact_data_are_certified_at_the_rounding_floor(method):
    """f(θ̂) ~ 1e-26 (exact torques): no relative test on f can pass, but f ≥ 0 certifies θ̂ to f(θ̂)/f(0). (WLS on
    exact data weights by a noise at the rounding floor, 1e-12 mean τ_j²: there Clarabel's answer is not at the
    floor, and the interior point solves it: test_estimators.)"""
    problem, _ = corpus_problem("chain RR, 2 dof, exact")
    result = make_estimator(method, allow_unidentifiable=True, options={"solver": "cvxpy"}).fit(problem)
    assert (result.status, result.solver) == ("optimal", "CLARABEL")
    gap = result.info["certified_gap"]
    assert gap <= certify.ROUNDING
    assert result.info["solver_chain"] == f"CLARABEL optimal (certified: f at the rounding floor, {gap:.1e} of f(0))"
