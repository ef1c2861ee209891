"""dm's conic reference (``NoiseModelDM(solver="cvxpy")``, estimators.noise_cvxpy.solve_noise_model_cvxpy): majorize–
minimize, each step a batched SDP for the convex majorizer g_k of f(θ) = Σ r_iᵀ (Σ_τ + M_i Σ_a M_i)⁻¹ r_i.

Specifications: (1) g_k ≥ f everywhere, g_k = f at θ_k, and ∇g_k = ∇f there (so a fixed point is a stationary point
of f); (2) every step decreases f (within the conic solver's accuracy); (3) from the same start the reference ends at
the interior point's optimum, with the noise levels fixed: on an identifiable drag model in f and θ, on a 3-DoF rigid
arm (rank 25 of 39, one mass projected out by the closure) in f and the predictions Yθ; (4) a conic optimum on a consistency boundary is returned strictly inside (the closure's completion needs it);
(5) the cvxpy form of a feasible set holds exactly where the set's margin is positive; (6) solver names are checked.

Tolerances. The reference stops when a step lowers f by less than tol·f = 1e-9·f; its steps are Clarabel solves with
relative gaps of 1e-10 (``optimal_inaccurate`` near 1e-8 on the arm), and the interior point's own tolerance is 1e-9:
so the two optima agree to about 1e-8 in f (measured: 2e-11 on the drag model, 2e-10 on the arm), asserted at 1e-6.
f is flat at the optimum, so θ agrees only to about √(1e-8·cond): measured 1.5e-6 (drag) and Yθ 2.5e-7 (arm),
asserted at 1e-5 and 1e-4.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from dualid.bench.arms import excitation, random_arm
from dualid.data.trajectory import Trajectory
from dualid.estimators.methods import make_estimator
from dualid.estimators.noise_model import noise_model_covariance, noise_model_derivatives, noise_model_objective
from dualid.estimators.noise_cvxpy import majorizer_blocks, solve_noise_model_cvxpy
from dualid.estimators.noise_dm import NoiseModelDM
from dualid.model.closure import on_closure
from dualid.model.consistency import central_point, cvxpy_feasible_set, feasible_set
from dualid.problem import build_problem
from tests.factories import drag_problem
from tests.test_noise_dm import eiv_problem, rel

SETTINGS = settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _psd(rng, n, rank, scale):
    B = rng.standard_normal((n, rank))
    return scale * B @ B.T / rank


def _arm(seed):
    """A random 3-DoF arm with joint friction and armature (bench.arms), 200 exact states; the regressor built from
    accelerations with noise 5 % of their rms, τ with noise 5 % of its rms: (problem, Σ_τ, Σ_a, θ_true)."""
    rng = np.random.default_rng(seed)
    arm = random_arm(rng, 3)
    t, q, v, a = excitation(rng, 3, 1.0)
    tau = arm.torque(q, v, a)
    s_tau, s_a = 0.05 * np.sqrt(np.mean(tau**2, axis=0)), 0.05 * np.sqrt(np.mean(a**2, axis=0))
    traj = Trajectory(t, q, v, tau + s_tau * rng.standard_normal(tau.shape), a=a + s_a * rng.standard_normal(a.shape),
                      coordinates=arm.ident.coordinates)
    return build_problem(arm.ident, traj), np.diag(s_tau**2), np.diag(s_a**2), arm.theta_true


@pytest.fixture(scope="module")
def rigid_arm():
    return _arm(2)


def majorizer_value(problem, theta, theta_k, sigma_tau, sigma_a) -> float:
    """g_k(θ) = Σ r_iᵀ (Σ_τ + L_k,i(θ))⁻¹ r_i ≥ f(θ) (``majorizer_blocks``); +inf where a block is not positive
    definite."""
    A0, Aj = majorizer_blocks(problem, theta_k, sigma_tau, sigma_a)
    try:
        L = np.linalg.cholesky(A0 + np.einsum("j,ijab->iab", theta, Aj))
    except np.linalg.LinAlgError:
        return np.inf
    z = np.linalg.solve(L, problem.residual(theta)[..., None])
    return float(np.sum(z * z))


def _closed(problem):
    """The feasible set closed over the parameters f cannot see (as dm's fit does) and its completion."""
    Y, tau = problem.Y.reshape(-1, problem.p), problem.tau.reshape(-1)
    return on_closure(feasible_set(problem.parameters), Y.T @ Y, float(tau @ tau), problem.parameters.names)


@SETTINGS
@given(seed=st.integers(0, 10_000), spread=st.floats(0.01, 1.0), constant=st.booleans(), rank=st.integers(1, 3))
def test_the_majorizer_bounds_f_touches_it_and_is_tangent_at_theta_k(seed, spread, constant, rank):
    """g_k(θ) ≥ f(θ) at random θ (g_k = ∞ where Σ_τ + L_k(θ) is not positive definite), g_k(θ_k) = f(θ_k) and
    ∇g_k(θ_k) = ∇f(θ_k), for full and singular Σ_a and with a constant part M_0 of the metric. Tolerances: f and g_k
    are rounding × cond C_i (Σ_τ small against M Σ_a M): over 600 such cases (cond ≤ ~1e7) the equality held to
    2.1e-9 and the gradients (∇g_k = Σ 2 Y_iᵀw_i − w_iᵀ A_ij w_i, w_i = A_i⁻¹ r_i, against ``noise_objective``'s ∇f)
    agreed to 7e-9; seed 1053 (cond 1.8e8) to 3.5e-8. So f's tolerance is max(1e-8, 1e-15 × max cond C_i)."""
    rng = np.random.default_rng(seed)
    problem, theta = drag_problem(rng, N=20, n=3)
    if constant:
        M0 = np.stack([_psd(rng, 3, 3, 0.5) for _ in range(problem.N)])
        problem = replace(problem, metric=replace(problem.metric, M0=M0))
    S, A = _psd(rng, 3, 3, 0.01), _psd(rng, 3, rank, 0.1)
    theta_k = theta * rng.uniform(0.5, 1.5, theta.shape)
    f_k = noise_model_objective(problem, theta_k, S, A)
    tol = max(1e-8, 1e-15 * float(np.linalg.cond(noise_model_covariance(problem.metric.evaluate(theta_k), S, A)).max()))
    assert majorizer_value(problem, theta_k, theta_k, S, A) == pytest.approx(f_k, rel=tol)
    finite = 0
    for _ in range(20):
        th = theta_k * (1 + spread * 10 ** rng.uniform(-3, 0) * rng.standard_normal(theta.shape))
        g, f = majorizer_value(problem, th, theta_k, S, A), noise_model_objective(problem, th, S, A)
        assert g >= f * (1 - tol)
        finite += np.isfinite(g)
    assume(finite > 0)  # else every sampled θ left the majorizer's domain (seed 1053: cond C_i 1.8e8)
    A0, Aj = majorizer_blocks(problem, theta_k, S, A)
    w = np.linalg.solve(A0 + np.einsum("j,ijab->iab", theta_k, Aj), problem.residual(theta_k)[..., None])[..., 0]
    grad_g = 2 * np.einsum("iaj,ia->j", problem.Y, w) - np.einsum("ia,ijab,ib->j", w, Aj, w)
    assert rel(grad_g, noise_model_derivatives(problem, theta_k, S, A, order=1).grad) < 1e-7


@pytest.mark.parametrize("seed", [0, 1])
def test_cvxpy_reaches_the_interior_points_optimum_on_an_identifiable_model(seed):
    problem, _ = eiv_problem(seed, N=200)
    S, A = np.eye(3) * 0.0025, np.eye(3) * 0.09
    newton = NoiseModelDM(sigma_tau=S, sigma_a=A).fit(problem)
    cvx = NoiseModelDM(sigma_tau=S, sigma_a=A, solver="cvxpy").fit(problem)
    assert newton.noise.choice == cvx.noise.choice == "noise model"
    assert (newton.solver, cvx.solver) == ("newton", "cvxpy-mm/CLARABEL")
    assert rel(cvx.objective, newton.objective) < 1e-6
    assert rel(cvx.theta, newton.theta) < 1e-5


def test_cvxpy_reaches_the_interior_points_optimum_on_a_rigid_arm(rigid_arm):
    problem, S, A, _ = rigid_arm
    newton = NoiseModelDM(sigma_tau=S, sigma_a=A, allow_unidentifiable=True).fit(problem)
    cvx = NoiseModelDM(sigma_tau=S, sigma_a=A, allow_unidentifiable=True, solver="cvxpy").fit(problem)
    assert newton.noise.choice == cvx.noise.choice == "noise model"
    assert rel(cvx.objective, newton.objective) < 1e-6
    assert rel(problem.Y @ cvx.theta, problem.Y @ newton.theta) < 1e-4  # θ itself is not unique (rank 25 of 39)
    assert cvx.info["projected_parameters"].startswith("j0.m = ") and cvx.is_consistent


def test_every_step_decreases_f(rigid_arm):
    """On the closed set dm solves on, from a central point of least squares: f falls at every step (to the conic
    solver's accuracy; only the last, rejected step may not), the first steps by far more, and the run converges."""
    problem, S, A, _ = rigid_arm
    cons, _ = _closed(problem)
    start = central_point(np.linalg.lstsq(problem.Y.reshape(-1, problem.p), problem.tau.reshape(-1), rcond=None)[0],
                          cons)
    theta, info = solve_noise_model_cvxpy(problem, cons, start, S, A)
    f = np.array(info["history"])
    assert info["status"].startswith("converged") and len(f) == info["iterations"] + 1 >= 4
    steps = np.diff(f)
    if info["status"] == "converged: no decrease":  # the last step was rejected: f did not fall there
        steps = steps[:-1]
    assert np.all(steps <= 1e-8 * f[1:len(steps) + 1])  # Clarabel stops at relative gaps near 1e-8 here
    assert f[1] < 0.5 * f[0] and f[2] < f[1] * (1 - 1e-6)
    assert info["objective"] == pytest.approx(min(f), rel=1e-9)
    assert cons.margin(theta) > 0


def test_a_conic_optimum_on_the_boundary_ends_strictly_inside_and_completes():
    """With Σ_a = 0 (WLS: g_k = f, one step) this arm's optimum is on a closed block's boundary, where Clarabel's θ was
    outside by 6e-10 (relative); the θ returned is inside, and the closure's completion of j0.m succeeds."""
    problem, S, _, _ = _arm(0)
    cons, done = _closed(problem)
    start = central_point(np.linalg.lstsq(problem.Y.reshape(-1, problem.p), problem.tau.reshape(-1), rcond=None)[0],
                          cons)
    theta, info = solve_noise_model_cvxpy(problem, cons, start, S, np.zeros((3, 3)))
    assert info["iterations"] <= 3 and cons.margin(theta) > 0
    completed, note = done(theta, {})
    assert note["projected_names"] == ["j0.m"] and problem.parameters.is_consistent(completed)


def test_the_cvxpy_form_of_a_feasible_set_is_the_set(rigid_arm):
    """cvxpy_feasible_set holds where FeasibleSet.margin > 0 and not where it is < 0: on the arm's set with a margin
    (every block's C0 ≠ 0, rows θ_k ≥ 0.3 θ_true,k) and on that set closed over j0.m (a compressed block)."""
    import cvxpy as cp

    problem, _, _, theta = rigid_arm
    Y, tau = problem.Y.reshape(-1, problem.p), problem.tau.reshape(-1)
    shifted = feasible_set(problem.parameters.with_margin(theta, 0.3))
    closed, _ = on_closure(shifted, Y.T @ Y, float(tau @ tau))
    assert len(closed.lmis[0].C0) == 3 and np.any(closed.lmis[0].C0) and len(shifted.h) == 9
    rng = np.random.default_rng(0)
    x = cp.Variable(problem.p)
    for cons in (shifted, closed):
        constraints, seen = cvxpy_feasible_set(x, cons), set()
        for _ in range(60):
            x.value = theta * (1 + 10 ** rng.uniform(-4, 0) * rng.standard_normal(theta.shape))
            margin = cons.margin(x.value)
            if abs(margin) > 1e-6:
                assert all(c.value(tolerance=1e-9) for c in constraints) == (margin > 0)
                seen.add(bool(margin > 0))
        assert seen == {True, False}


def test_scs_is_selectable():
    problem, _ = eiv_problem(0, N=100)
    S, A = np.eye(3) * 0.0025, np.eye(3) * 0.09
    scs = NoiseModelDM(sigma_tau=S, sigma_a=A, solver="cvxpy", cvxpy_solver="SCS").fit(problem)
    assert scs.solver == "cvxpy-mm/SCS"
    assert rel(scs.objective, NoiseModelDM(sigma_tau=S, sigma_a=A).fit(problem).objective) < 1e-6


def test_the_method_table_passes_the_solver_names_to_dm():
    assert make_estimator("dm", options={"solver": "cvxpy"}).solver == "cvxpy"
