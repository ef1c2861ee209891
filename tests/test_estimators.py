"""Every estimator recovers the truth from noiseless exciting data; constraints hold; errors are explicit."""

import numpy as np
import pytest

from dualid import OLS, WLS, DualMetric, EnergyLS, RegularizedWLS
from dualid.errors import ConfigError, ConsistencyError, DataError, IdentifiabilityError, MetricError, SolverError
from dualid.model.metric import AffineMetric
from dualid.problem import IdentificationProblem, build_problem
from dualid.systems import pan_tilt
from tests.factories import drag_problem

ESTIMATORS = {
    "ols": OLS(),
    "ols_unconstrained": OLS(constrained=False),
    "ols_newton": OLS(solver="newton"),
    "wls": WLS(),
    "wls_newton": WLS(solver="newton"),
    "energy": EnergyLS(),
    "energy_newton": EnergyLS(solver="newton"),
    "dm": DualMetric(),  # the Newton solver
    "dm_unconstrained": DualMetric(constrained=False),
    "dm_sdp": DualMetric(solver="cvxpy"),
    "dm_sdp_unconstrained": DualMetric(solver="cvxpy", constrained=False),
}


@pytest.fixture(scope="module")
def pan_tilt_noiseless():
    model, train, _, theta = pan_tilt.dataset(1, n_train=1, n_test=0, noise=pan_tilt.PanTiltNoise.noiseless(), duration=3)
    return build_problem(model, train).subset(slice(0, None, 4)), theta


# The Schur-complement SDP is degenerate on exact data (every slack is 0 at the optimum), so the
# interior-point reference reaches ~1e-5 there; the quadratic estimators are solved to ~1e-9.
RTOL = {"dm_sdp": 1e-4, "dm_sdp_unconstrained": 1e-4}


@pytest.mark.parametrize("name", sorted(ESTIMATORS))
def test_recovers_truth_from_noiseless_drag_data(name):
    problem, theta = drag_problem(np.random.default_rng(0), N=40, n=3)
    result = ESTIMATORS[name].fit(problem)
    np.testing.assert_allclose(result.theta, theta, rtol=RTOL.get(name, 1e-6))
    assert result.objective == pytest.approx(0.0, abs=1e-7)
    if name.startswith("wls"):  # Σ̂ from rounding-level residuals would weigh rounding: 1e-12 mean τ_j² instead, said
        assert result.info["covariance"] == "rounding floor" and "exact data" in result.info["fallback"]


def test_wls_weights_come_from_the_residuals_once_there_is_noise():
    problem, _ = drag_problem(np.random.default_rng(0), N=40, n=3, noise=1e-4)  # Σr² ≈ 7e-11 Στ²: noise
    result = WLS().fit(problem)
    assert result.info["covariance"] == "ols residuals" and "fallback" not in result.info


def test_every_wls_weight_takes_the_rounding_floor_on_exact_data():
    """The residual covariance, the dual-metric guard's WLS reference: on exact data 1e-12 mean τ_j², said so."""
    from dualid.estimators.least_squares import residual_covariance, wls_reference

    exact, theta = drag_problem(np.random.default_rng(0), N=40, n=3)
    S, fallback = residual_covariance(exact, theta)
    np.testing.assert_allclose(S, 1e-12 * np.diag(np.mean(exact.tau**2, axis=0)), rtol=1e-12)
    assert "exact data" in fallback and "exact data" in wls_reference(exact, True)[1]
    np.testing.assert_allclose(wls_reference(exact, True)[0], theta, rtol=1e-6)
    noisy, _ = drag_problem(np.random.default_rng(0), N=40, n=3, noise=1e-4)
    S, fallback = residual_covariance(noisy, theta)
    r = noisy.residual(theta)
    np.testing.assert_allclose(S, r.T @ r / noisy.N, rtol=1e-12)
    assert fallback is None and "exact" not in wls_reference(noisy, True)[1]


