"""The structure-exploiting Newton solver of the dual-metric problem, against the SDP reference.

Specifications: f's gradient and Hessian against finite differences; the optimum against
``DualMetric(solver="cvxpy")`` (objective within 1e-6 relative, θ when identifiable, predictions Yθ
when not); active constraints; coordinate invariance; the documented errors.
"""

from __future__ import annotations

import re

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dualid import DualMetric
from dualid.errors import MetricError, SolverError, SolverOptionError
from dualid.estimators.newton import dual_metric_derivatives, fit_dual_metric_newton
from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.pan_tilt import PanTilt
from dualid.model.parameters import ParameterBlock, ParameterSpace
from dualid.model.rigid_body import RigidBodyModel
from dualid.problem import IdentificationProblem

SETTINGS = settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# --- instances ----------------------------------------------------------------------------------
def crazyflie_like(point_mass_pendulum: bool = False) -> pin.Model:
    """Free-flyer quadrotor, a universal joint (2 revolute axes) and a pendulum: n = 8, p = 30."""
    model = pin.Model()
    base = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    model.appendBodyToJoint(base, pin.Inertia(0.03, np.zeros(3), np.diag([1.6e-5, 1.6e-5, 2.9e-5])), pin.SE3.Identity())
    a1 = model.addJoint(base, pin.JointModelRX(), pin.SE3(np.eye(3), np.array([0.0, 0.0, -0.02])), "a1")
    model.appendBodyToJoint(a1, pin.Inertia(0.002, np.array([0, 0, -0.005]), np.diag([2e-8, 2e-8, 1e-8])), pin.SE3.Identity())
    a2 = model.addJoint(a1, pin.JointModelRY(), pin.SE3.Identity(), "a2")
    inertia = np.zeros((3, 3)) if point_mass_pendulum else np.diag([6e-5, 6e-5, 1e-7])
    model.appendBodyToJoint(a2, pin.Inertia(0.008, np.array([0, 0, -0.15]), inertia), pin.SE3.Identity())
    return model


def rigid_body_problem(model: pin.Model, N: int, seed: int, noise: float) -> tuple[IdentificationProblem, np.ndarray]:
    """Random states through RigidBodyModel (Pinocchio's regressor; M = Σ_b J_bᵀ G_b J_b, LOCAL Jacobians)."""
    rng = np.random.default_rng(seed)
    pin.seed(seed)
    rb = RigidBodyModel(model)
    q = np.stack([pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq)) for _ in range(N)])
    va = rng.normal(size=(N, 2, model.nv))  # per sample v then a
    v, a = va[:, 0], va[:, 1]
    Y = rb.regressor(q, v, a)
    theta = rb.nominal
    tau = Y @ theta
    tau = tau + noise * np.abs(tau).mean(axis=0) * rng.normal(size=tau.shape)
    return IdentificationProblem(Y, tau, rb.metric(q), np.zeros((N, model.nv)), rb.parameters), theta


def pan_tilt_problem(N, seed, theta, length=0.3, noise=0.05) -> IdentificationProblem:
    rng = np.random.default_rng(seed)
    model = PanTilt(length=length)
    q = rng.uniform(-1.2, 1.2, (N, 2))
    v, a = rng.normal(size=(N, 2)), rng.normal(size=(N, 2))
    Y = model.regressor(q, v, a)
    tau = Y @ theta + noise * rng.normal(size=(N, 2))
    return IdentificationProblem(Y, tau, model.metric(q), v, model.parameters)


