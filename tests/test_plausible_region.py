"""plausible_in_region: the θ closest to the prior whose base parameters lie in the fit's confidence region.

Specifications: (1) on a noisy 4-DoF arm the masses the prior determines move toward the prior compared
with the exact-prediction choice, and the divergence is never larger (the exact slice lies inside the
region); (2) the ellipsoid constraint holds at the solution, checked with Σ_β⁻¹ computed here; (3) level
→ 0 keeps θ̂'s training predictions, level 0 is the exact-prediction choice; (4) exact error messages for bad levels;
(5) the choice does not depend on the unit of a parameter; (6) it is the optimum of the same problem stated for
cvxpy and solved by Clarabel (the SDP reference).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.stats

from dualid.bench.arms import make_run, random_arm
from dualid.data.trajectory import Trajectory
from dualid.errors import ConfigError
from dualid.estimators import OLS
from dualid.evaluation.plausible import PRIOR, plausible_parameters
from dualid.evaluation.plausible_region import check_level, plausible_in_region
from dualid.evaluation.uncertainty import base_uncertainty
from dualid.model.joint_terms import with_joint_terms
from dualid.model.rigid_body import RigidBodyModel
from dualid.problem import build_problem
from dualid.robot.uncertainty import training_blocks

PENDUBOT = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data" / "pendubot_model_2.1.urdf"


def _fit(problem):
    est = OLS(allow_unidentifiable=True)
    result = est.fit(problem)
    base = problem.identifiability().base
    return result.theta, base_uncertainty(problem, result, est, base, blocks=training_blocks([problem.N], base.rank))


@pytest.fixture(scope="module")
def noisy_arm():
    """4-DoF random arm, 2 % torque noise, v and a differentiated from 16-bit encoders; CAD-like prior."""
    rng = np.random.default_rng(7)
    arm = random_arm(rng, 4)
    run = make_run(arm, rng, 4.0, 0.02)
    problem = build_problem(arm.ident, run.measured).subset(slice(None, None, 4))
    p0 = arm.ident.base.parameters.p
    prior = arm.theta_true.copy()
    factor = 1 + rng.choice([-1, 1], 4) * rng.uniform(0.2, 0.3, 4)
    prior[:p0] = (arm.theta_true[:p0].reshape(4, 10) * factor[:, None]).ravel()
    theta_hat, unc = _fit(problem)
    prior[p0:] = np.maximum(theta_hat[p0:], 1e-3 * theta_hat[p0:].max())
    return problem, theta_hat, prior, unc, np.arange(0, p0, 10)


def test_masses_move_toward_the_prior_and_the_region_holds(noisy_arm):
    problem, theta_hat, prior, unc, masses = noisy_arm
    exact = plausible_parameters(problem, theta_hat, prior)
    region = plausible_in_region(problem, theta_hat, prior, unc, 0.95)
    assert region.form == "confidence" and region.level == 0.95 and region.consistent
    assert region.radius2 == pytest.approx(scipy.stats.chi2.ppf(0.95, 1))
    # the constraint at the solution, with Σ_β⁻¹ and β = Cθ computed here
    d = unc.base.C @ region.theta - unc.base.C @ theta_hat
    statistic = d @ np.linalg.solve(unc.covariance, d)
    assert statistic <= region.radius2 * (1 + 1e-6)
    assert statistic == pytest.approx(region.statistic, rel=1e-6)
    assert region.divergence <= exact.divergence  # θ̂'s slice lies inside the region
    by_prior = [k for k in masses if region.determined_by[k] == PRIOR and exact.determined_by[k] == PRIOR]
    assert len(by_prior) >= 2
    gap_exact = np.abs(np.log(exact.theta[by_prior] / prior[by_prior]))
    gap_region = np.abs(np.log(region.theta[by_prior] / prior[by_prior]))
    assert np.all(gap_region < gap_exact), (gap_region, gap_exact)
    assert np.max(gap_exact) > np.log(10) > np.max(gap_region)  # 10× off the prior, then within a factor of 10
    # what it costs on the training data: a small fraction of the residual
    assert region.training_rmse_hat < region.training_rmse < 1.01 * region.training_rmse_hat


@pytest.mark.parametrize("consistent,one_run", [(True, True), (False, True), (True, False)])
def test_the_region_choice_is_the_sdp_optimum(noisy_arm, consistent, one_run, monkeypatch):
    """Both ways of solving it: one interior point with the region as a constraint (below REGION_ROWS_MAX rows; this
    arm's region has 36, so the limit is raised here) and the penalised sequence (this arm as it is)."""
    import cvxpy as cp

    import dualid.evaluation.plausible_newton as pn

    from dualid.evaluation.plausible_newton import prior_divergence, prior_terms
    from dualid.model.consistency import cvxpy_constraints

    problem, theta_hat, prior, unc, _ = noisy_arm
    if not consistent:  # the same β̂ (so the same region and optimum) from a θ̂ with a negative mass the data miss
        null = np.linalg.svd(unc.base.C)[2][unc.base.rank:]
        step = null.T @ np.linalg.lstsq(null.T, -np.eye(problem.parameters.p)[0], rcond=None)[0]
        theta_hat = theta_hat + 10 * theta_hat[0] / max(abs(step[0]), 1e-300) * step
        assert theta_hat[0] < 0 and np.allclose(unc.base.C @ theta_hat, unc.base.C @ noisy_arm[1])
    if one_run:
        monkeypatch.setattr(pn, "REGION_ROWS_MAX", 10**6)
    region = plausible_in_region(problem, theta_hat, prior, unc, 0.95)
    expected = ("a region LMI of 36 rows: the penalised sequence; " if not one_run else
                "interior point with the region as a constraint, " if consistent else
                "no strictly feasible start in the region; ")
    assert region.solver_chain.startswith(expected), region.solver_chain
    rigid, quad_idx, quad_w, _ = prior_terms(problem, prior)
    theta = cp.Variable(problem.parameters.p)
    R = 0.5 * cp.sum(cp.multiply(quad_w, cp.square(theta[quad_idx] - prior[quad_idx])))
    for idx, V, _, logdet0, C0inv in rigid:
        k, m, _ = V.shape
        C = cp.reshape(V.reshape(k, m * m).T @ theta[idx], (m, m), order="C")
        R = R - cp.log_det(0.5 * (C + C.T)) + logdet0 + cp.trace(C0inv @ C) - m
    d = unc.base.C @ theta - unc.base.C @ theta_hat
    S = np.linalg.inv(unc.covariance)
    cons = [cp.quad_form(d, 0.5 * (S + S.T)) <= region.radius2, *cvxpy_constraints(theta, problem.parameters)]
    reference = cp.Problem(cp.Minimize(R), cons)
    reference.solve(solver="CLARABEL")
    assert reference.status == "optimal"
    assert region.divergence == pytest.approx(prior_divergence(problem, region.theta, prior))
    rtol = 1e-7 if consistent and one_run else 1e-5  # the penalised sequence stops with the statistic within U_TOL
    assert region.divergence <= reference.value * (1 + rtol)  # the same optimum, not a worse point
    assert reference.value <= region.divergence * (1 + 1e-6)
    assert np.allclose(region.theta, theta.value, rtol=1e-3, atol=1e-6 * np.abs(prior).max())


def _pendubot_problem(seed: int):
    """(problem, θ_true): 80 random states of the DFKI pendubot with joint terms, 0.01 N m torque noise."""
    rigid = RigidBodyModel.from_urdf(PENDUBOT)
    model = with_joint_terms(rigid)
    rng = np.random.default_rng(seed)
    theta_true = np.concatenate([rigid.nominal, [0.02, 0.01], [0.08, 0.09], [0.003, 0.004]])
    T = 80
    q, v, a = rng.uniform(-2, 2, (T, 2)), rng.normal(size=(T, 2)), rng.normal(size=(T, 2))
    tau = model.regressor(q, v, a) @ theta_true + 0.01 * rng.normal(size=(T, 2))
    problem = build_problem(model, Trajectory(np.arange(T) * 0.01, q, v, tau, a, coordinates=model.coordinates))
    return problem, theta_true


def test_level_to_zero_keeps_the_predictions():
    problem, theta_true = _pendubot_problem(2)
    theta_hat, unc = _fit(problem)
    theta0 = theta_true.copy()
    theta0[:20] *= np.repeat([1.25, 0.8], 10)
    exact = plausible_parameters(problem, theta_hat, theta0)
    zero = plausible_in_region(problem, theta_hat, theta0, unc, 0.0)
    assert zero.form == "exact" and zero.theta.tolist() == exact.theta.tolist()
    tiny = plausible_in_region(problem, theta_hat, theta0, unc, 1e-9)
    assert tiny.form == "confidence" and tiny.radius2 < 1e-17
    assert tiny.statistic <= tiny.radius2 * (1 + 1e-6) and tiny.prediction_change < 1e-7  # θ̂'s predictions
    wide = plausible_in_region(problem, theta_hat, theta0, unc, 0.95)
    assert wide.divergence <= tiny.divergence  # the same objective on a larger set


@pytest.mark.parametrize("level", [1.0, -0.1, "high", True, float("nan")])
def test_bad_levels(level):
    with pytest.raises(ConfigError) as err:
        check_level(level)
    assert str(err.value) == ("plausible parameters: level: expected a probability in [0, 1) (0: keep the training "
                              f"predictions exactly), got {level!r}")


def test_invariant_under_a_unit_scaling_of_a_parameter():
    """Joint1.b in N mm s/rad instead of N m s/rad (θ_k × 1000, its regressor column / 1000): the same choice."""
    import dataclasses

    problem, theta_true = _pendubot_problem(3)
    k, s = problem.parameters.index("Joint1.b"), 1000.0
    Y = np.array(problem.Y)
    Y[:, :, k] /= s
    scaled = dataclasses.replace(problem, Y=Y)
    theta0 = theta_true.copy()
    theta0[:20] *= np.repeat([1.25, 0.8], 10)
    theta0_s = theta0.copy()
    theta0_s[k] *= s
    a_, b_ = (plausible_in_region(pr, th, t0, unc, 0.95)
              for pr, t0 in ((problem, theta0), (scaled, theta0_s)) for th, unc in [_fit(pr)])
    back = b_.theta.copy()
    back[k] /= s
    np.testing.assert_allclose(back, a_.theta, rtol=1e-4, atol=1e-8)  # conic-solver accuracy (1.2e-5 seen); a unit bug is ×1000
    np.testing.assert_allclose(b_.prior_share, a_.prior_share, atol=1e-4)  # μ from the solution: solver accuracy
    assert b_.statistic == pytest.approx(a_.statistic, rel=1e-6) and b_.divergence == pytest.approx(a_.divergence, rel=1e-6)


def test_a_region_solve_ending_on_a_heavy_body_is_checked_from_the_prior(noisy_arm, monkeypatch):
    """The region's interior point can stop far out when it starts near θ̂'s completed masses (10¹¹ kg: the data do
    not determine them; simulated Panda). A run ending with a body above HEAVY_RATIO × the prior's moving mass is
    checked against the penalised sequence from the prior: the same convex problem, the lower R is kept."""
    import dualid.evaluation.plausible_newton as pn

    problem, theta_hat, prior, unc, masses = noisy_arm
    monkeypatch.setattr(pn, "REGION_ROWS_MAX", 10**6)  # this arm's region has 36 rows: one run with the region
    honest = plausible_in_region(problem, theta_hat, prior, unc, 0.95)
    real = pn.run_interior_point

    null = np.linalg.svd(unc.base.C)[2][unc.base.rank:]  # a step that moves the first mass, not β: unseen
    step = null.T @ np.linalg.lstsq(null.T, np.eye(problem.parameters.p)[0], rcond=None)[0]

    heavy = 50 * prior[masses].sum()

    def stalled(*args, **kwargs):  # the run returns its optimum with that mass blown up 50× the arm's, β unchanged
        th, Z, z, info = real(*args, **kwargs)
        return th + (heavy - th[0]) / step[0] * step, Z, z, info

    monkeypatch.setattr(pn, "run_interior_point", stalled)
    checked = plausible_in_region(problem, theta_hat, prior, unc, 0.95)
    assert "above 2 × the prior's whole moving mass" in checked.solver_chain
    assert checked.theta[masses].max() < 2 * prior[masses].sum()
    assert checked.statistic <= checked.radius2 * (1 + 1e-4)
    # the penalised sequence reaches the optimum the region's solve finds without the blow-up
    assert checked.divergence == pytest.approx(honest.divergence, rel=1e-4)


def test_a_large_region_falls_back_to_one_run_when_the_sequence_does_not_succeed(noisy_arm, monkeypatch):
    """From REGION_ROWS_MAX rows the penalised sequence goes first; where it fails, or ends outside the region, the
    single run with the region as a constraint is tried last and kept, with the same optimum."""
    import dualid.evaluation.plausible_newton as pn
    from dualid.errors import SolverError

    problem, theta_hat, prior, unc, _ = noisy_arm
    monkeypatch.setattr(pn, "REGION_ROWS_MAX", 10**6)
    one_run = plausible_in_region(problem, theta_hat, prior, unc, 0.95)
    monkeypatch.setattr(pn, "REGION_ROWS_MAX", 32)  # this arm's region has 36 rows
    real = pn._penalised

    def failed(*args, **kwargs):
        raise SolverError("plausible parameters: the interior point failed (injected)", status="failed")

    def outside(*args, **kwargs):
        th, mu, solves, _ = real(*args, **kwargs)
        return th, mu, solves, "outside the region (injected)"

    for injected, why in ((failed, "the penalised sequence failed"), (outside, "the sequence ended outside the region")):
        monkeypatch.setattr(pn, "_penalised", injected)
        kept = plausible_in_region(problem, theta_hat, prior, unc, 0.95)
        assert kept.solver_chain.startswith("a region LMI of 36 rows: the penalised sequence")
        assert kept.solver_chain.endswith(f"iterations: kept ({why})"), kept.solver_chain
        assert kept.divergence == pytest.approx(one_run.divergence, rel=1e-9)