@pytest.mark.parametrize("name", sorted(ESTIMATORS))
def test_recovers_truth_from_noiseless_pan_tilt_data(name, pan_tilt_noiseless):
    problem, theta = pan_tilt_noiseless
    np.testing.assert_allclose(ESTIMATORS[name].fit(problem).theta, theta, rtol=RTOL.get(name, 1e-5))


@pytest.mark.parametrize("regularizer", ["logdet", "pullback"])
def test_regularized_wls_recovers_truth(regularizer):
    problem, theta = drag_problem(np.random.default_rng(1), N=40, n=3)
    eye = np.eye(3)  # a given covariance keeps the data term's scale fixed (Σ r_iᵀ r_i)
    at_truth = RegularizedWLS(theta0=theta, gamma=10.0, per_equation=False, regularizer=regularizer,
                              covariance=eye).fit(problem)
    np.testing.assert_allclose(at_truth.theta, theta, rtol=1e-6)
    off = RegularizedWLS(theta0=1.3 * theta, gamma=1e-6, per_equation=False, regularizer=regularizer,
                         covariance=eye).fit(problem)
    np.testing.assert_allclose(off.theta, theta, rtol=1e-4)
    strong = RegularizedWLS(theta0=1.3 * theta, gamma=1e7, per_equation=False, regularizer=regularizer,
                            covariance=eye).fit(problem)
    np.testing.assert_allclose(strong.theta, 1.3 * theta, rtol=1e-3)  # the prior dominates



def test_constraints_hold_where_the_unconstrained_fit_violates_them():
    rng = np.random.default_rng(2)
    theta = rng.uniform(0.5, 2.0, 9)
    theta[[2, 5]] = 0.0  # two coefficients on the boundary: noise pushes them negative
    problem, _ = drag_problem(rng, N=30, n=3, noise=0.5, theta=theta)
    free = OLS(constrained=False).fit(problem)
    assert free.theta.min() < 0
    for est in (OLS(), WLS(), EnergyLS(), DualMetric(), DualMetric(solver="cvxpy")):
        result = est.fit(problem)
        assert result.theta.min() >= -1e-8, est
        assert result.is_consistent


def test_result_is_immutable_and_reports_the_solver():
    problem, _ = drag_problem(np.random.default_rng(0), N=20, n=3)
    result = DualMetric().fit(problem)
    with pytest.raises(ValueError):
        result.theta[0] = 1.0
    with pytest.raises(AttributeError):
        result.objective = 0.0
    assert result.status == "optimal" and result.solver == "newton" and result.solve_time > 0
    assert DualMetric(solver="cvxpy").fit(problem).solver == "sdp/CLARABEL"
    assert [b.name for b in result.bodies] == ["body0", "body1", "body2"]
    assert result.as_dict()["parameters"][0]["name"] == "body0.d_long"


# --- bad input ----------------------------------------------------------------------------------
def test_problem_shape_and_finiteness_errors():
    problem, _ = drag_problem(np.random.default_rng(0), N=10, n=3)
    with pytest.raises(DataError, match=r"tau: expected shape \(10, 3\), got \(10, 2\)"):
        IdentificationProblem(problem.Y, problem.tau[:, :2], problem.metric, problem.v, problem.parameters)
    Y = problem.Y.copy()
    Y[4, 1, 2] = np.nan
    with pytest.raises(DataError, match=r"Y: 1 non-finite values \(NaN or inf\), first at index \[4, 1, 2\]"):
        IdentificationProblem(Y, problem.tau, problem.metric, problem.v, problem.parameters)
    with pytest.raises(DataError, match=r"metric: expected N=5 samples of 3×3 matrices in p=9 parameters, got N=10"):
        IdentificationProblem(problem.Y[:5], problem.tau[:5], problem.metric, problem.v[:5], problem.parameters)
    with pytest.raises(DataError, match=r"kind: expected 'inertia' or 'drag', got 'viscous'"):
        IdentificationProblem(problem.Y, problem.tau, problem.metric, problem.v, problem.parameters, "viscous")