def factored_problem(N, n, p, d, seed, noise=0.1, M0=None) -> tuple[IdentificationProblem, np.ndarray]:
    """M_i(θ) = J_iᵀ (Σ θ_k E_k) J_i, E_k random PSD, θ ≥ 0 (a 'nonnegative' block); Y random."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(p, d, d))
    E = A @ np.swapaxes(A, 1, 2) / d
    J = rng.normal(size=(N, d, n)) + 2.0 * np.eye(d, n)  # well-conditioned metrics: an accurate SDP reference
    theta = rng.uniform(0.5, 2.0, p)
    Y = rng.normal(size=(N, n, p))
    tau = Y @ theta + noise * rng.normal(size=(N, n))
    space = ParameterSpace(tuple(f"t{k}" for k in range(p)), ("1",) * p, (ParameterBlock("t", "nonnegative", tuple(range(p))),))
    metric = AffineMetric(p, (MetricTerm(tuple(range(p)), E, J),), M0)
    return IdentificationProblem(Y, tau, metric, np.zeros((N, n)), space), theta


def fit_both(problem, **kw):
    newton = DualMetric(solver="newton", **kw).fit(problem)
    sdp = DualMetric(solver="cvxpy", **kw).fit(problem)
    return newton, sdp


def assert_same_optimum(newton, sdp, problem, rtol=1e-5):
    assert newton.status == "optimal" and newton.solver == "newton" and newton.method == "dual_metric"
    assert newton.info["relative_gap"] <= 1e-9
    # the Newton solution is at least as good as the SDP's (which is accurate to ~1e-8 when it says optimal)
    assert newton.objective <= sdp.objective * (1 + 1e-7)
    # and not far from it when the SDP claims optimality (its own accuracy is the limit). When Clarabel
    # says "optimal_inaccurate" (near-singular M_i at the optimum) it can be far above: only "no worse" holds.
    if sdp.status == "optimal":
        assert sdp.objective - newton.objective <= rtol * sdp.objective
    np.testing.assert_allclose(newton.objective, problem.dual_metric_objective(newton.theta), rtol=1e-10)
    assert problem.parameters.is_consistent(newton.theta, tol=1e-9)


# --- derivatives --------------------------------------------------------------------------------
def test_gradient_and_hessian_match_finite_differences_and_the_hessian_is_exact():
    problem, theta = rigid_body_problem(crazyflie_like(), 12, seed=3, noise=0.3)
    rng = np.random.default_rng(0)
    theta = theta * (1 + 0.1 * rng.normal(size=theta.size))
    der = dual_metric_derivatives(problem, theta)
    scale = np.maximum(np.abs(theta), 1e-6)
    for k in range(problem.p):
        h = 1e-5 * scale[k]
        e = np.zeros(problem.p)
        e[k] = h
        fp = dual_metric_derivatives(problem, theta + e)
        fm = dual_metric_derivatives(problem, theta - e)
        np.testing.assert_allclose((fp.f - fm.f) / (2 * h), der.grad[k], rtol=1e-5, atol=1e-6 * np.abs(der.grad).max())
        # ∂²f/∂θ_k∂θ_l = Σ 2 (Y_k − M_k w)ᵀ M⁻¹ (Y_l − M_l w) is the exact Hessian (M affine in θ)
        np.testing.assert_allclose(
            (fp.grad - fm.grad) / (2 * h), der.hess[:, k], rtol=1e-5, atol=1e-6 * np.abs(der.hess[:, k]).max()
        )
    assert np.linalg.eigvalsh(der.hess)[0] >= -1e-9 * np.abs(der.hess).max()


def test_chunked_passes_equal_one_pass_and_match_the_metric_methods():
    problem, theta = rigid_body_problem(crazyflie_like(), 23, seed=1, noise=0.1)
    one = dual_metric_derivatives(problem, theta, chunk=1000)
    many = dual_metric_derivatives(problem, theta, chunk=5)
    np.testing.assert_allclose(many.f, one.f, rtol=1e-12)
    np.testing.assert_allclose(many.grad, one.grad, rtol=1e-10, atol=1e-12 * np.abs(one.grad).max())
    np.testing.assert_allclose(many.hess, one.hess, rtol=1e-10, atol=1e-12 * np.abs(one.hess).max())
    np.testing.assert_allclose(one.f, problem.dual_metric_objective(theta), rtol=1e-12)
    w = np.random.default_rng(2).normal(size=(problem.N, problem.n))
    Mw, wMw = problem.metric.apply_quad(w, slice(None))
    _, Mk = problem.metric.basis()  # the dense M_ik (N, p, n, n): an independent path
    np.testing.assert_allclose(-Mw, np.einsum("nkij,nj->nik", Mk, w), atol=1e-12)
    np.testing.assert_allclose(wMw, np.einsum("ni,nkij,nj->k", w, Mk, w), rtol=1e-10)


# --- agreement with the SDP ---------------------------------------------------------------------
@SETTINGS
@given(
    seed=st.integers(0, 10_000),
    m=st.floats(0.1, 3.0),
    b_pan=st.floats(0.0, 0.5),
    b_tilt=st.floats(0.0, 0.5),
    length=st.floats(0.1, 1.0),
)
def test_pan_tilt_agrees_with_the_sdp(seed, m, b_pan, b_tilt, length):
    problem = pan_tilt_problem(40, seed, np.array([m, b_pan, b_tilt]), length=length)
    newton, sdp = fit_both(problem)
    assert_same_optimum(newton, sdp, problem)
    np.testing.assert_allclose(newton.theta, sdp.theta, rtol=1e-4, atol=1e-4 * np.abs(sdp.theta).max())


@SETTINGS
@given(seed=st.integers(0, 10_000), n=st.integers(1, 4), p=st.integers(1, 5), extra=st.integers(0, 2))
def test_random_factored_metrics_agree_with_the_sdp(seed, n, p, extra):
    problem, _ = factored_problem(N=30, n=n, p=p, d=n + extra, seed=seed)
    newton, sdp = fit_both(problem)
    assert_same_optimum(newton, sdp, problem)
    if sdp.status == "optimal":
        np.testing.assert_allclose(newton.theta, sdp.theta, rtol=1e-4, atol=1e-4 * np.abs(sdp.theta).max())


def test_floating_base_null_space_same_objective_and_predictions():
    problem, _ = rigid_body_problem(crazyflie_like(), 40, seed=1, noise=0.05)
    assert problem.identifiability().rank == problem.p - 6  # masses and first moments move between bodies
    newton, sdp = fit_both(problem, allow_unidentifiable=True)
    assert_same_optimum(newton, sdp, problem)
    Yn, Ys = problem.Y @ newton.theta, problem.Y @ sdp.theta
    np.testing.assert_allclose(Yn, Ys, atol=1e-4 * np.abs(Ys).max())


def test_point_mass_pendulum_has_an_active_pseudo_inertia_constraint():
    model = crazyflie_like(point_mass_pendulum=True)
    problem, _ = rigid_body_problem(model, 40, seed=0, noise=0.02)
    newton, sdp = fit_both(problem, allow_unidentifiable=True)
    assert_same_optimum(newton, sdp, problem)
    margins = problem.parameters.consistency_margins(newton.theta)
    P = problem.parameters.blocks[2].constraint_matrix(newton.theta)
    assert margins["a2"] <= 1e-6 * np.abs(P).max()  # the pendulum's pseudo-inertia is singular at the optimum
    unconstrained = DualMetric(solver="newton", constrained=False, allow_unidentifiable=True).fit(problem)
    assert unconstrained.objective < newton.objective * (1 - 1e-6)  # the constraint matters


def test_negative_unconstrained_damping_is_clipped_at_zero():
    problem = pan_tilt_problem(60, seed=5, theta=np.array([1.0, -0.2, 0.1]), noise=0.01)
    newton, sdp = fit_both(problem)
    assert_same_optimum(newton, sdp, problem)
    assert 0 <= newton.theta[1] <= 1e-6
    free = DualMetric(solver="newton", constrained=False).fit(problem)
    assert free.theta[1] < -0.1 and free.objective < newton.objective


def test_bounds_are_respected_and_agree_with_the_sdp():
    base = pan_tilt_problem(50, seed=6, theta=np.array([1.0, 0.2, 0.1]))
    space = base.parameters.with_bounds(lower={"m": 1.2}, upper={"b_pan": 0.15})
    problem = IdentificationProblem(base.Y, base.tau, base.metric, base.v, space)
    newton, sdp = fit_both(problem)
    assert_same_optimum(newton, sdp, problem)
    assert newton.theta[0] >= 1.2 and newton.theta[1] <= 0.15


def test_objective_and_minimiser_are_invariant_to_the_chart():
    problem, _ = rigid_body_problem(crazyflie_like(), 40, seed=2, noise=0.05)
    B = np.random.default_rng(3).normal(size=(problem.N, problem.n, problem.n)) + 3 * np.eye(problem.n)
    a = fit_dual_metric_newton(problem)
    b = fit_dual_metric_newton(problem.in_coordinates(B))
    np.testing.assert_allclose(b.objective, a.objective, rtol=1e-8)
    np.testing.assert_allclose(problem.Y @ b.theta, problem.Y @ a.theta, atol=1e-5 * np.abs(problem.Y @ a.theta).max())


def test_unconstrained_problem_is_plain_newton():
    problem, _ = factored_problem(N=25, n=3, p=4, d=3, seed=9)
    free = DualMetric(solver="newton", constrained=False).fit(problem)
    sdp = DualMetric(solver="cvxpy", constrained=False).fit(problem)
    assert free.status == "optimal" and free.info["duality_gap"] == 0.0
    np.testing.assert_allclose(free.objective, sdp.objective, rtol=1e-6)


# --- errors -------------------------------------------------------------------------------------
def test_contradictory_bounds_raise_solver_error_with_status():
    base = pan_tilt_problem(20, seed=0, theta=np.array([1.0, 0.2, 0.1]))
    space = base.parameters.with_bounds(lower={"m": 2.0}, upper={"m": 1.0})
    problem = IdentificationProblem(base.Y, base.tau, base.metric, base.v, space)
    with pytest.raises(SolverError, match=r"the bounds admit no strictly feasible θ: m has lower bound 2 ≥ upper bound 1") as exc:
        DualMetric(solver="newton").fit(problem)
    assert exc.value.status == "infeasible"


def test_bounds_contradicting_physical_consistency_raise_solver_error():
    base = pan_tilt_problem(20, seed=0, theta=np.array([1.0, 0.2, 0.1]))
    space = base.parameters.with_bounds(upper={"m": -0.5})  # m ≥ 0 is the consistency constraint
    problem = IdentificationProblem(base.Y, base.tau, base.metric, base.v, space)
    with pytest.raises(SolverError, match=r"admit no strictly feasible θ \(phase-I margin") as exc:
        DualMetric(solver="newton").fit(problem)
    assert exc.value.status == "infeasible"


def test_metric_that_no_theta_makes_positive_definite_raises_metric_error():
    N, n = 20, 2
    M0 = np.zeros((N, n, n))
    M0[7] = -np.eye(n)  # sample 7: a negative-definite constant part ...
    problem, _ = factored_problem(N, n, 2, 2, seed=1, M0=M0)
    J = np.array(problem.metric.terms[0].J)
    J[7] = 0.0  # ... that no parameter can change
    metric = AffineMetric(2, (MetricTerm((0, 1), problem.metric.terms[0].E, J),), M0)
    problem = IdentificationProblem(problem.Y, problem.tau, metric, problem.v, problem.parameters)
    with pytest.raises(MetricError, match=r"no θ satisfying the constraints makes M_i\(θ\) positive definite at samples \[7\]"):
        DualMetric(solver="newton").fit(problem)


def test_iteration_limit_raises_solver_error_naming_the_gap():
    problem, _ = rigid_body_problem(crazyflie_like(), 30, seed=0, noise=0.05)
    with pytest.raises(SolverError, match=r"no convergence in 2 iterations; relative gap reached [0-9.e+-]+ \(duality gap") as exc:
        fit_dual_metric_newton(problem, max_iter=2)
    assert exc.value.status == "max_iterations"


def test_unknown_solver_name():
    problem = pan_tilt_problem(20, seed=0, theta=np.array([1.0, 0.2, 0.1]))
    with pytest.raises(SolverOptionError, match=r"solver must be one of \('newton', 'cvxpy'\), got 'qp'"):
        DualMetric(solver="qp").fit(problem)


def test_warm_start_from_a_subsample_starts_at_its_optimum_and_reaches_the_same_optimum():
    problem, _ = rigid_body_problem(crazyflie_like(), 200, seed=7, noise=0.05)
    cold = fit_dual_metric_newton(problem, warm_start_samples=0)
    warm = fit_dual_metric_newton(problem, warm_start_samples=25)
    assert re.fullmatch(r"warm start from 25 samples \(\d+ iterations\)", warm.info["start"])  # no fallback
    # the full solve starts at the subsample's optimum: f there, from an independent SDP fit of the
    # same strided subsample (the warm start solves it to WARM_TOL = 1e-6 only, hence rtol)
    sub = problem.subset(slice(0, None, problem.N // 25))
    theta_sub = DualMetric(solver="cvxpy", allow_unidentifiable=True).fit(sub).theta
    f_sub = dual_metric_derivatives(problem, theta_sub, 0, 4096).f
    assert warm.info["objective_start"] == pytest.approx(f_sub, rel=1e-4)
    assert warm.info["objective_start"] < cold.info["objective_start"]
    assert warm.info["iterations"] < cold.info["iterations"]  # 6 against 11 when measured
    assert warm.info["relative_gap"] <= 1e-9
    np.testing.assert_allclose(warm.objective, cold.objective, rtol=1e-8)
    np.testing.assert_allclose(problem.Y @ warm.theta, problem.Y @ cold.theta, atol=1e-5 * np.abs(problem.Y @ cold.theta).max())


def test_the_default_warm_start_begins_at_eight_thousand_samples_and_keeps_the_optimum():
    """From N = 8 × MIN_WARM = 8,000 samples the fit starts from an eighth of them (1,000 here)."""
    problem, _ = rigid_body_problem(crazyflie_like(), 8000, seed=3, noise=0.05)
    cold = fit_dual_metric_newton(problem, warm_start_samples=0)
    warm = fit_dual_metric_newton(problem)
    assert re.fullmatch(r"warm start from 1000 samples \(\d+ iterations\)", warm.info["start"])
    assert warm.info["iterations"] < cold.info["iterations"]
    np.testing.assert_allclose(warm.objective, cold.objective, rtol=1e-8)
    np.testing.assert_allclose(problem.Y @ warm.theta, problem.Y @ cold.theta, atol=1e-5 * np.abs(problem.Y @ cold.theta).max())
    below = problem.subset(slice(0, 7992))
    assert "warm" not in fit_dual_metric_newton(below).info["start"]


def test_a_large_subsample_is_itself_warm_started_and_the_optimum_is_the_same(monkeypatch):
    """The subsample's solve is the same procedure: large enough (here with MIN_WARM lowered to 100: one nested
    level on 4,000 samples; by default from N = 64,000 on), it starts from its own strided subsample."""
    import dualid.estimators.newton.fit as newton_fit

    monkeypatch.setattr(newton_fit, "MIN_WARM", 100)
    problem, _ = rigid_body_problem(crazyflie_like(), 4000, seed=7, noise=0.05)
    cold = fit_dual_metric_newton(problem, warm_start_samples=0)
    warm = fit_dual_metric_newton(problem, warm_start_samples=800)
    assert re.fullmatch(r"warm start from 800 samples \(\d+ iterations\), itself from a warm start from 100 samples "
                        r"\(\d+ iterations\)", warm.info["start"])
    assert warm.info["relative_gap"] <= 1e-9
    np.testing.assert_allclose(warm.objective, cold.objective, rtol=1e-8)
    np.testing.assert_allclose(problem.Y @ warm.theta, problem.Y @ cold.theta, atol=1e-5 * np.abs(problem.Y @ cold.theta).max())


def test_a_failed_warm_start_is_recorded_and_the_cold_start_runs():
    problem, _ = rigid_body_problem(crazyflie_like(), 60, seed=7, noise=0.05)
    cold = fit_dual_metric_newton(problem, warm_start_samples=0)
    warm = fit_dual_metric_newton(problem, warm_start_samples=12)
    # 12 of 60 samples is a harsh warm start: the full solve from it jams, and the cold start runs
    assert re.fullmatch(r"warm start from 12 samples \(\d+ iterations\) failed \(max_iterations\); .+", warm.info["start"])
    assert warm.info["start"].endswith("; " + cold.info["start"])
    assert warm.info["iterations"] == cold.info["iterations"]
    np.testing.assert_allclose(warm.objective, cold.objective, rtol=1e-8)


def test_unconstrained_null_space_is_handled_without_failing():
    problem, _ = rigid_body_problem(crazyflie_like(), 40, seed=8, noise=0.05)
    newton = DualMetric(solver="newton", constrained=False, allow_unidentifiable=True).fit(problem)
    sdp = DualMetric(solver="cvxpy", constrained=False, allow_unidentifiable=True).fit(problem)
    assert newton.status == "optimal"
    assert abs(newton.objective - sdp.objective) <= 1e-6 * sdp.objective
    np.testing.assert_allclose(problem.Y @ newton.theta, problem.Y @ sdp.theta, atol=1e-4 * np.abs(problem.Y @ sdp.theta).max())
