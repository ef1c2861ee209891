"""Constrained and regularized least squares by dualid's own interior-point method (the default), Clarabel as its
recorded fallback, and the interior point as the fallback of the conic reference (solver="cvxpy") when Clarabel fails
or stops at optimal_inaccurate (thin-rod arms: pseudo-inertias near singular)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from dualid import OLS, WLS, EnergyLS, RegularizedWLS
from dualid.data import Trajectory
from dualid.estimators.newton.objective import statistics
from dualid.estimators.quadratic_fit import fit_quadratic
from dualid.estimators.quadratic_newton import fit_quadratic_newton
from dualid.model import RigidBodyModel
from dualid.model.consistency import regularizer_value
from dualid.problem import build_problem
from tests.factories import arm


def _arm_problem(model, seed, T=300):
    rng = np.random.default_rng(seed)
    nj = model.model.nv if hasattr(model, "model") else len(model.coordinates)
    q = rng.uniform(-np.pi, np.pi, (T, nj))
    v, a = rng.standard_normal((T, nj)), 3 * rng.standard_normal((T, nj))
    tau = model.regressor(q, v, a) @ model.nominal
    tau += 0.05 * np.abs(tau).mean(0) * rng.standard_normal(tau.shape)
    return build_problem(model, Trajectory(np.arange(T) * 0.01, q, v, tau, a, model.coordinates, "random"))


@pytest.fixture(scope="module")
def arm3():
    model = RigidBodyModel(arm(3))
    return model, _arm_problem(model, 0)


@pytest.fixture(scope="module")
def arm7():
    from dualid.bench.runner import pinocchio_model

    model = RigidBodyModel(pinocchio_model("arm7"))
    return model, _arm_problem(model, 0)


@pytest.mark.parametrize("which", ["arm3", "arm7"])
def test_constrained_ols_on_thin_rod_arms_is_optimal(which, request):
    """Pseudo-inertias near singular: the fit is optimal, consistent, agrees with SCS (a different algorithm) and no
    raw warning escapes."""
    _, problem = request.getfixturevalue(which)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = OLS(allow_unidentifiable=True, solver="newton").fit(problem)
    assert result.status == "optimal" and result.is_consistent and result.solver == "newton"
    scs = fit_quadratic(problem, statistics(problem), method="ols", constrained=True, solver="SCS",
                        solver_options={"eps": 1e-10, "max_iters": 100_000}, allow_unidentifiable=True)
    assert result.objective <= scs.objective * (1 + 1e-7)
    assert result.objective == pytest.approx(scs.objective, rel=1e-5)


def test_a_failed_clarabel_fit_falls_back_to_newton_and_says_so(arm3):
    _, problem = arm3
    result = EnergyLS(allow_unidentifiable=True, solver="cvxpy", solver_options={"max_iter": 3}).fit(problem)
    assert (result.status, result.solver, result.info["fallback_used"]) == ("optimal", "newton", True)
    assert result.info["solver_chain"].startswith("CLARABEL failed (user_limit)")
    assert result.info["solver_chain"].endswith("→ newton optimal")
    reference = EnergyLS(allow_unidentifiable=True).fit(problem)
    assert result.objective == pytest.approx(reference.objective, rel=1e-6)


def test_a_failed_newton_fit_falls_back_to_clarabel_and_says_so(arm3):
    _, problem = arm3
    result = EnergyLS(allow_unidentifiable=True, solver_options={"max_iter": 3}).fit(problem)
    assert (result.status, result.info["fallback_used"]) == ("optimal", True)
    assert result.info["solver_chain"].startswith("newton failed (max_iterations) → CLARABEL ")
    reference = EnergyLS(allow_unidentifiable=True).fit(problem)
    assert result.objective == pytest.approx(reference.objective, rel=1e-6)


def test_wls_on_the_7dof_arm_is_optimal(arm7):
    _, problem = arm7
    result = WLS(allow_unidentifiable=True).fit(problem)
    assert result.status == "optimal" and result.is_consistent


@pytest.mark.parametrize("kind", ["pullback", "logdet"])
def test_regularized_fit_agrees_with_cvxpy_where_clarabel_is_optimal(arm3, kind):
    model, problem = arm3
    theta0 = model.nominal * 1.3  # a CAD-like prior, off from the truth
    stats = statistics(problem)
    gamma = 10.0
    theta, info = fit_quadratic_newton(stats.H, stats.g, stats.c, problem.parameters, regularizer=(kind, theta0, gamma))
    value = stats.objective(problem, theta) + gamma * regularizer_value(kind, problem.parameters, theta, theta0)
    ref = RegularizedWLS(theta0=theta0, gamma=gamma, per_equation=False, regularizer=kind, covariance=np.eye(problem.n),
                         allow_unidentifiable=True, solver="cvxpy").fit(problem)
    assert ref.status == "optimal" and ref.solver == "CLARABEL"
    assert value == pytest.approx(ref.objective, rel=1e-7)
    assert info["iterations"] <= 30
    assert problem.parameters.is_consistent(theta, tol=1e-9)


def test_a_duality_gap_of_exactly_zero_is_not_a_division_by_zero(arm3):
    """The dual iterates can underflow to 0 (seen on LandSalp's log-det fit with the OLS prior: the gap halves
    ×20 per iteration to 0 after ~250 of them); μ = gap/ν = 0 then leaves nothing to centre (σ = 0), instead of
    dividing by it. Started here with Z = 0, z = 0 (gap 0 at iteration 0), away from an interior minimiser a."""
    from dualid.estimators.newton.interior_point import run_interior_point
    from dualid.model.consistency import central_point
    from dualid.estimators.quadratic_newton import quadratic_objective
    from dualid.model.consistency import feasible_set

    model, problem = arm3
    cons = feasible_set(problem.parameters, True)
    a = np.asarray(model.nominal, dtype=float)
    assert cons.margin(a) > 0
    objective, _ = quadratic_objective(np.eye(len(a)), a, float(a @ a), problem.parameters)
    theta0 = 0.5 * (a + central_point(a, cons))  # strictly feasible (convex combination), ≠ a
    assert cons.margin(theta0) > 0 and np.abs(theta0 - a).max() > 1e-3 * np.abs(a).max()
    Z = [np.zeros_like(c.C(theta0)) for c in cons.lmis]
    theta, _, _, info = run_interior_point(None, cons, theta0, Z, np.zeros(len(cons.h)), 1e-9, 50, 0, False,
                                        objective=objective, f_scale=1.0)
    assert info["duality_gap"] < 1e-300  # the dual stays at 0 (up to repair_psd's denormals)
    np.testing.assert_allclose(theta, a, rtol=0, atol=1e-9 * np.abs(a).max())


def _dfki_problem():
    """The DFKI example's training problem (examples/dfki/fit.yaml): its links' Iyy and Izz have no effect on the data."""
    from pathlib import Path

    from dualid.problem import build_problem as problem_of
    from dualid.robot import fit as rf
    from dualid.robot.config import FitConfig

    config = FitConfig.from_yaml(Path(__file__).resolve().parents[1] / "examples" / "dfki" / "fit.yaml")
    rigid, model = rf.build_model(config)
    joints = tuple(rigid.coordinates)
    columns = rf.column_map(config.columns, joints, config.train[0])
    steps, _ = rf.choose_preprocessing(config.preprocessing, config.train[0], columns, joints)
    return rf.with_bounds(problem_of(model, rf.load_runs(config.train, columns, joints, steps, rigid)), config.bounds)


def test_the_interior_point_does_not_drift_along_what_the_data_do_not_see(monkeypatch):
    """The barrier pushes an interior point outward along directions f cannot see that loosen a block (a link's
    Iyy + Izz about a joint that turns about x): on the DFKI logs WLS ended at Iyy = Izz = 110 kg m² and dm (its WLS
    fallback) at 5,204. Its end is moved along the data's null space toward its start (``newton.start.toward_start``):
    the same predictions and objective, inertias of the links' size."""
    from dualid.estimators import noise_dm
    from dualid.estimators.methods import make_estimator
    from dualid.estimators.newton import weighted

    problem = _dfki_problem()
    unseen = [k for k, name in enumerate(problem.parameters.names) if name.endswith((".Iyy", ".Izz"))]
    fit = {m: make_estimator(m, allow_unidentifiable=True).fit(problem) for m in ("wls", "dm")}
    for module in (weighted, noise_dm):
        monkeypatch.setattr(module, "toward_start", lambda theta, *args: theta)
    drift = {m: make_estimator(m, allow_unidentifiable=True).fit(problem) for m in ("wls", "dm")}
    Y = problem.Y.reshape(-1, problem.p)
    for m in fit:
        assert np.max(np.abs(fit[m].theta[unseen])) < 1.0 < np.max(np.abs(drift[m].theta[unseen])), m
        prediction, drifted = Y @ fit[m].theta, Y @ drift[m].theta
        assert np.linalg.norm(prediction - drifted) <= 1e-7 * np.linalg.norm(drifted), m
        assert fit[m].objective == pytest.approx(drift[m].objective, rel=1e-9), m