def test_too_few_samples_is_an_identifiability_error():
    problem, _ = drag_problem(np.random.default_rng(0), N=2, n=3)
    for est in (OLS(), DualMetric(), WLS()):
        with pytest.raises(IdentifiabilityError, match=r"too few samples: 2 samples × 3 coordinates = 6 equations for 9 parameters"):
            est.fit(problem)


def test_rank_deficiency_names_the_unidentifiable_parameters():
    problem, theta = drag_problem(np.random.default_rng(0), N=30, n=3)
    # body1's rotational drag never acts: its Jacobian row is zero at every sample
    J = np.array(problem.metric.terms[1].J)
    J[:, 2, :] = 0.0
    terms = list(problem.metric.terms)
    terms[1] = type(terms[1])(terms[1].indices, terms[1].E, J)
    metric = AffineMetric(problem.p, tuple(terms))
    broken = IdentificationProblem(metric.apply(problem.v), metric.apply(problem.v) @ theta, metric, problem.v, problem.parameters, "drag")
    for est in (OLS(), DualMetric(), EnergyLS()):
        with pytest.raises(IdentifiabilityError, match=r"rank 8 < 9 parameters.*Not identifiable: body1\.d_rot"):
            est.fit(broken)
    lenient = OLS(allow_unidentifiable=True).fit(broken)
    np.testing.assert_allclose(broken.residual(lenient.theta), 0.0, atol=1e-8)


def test_nominal_must_be_physically_consistent():
    problem, theta = drag_problem(np.random.default_rng(0), N=20, n=3)
    bad = theta.copy()
    bad[4] = -1.0
    with pytest.raises(ConsistencyError, match=r"nominal θ₀ is not physically consistent: block 'body1' has constraint-matrix smallest eigenvalue -1; it must be positive definite"):
        RegularizedWLS(theta0=bad).fit(problem)
    with pytest.raises(ValueError, match=r"nominal θ₀: expected shape \(9,\), got \(3,\)"):
        RegularizedWLS(theta0=theta[:3]).fit(problem)
    with pytest.raises(ConfigError, match=r"^RegularizedWLS: regularizer must be 'logdet' or 'pullback', got 'l2'$"):
        RegularizedWLS(theta0=theta, regularizer="l2")


def test_infeasible_constraints_raise_with_the_solver_status():
    problem, _ = drag_problem(np.random.default_rng(0), N=20, n=3)
    impossible = IdentificationProblem(
        problem.Y, problem.tau, problem.metric, problem.v, problem.parameters.with_bounds(upper=np.full(9, -1.0)), "drag"
    )
    with pytest.raises(SolverError, match=r"ols fit: the problem is infeasible \(CLARABEL status 'infeasible'\)") as info:
        OLS().fit(impossible)
    assert info.value.status == "infeasible"


def test_a_false_infeasibility_claim_is_refuted_by_the_interior_point(monkeypatch):
    """cvxpy's "infeasible" ends a fit only when dualid's interior point finds no feasible optimum either (a badly
    scaled conic problem can be called infeasible: the margin's pullback fit in test_margin was); the chain says so."""
    import dualid.estimators.quadratic_fit as ls

    problem, _ = drag_problem(np.random.default_rng(0), N=20, n=3)
    expected = OLS().fit(problem)

    def claims_infeasible(*args, **kwargs):
        raise SolverError("ols fit: the problem is infeasible (CLARABEL status 'infeasible')", status="infeasible")

    monkeypatch.setattr(ls, "solve_cvxpy", claims_infeasible)
    result = OLS(solver="cvxpy").fit(problem)
    assert result.info["solver_chain"] == "CLARABEL claimed infeasible → newton optimal"
    assert result.solver == "newton" and result.status == "optimal" and result.info["fallback_used"] is True
    assert np.allclose(result.theta, expected.theta, rtol=1e-6, atol=1e-9)
    impossible = IdentificationProblem(
        problem.Y, problem.tau, problem.metric, problem.v, problem.parameters.with_bounds(upper=np.full(9, -1.0)), "drag"
    )
    with pytest.raises(SolverError, match=r"^ols fit: the problem is infeasible \(CLARABEL status 'infeasible'\)$"):
        OLS(solver="cvxpy").fit(impossible)  # the interior point finds no start either: the claim stands


