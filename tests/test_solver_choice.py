"""One solver vocabulary (estimators.base.SOLVERS): every estimator solves with dualid's interior point
("newton", the default) or with the cvxpy reference ("cvxpy": Clarabel, or SCS by solver_options), the one asked for
and nothing else: no polish of one by the other and no fallback between them, a failure is a SolverError, and an old
solver name is a ConfigError naming the valid ones."""

from __future__ import annotations

import numpy as np
import pytest

from dualid import OLS, WLS, DualMetric, EnergyLS, RegularizedWLS
from dualid.bench.corpus import problem as corpus_problem
from dualid.errors import ConfigError, SolverError
from dualid.estimators.base import SOLVERS
from dualid.estimators.methods import make_estimator


def test_the_vocabulary_is_newton_and_cvxpy_and_newton_is_every_default():
    assert SOLVERS == ("newton", "cvxpy")
    theta0 = np.zeros(10)
    for est in (OLS(), WLS(), EnergyLS(), RegularizedWLS(theta0=theta0), DualMetric()):
        assert est.solver == "newton", type(est).__name__


@pytest.mark.parametrize("cls", [OLS, WLS, EnergyLS, DualMetric])
@pytest.mark.parametrize("old", ["CLARABEL", "SCS", "sdp", "sdp_clarabel", "sdp_scs"])
def test_an_old_solver_name_is_refused_naming_the_valid_ones(cls, old):
    with pytest.raises(ConfigError, match="'newton', 'cvxpy'"):
        cls(solver=old)


def test_dual_metric_has_no_fallback_or_sdp_solver_field():
    with pytest.raises(TypeError):
        DualMetric(fallback=("cvxpy",))
    with pytest.raises(TypeError):
        DualMetric(sdp_solver="SCS")


def test_solver_options_are_checked_for_the_solver_asked_for():
    with pytest.raises(ConfigError, match="tol, max_iter"):
        OLS(solver_options={"cvxpy_solver": "SCS"})  # a cvxpy option given to newton
    with pytest.raises(ConfigError, match="CLARABEL, SCS"):
        WLS(solver="cvxpy", solver_options={"cvxpy_solver": "MOSEK"})
    OLS(solver="cvxpy", solver_options={"cvxpy_solver": "SCS", "eps": 1e-9})


@pytest.mark.parametrize("method", ["ols", "wls", "energy"])
def test_newton_agrees_with_the_cvxpy_reference(method):
    problem, _ = corpus_problem("chain RPR, 3 dof, 5 %")
    newton = make_estimator(method, allow_unidentifiable=True).fit(problem)
    ref = make_estimator(method, allow_unidentifiable=True, options={"solver": "cvxpy"}).fit(problem)
    assert (newton.status, newton.solver) == ("optimal", "newton")
    assert (ref.status, ref.solver) == ("optimal", "CLARABEL")
    assert "solver_chain" not in newton.info and "fallback_used" not in newton.info
    assert newton.objective == pytest.approx(ref.objective, rel=1e-6)
    assert newton.objective <= ref.objective * (1 + 1e-9)


def test_scs_is_chosen_by_solver_options():
    problem, _ = corpus_problem("point-mass link, 3 dof, 5 %")
    r = OLS(solver="cvxpy", solver_options={"cvxpy_solver": "SCS"}, allow_unidentifiable=True).fit(problem)
    assert r.solver == "SCS"


@pytest.mark.parametrize("method", ["ols", "energy", "wls"])
def test_exact_data_are_fitted_to_the_rounding_floor(method):
    """f(θ̂)/f(0) at rounding (exact torques), by the default solver alone."""
    problem, _ = corpus_problem("chain RR, 2 dof, exact")
    result = make_estimator(method, allow_unidentifiable=True).fit(problem)
    assert (result.status, result.solver) == ("optimal", "newton")
    Y, tau = problem.Y.reshape(-1, problem.p), problem.tau.reshape(-1)
    assert np.linalg.norm(Y @ result.theta - tau) <= 1e-6 * np.linalg.norm(tau)


def test_a_newton_failure_is_a_solver_error_and_cvxpy_is_not_tried(monkeypatch):
    import dualid.estimators.base as base
    import dualid.estimators.quadratic_fit as quadratic_fit

    def fails(*args, **kwargs):
        raise SolverError("newton failed (test)", status="test")

    def never(*args, **kwargs):
        raise AssertionError("cvxpy was run")

    monkeypatch.setattr(quadratic_fit, "fit_quadratic_newton", fails)
    monkeypatch.setattr(quadratic_fit, "solve_cvxpy", never)
    monkeypatch.setattr(base, "solve_cvxpy", never)
    problem, _ = corpus_problem("point-mass link, 3 dof, 5 %")
    with pytest.raises(SolverError, match="newton failed"):
        OLS(allow_unidentifiable=True).fit(problem)
