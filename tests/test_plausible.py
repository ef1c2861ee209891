"""plausible_parameters: the θ with θ̂'s training predictions closest to a prior in the log-det divergence.

Specifications: (1) when the prior itself predicts like θ̂ (θ₀ − θ̂ in the null space), the answer is
θ₀ (divergence 0); (2) against an independent formulation (θ as the cvxpy variable, equality
Y(θ − θ̂) = 0 on scipy's null space); (3) training predictions unchanged, θ_p consistent; (4) a full-rank
problem returns θ̂; (5) exact error messages; (6) a 7-DoF case: masses the data leave to the
prior land within 30 % of it, where the raw fit's are far off.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from dualid.bench.arms import make_run, random_arm
from dualid.data.trajectory import Trajectory
from dualid.errors import ConfigError, ConsistencyError
from dualid.estimators import OLS
from dualid.evaluation.plausible import DATA, PRIOR, plausible_parameters
from dualid.model.joint_terms import with_joint_terms
from dualid.model.pan_tilt import PanTilt
from dualid.model.rigid_body import RigidBodyModel
from dualid.problem import build_problem

PENDUBOT = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data" / "pendubot_model_2.1.urdf"


def _pendubot_problem(T: int = 60, seed: int = 0):
    rigid = RigidBodyModel.from_urdf(PENDUBOT)
    model = with_joint_terms(rigid)
    rng = np.random.default_rng(seed)
    theta = np.concatenate([rigid.nominal, [0.02, 0.01], [0.08, 0.09], [0.003, 0.004]])
    q, v, a = rng.uniform(-2, 2, (T, 2)), rng.normal(size=(T, 2)), rng.normal(size=(T, 2))
    tau = model.regressor(q, v, a) @ theta
    return model, build_problem(model, Trajectory(np.arange(T) * 0.01, q, v, tau, a, coordinates=model.coordinates)), theta


def test_prior_in_the_slice_is_returned():
    model, problem, theta_true = _pendubot_problem()
    null = problem.identifiability().null_space
    theta_hat = theta_true + null @ np.linspace(3.0, -2.0, null.shape[1])  # same predictions, absurd values
    result = plausible_parameters(problem, theta_hat, theta_true)
    assert result.objective == "logdet" and result.status == "optimal"
    np.testing.assert_allclose(result.theta, theta_true, rtol=1e-5, atol=1e-7)
    assert result.divergence < 1e-8 < result.divergence_hat
    assert result.predictions_unchanged and result.prediction_change < 1e-12 and result.consistent


def test_matches_an_independent_formulation():
    import cvxpy as cp

    model, problem, theta_true = _pendubot_problem(seed=1)
    theta_hat = OLS(allow_unidentifiable=True).fit(problem).theta
    theta0 = theta_true.copy()
    theta0[:20] *= np.repeat([1.25, 0.8], 10)  # a CAD-like prior: body 1 25 % heavy, body 2 20 % light
    result = plausible_parameters(problem, theta_hat, theta0)
    # reference: θ itself the variable, the slice as Y(θ − θ̂) = 0 on scipy's null space of Y
    A = problem.Y.reshape(-1, problem.p)
    s = np.linalg.norm(A, axis=0)
    s[s == 0] = 1
    R = scipy.linalg.orth((A / s).T, rcond=1e-7).T  # the row space, unit-norm columns
    th = cp.Variable(problem.p)
    obj, cons = 0, [R @ cp.multiply(s, th - theta_hat) == 0]
    for b in problem.parameters.blocks:
        V, idx = b.constraint_basis, list(b.indices)
        C0 = np.tensordot(theta0[idx], V, axes=1)
        C = cp.reshape(V.reshape(len(idx), -1).T @ th[idx], V.shape[1:], order="C")
        obj += -cp.log_det(0.5 * (C + C.T)) + cp.trace(np.linalg.inv(C0) @ C)
    reference = cp.Problem(cp.Minimize(obj), cons)
    reference.solve(solver="CLARABEL")
    # the same minimum; the minimiser to 1e-3 (the divergence is nearly flat along Joint1.Ixx + Joint1.Ia)
    const = sum(np.linalg.slogdet(b.constraint_matrix(theta0))[1] - b.constraint_basis.shape[1]
                for b in problem.parameters.blocks)
    # rel 1e-4: with θ̂ the certified OLS fit (estimators.quadratic_newton.polish) Clarabel's reference ends 1.1e-5 above the result
    assert result.divergence == pytest.approx(reference.value + const, rel=1e-4)
    assert result.divergence <= reference.value + const + 1e-9  # never worse than the reference
    np.testing.assert_allclose(result.theta, th.value, rtol=1e-3, atol=1e-6)
    assert result.divergence <= result.divergence_hat
    assert result.predictions_unchanged and result.consistent


def test_which_parameters_the_prior_chose():
    model, problem, theta_true = _pendubot_problem()
    result = plausible_parameters(problem, theta_true, theta_true)
    share = dict(zip(result.names, result.prior_share))
    by = dict(zip(result.names, result.determined_by))
    unident = set(problem.identifiability().unidentifiable)
    assert {n for n, d in by.items() if d == DATA} >= set(problem.parameters.names) - unident
    assert by["Joint1.m"] == PRIOR and share["Joint1.m"] == pytest.approx(1.0)  # no torque depends on it alone
    assert by["Joint1.b"] == DATA and share["Joint1.b"] == 0.0
    assert set(result.by_prior()) <= unident


def test_full_rank_returns_theta_hat():
    model = PanTilt()
    rng = np.random.default_rng(0)
    q, v, a = rng.uniform(-1, 1, (40, 2)), rng.normal(size=(40, 2)), rng.normal(size=(40, 2))
    theta = np.array([0.5, 0.1, 0.2])
    tau = model.regressor(q, v, a) @ theta
    problem = build_problem(model, Trajectory(np.arange(40) * 0.01, q, v, tau, a, coordinates=model.coordinates))
    result = plausible_parameters(problem, theta, [1.0, 1.0, 1.0])
    assert result.status == "full rank" and result.theta.tolist() == theta.tolist()
    assert result.determined_by == (DATA,) * 3 and result.null_space.shape == (3, 0)


def test_errors():
    model, problem, theta = _pendubot_problem()
    bad = theta.copy()
    bad[0] = -1.0
    with pytest.raises(ConsistencyError) as err:
        plausible_parameters(problem, theta, bad)
    assert str(err.value) == ("plausible_parameters: the prior nominal θ₀ is not physically consistent: block 'Joint1' "
                              "has constraint-matrix smallest eigenvalue -1.03; it must be positive definite")
    with pytest.raises(ConfigError) as err:
        plausible_parameters(problem, theta, theta, solver="MOSEK")
    assert str(err.value) == "plausible_parameters: solver must be one of CLARABEL, SCS, got 'MOSEK'"


def test_seven_dof_arm_masses_near_a_cad_prior():
    """A 7-DoF arm, exact data (the regressor's null space is all that is unknown),
    a CAD-like prior (each body's θ scaled by 1 ± 20–30 %, a density error)."""
    rng = np.random.default_rng(7)
    arm = random_arm(rng, 7)
    run = make_run(arm, rng, 4.0, 0.0)
    k = slice(None, None, 8)
    traj = Trajectory(run.measured.t[k], run.q[k], run.v[k], run.tau_clean[k], run.a[k], coordinates=arm.ident.coordinates)
    problem = build_problem(arm.ident, traj)
    p0 = arm.ident.base.parameters.p
    factor = 1 + rng.choice([-1, 1], 7) * rng.uniform(0.2, 0.3, 7)
    prior = arm.theta_true.copy()
    prior[:p0] = (arm.theta_true[:p0].reshape(7, 10) * factor[:, None]).ravel()
    raw = OLS(allow_unidentifiable=True).fit(problem).theta
    prior[p0:] = np.maximum(raw[p0:], 1e-3 * raw[p0:].max())  # joint terms: the fit's own, as dualid fit does
    result = plausible_parameters(problem, raw, prior)
    assert result.predictions_unchanged and result.consistent
    masses = np.arange(0, p0, 10)
    by_prior = [i for i in masses if result.determined_by[i] == PRIOR]
    assert len(by_prior) >= 3
    ratio = result.theta[by_prior] / prior[by_prior]
    assert np.all(np.abs(ratio - 1) <= 0.30), ratio
    raw_ratio = raw[masses] / prior[masses]
    assert raw_ratio.max() > 1.3 or raw_ratio.min() < 0.7  # the raw fit's masses, for contrast


def test_pullback_when_the_data_pin_a_parameter_on_the_boundary():
    """Pan–tilt with the tilt never moving (its damping a null direction) and zero pan damping (the data
    fix b_pan = 0, on the boundary): the log-det divergence is infinite on the whole slice, so the
    quadratic (pullback) expansion chooses, b_tilt goes to the prior and b_pan stays 0."""
    model = PanTilt()
    rng = np.random.default_rng(0)
    T = 50
    q = np.column_stack([rng.uniform(-1, 1, T), np.full(T, 0.4)])
    v = np.column_stack([rng.normal(size=T), np.zeros(T)])
    a = np.column_stack([rng.normal(size=T), np.zeros(T)])
    theta = np.array([0.5, 0.0, 0.3])
    tau = model.regressor(q, v, a) @ theta
    problem = build_problem(model, Trajectory(np.arange(T) * 0.01, q, v, tau, a, coordinates=model.coordinates))
    result = plausible_parameters(problem, theta, [0.4, 0.1, 0.2])
    assert result.objective == "pullback" and result.fallback_used
    assert result.solver_chain.startswith("logdet CLARABEL") and "pullback CLARABEL optimal" in result.solver_chain
    np.testing.assert_allclose(result.theta, [0.5, 0.0, 0.2], atol=1e-7)
    assert result.determined_by == (DATA, DATA, PRIOR) and result.consistent