def test_metric_that_cannot_be_positive_definite_is_a_metric_error():
    problem, _ = drag_problem(np.random.default_rng(0), N=20, n=3)
    M0 = np.zeros((20, 3, 3))
    M0[7] = -1e3 * np.eye(3)  # sample 7 is negative definite unless θ is huge
    metric = AffineMetric(problem.p, problem.metric.terms, M0)
    bounded = problem.parameters.with_bounds(upper=np.full(9, 2.0))
    bad = IdentificationProblem(problem.Y, problem.tau, metric, problem.v, bounded, "drag")
    with pytest.raises(MetricError, match=r"no θ makes every M_i\(θ\) positive semidefinite under the constraints"):
        DualMetric(solver="cvxpy").fit(bad)
    with pytest.raises(MetricError, match=r"no θ satisfying the constraints makes M_i\(θ\) positive definite at samples \[7\]"):
        DualMetric().fit(bad)


def test_unknown_solver_names_are_rejected():
    problem, _ = drag_problem(np.random.default_rng(0), N=20, n=3)
    with pytest.raises(ConfigError, match=r"^OLS: solver must be one of \('newton', 'cvxpy'\), got 'MOSEK'$"):
        OLS(solver="MOSEK")
    with pytest.raises(ConfigError, match=r"^OLS: cvxpy_solver must be one of \('CLARABEL', 'SCS'\), got 'MOSEK'$"):
        OLS(cvxpy_solver="MOSEK")


@pytest.mark.parametrize("make, message", [
    (lambda: RegularizedWLS(theta0=None), r"^RegularizedWLS: needs a nominal θ₀ \(theta0=...\)$"),
    (lambda: RegularizedWLS(theta0=[1.0, float("nan")]), r"^RegularizedWLS: theta0 must be a finite vector"),
    (lambda: RegularizedWLS(theta0=[1.0], gamma=float("nan")), r"^RegularizedWLS: gamma must be a finite number ≥ 0, got nan$"),
    (lambda: RegularizedWLS(theta0=[1.0], gamma=-1), r"^RegularizedWLS: gamma must be a finite number ≥ 0, got -1$"),
    (lambda: WLS(covariance=[[1.0, 2.0], [2.0, 1.0]]), r"^WLS: covariance must be a finite symmetric positive-definite matrix$"),
    (lambda: WLS(covariance=[1.0, 2.0]), r"^WLS: covariance must be a square \(n, n\) matrix, got shape \(2,\)$"),
    (lambda: OLS(constrained="yes"), r"^OLS: constrained must be True or False, got 'yes'$"),
    (lambda: OLS(solver_options={"max_iter": [1, 2]}), r"^OLS: solver_options: option 'max_iter' must be a number, string or bool, got list$"),
])
def test_hyperparameters_are_checked_at_construction(make, message):
    with pytest.raises(ConfigError, match=message):
        make()


def test_estimators_are_values():
    theta0 = np.array([1.0, 2.0])
    a = RegularizedWLS(theta0=theta0, gamma=0.1, solver_options={"max_iter": 50})
    b = RegularizedWLS(theta0=theta0.copy(), gamma=0.1, solver_options={"max_iter": 50})
    assert a == b and hash(a) == hash(b) and len({a, b, OLS(), OLS()}) == 2
    assert WLS(covariance=np.eye(2)) == WLS(covariance=[[1.0, 0.0], [0.0, 1.0]])


def test_per_equation_gamma_scales_with_the_number_of_equations():
    problem, theta = drag_problem(np.random.default_rng(4), N=40, n=3, noise=0.3)
    theta0 = 1.3 * theta
    relative = RegularizedWLS(theta0=theta0, gamma=0.5, per_equation=True).fit(problem)
    absolute = RegularizedWLS(theta0=theta0, gamma=0.5 * 40 * 3, per_equation=False).fit(problem)
    np.testing.assert_allclose(relative.theta, absolute.theta, rtol=1e-7)
    assert relative.info["gamma"] == pytest.approx(60.0)
