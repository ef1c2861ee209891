"""Covariance of the base parameters: closed forms for least squares, finite differences for the
dual-metric objective and the log-det prior, active constraints, the bootstrap, and the error messages."""

import numpy as np
import pytest

from dualid import OLS, WLS, BaseUncertainty, DualMetric, NoiseModelDM, RegularizedWLS, base_uncertainty, bootstrap
from dualid.errors import ConfigError, SolverError
from dualid.evaluation.objective_terms import derivatives
from dualid.evaluation.uncertainty import block_labels, run_segments
from dualid.model.consistency import regularizer_value
from dualid.model.metric import AffineMetric
from dualid.model.parameters import ParameterBlock, ParameterSpace
from dualid.problem import IdentificationProblem
from tests.factories import drag_problem


def linear_problem(N=400, p=3, sigma=0.1, seed=0, blocks=()):
    """τ_i = x_iᵀ θ + ε_i, one coordinate, ε ~ N(0, σ²): the textbook regression."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(N, p)) * np.array([1.0, 10.0, 0.1][:p])
    theta = np.array([1.0, -0.5, 2.0][:p])
    tau = X @ theta + sigma * rng.normal(size=N)
    space = ParameterSpace(tuple(f"x{k}" for k in range(p)), ("kg",) * p, blocks)
    problem = IdentificationProblem(X[:, None, :], tau[:, None], AffineMetric(p, (), np.ones((N, 1, 1))),
                                    np.ones((N, 1)), space)
    return problem, X, tau, theta


def test_model_covariance_is_the_textbook_one_for_ols():
    problem, X, tau, _ = linear_problem()
    est = OLS(constrained=False)
    result = est.fit(problem)
    u = base_uncertainty(problem, result, est, kind="model")
    e = tau - X @ result.theta
    textbook = float(e @ e) / (len(tau) - 3) * np.linalg.inv(X.T @ X)
    np.testing.assert_allclose(u.covariance, textbook, rtol=1e-9)
    assert u.values == pytest.approx(result.theta)


def test_sandwich_is_the_robust_closed_form_and_near_textbook_when_homoscedastic():
    problem, X, tau, _ = linear_problem(N=20_000)
    est = OLS(constrained=False)
    result = est.fit(problem)
    u = base_uncertainty(problem, result, est)
    e = tau - X @ result.theta
    bread = np.linalg.inv(X.T @ X)
    hc1 = bread @ (X.T * e**2) @ X @ bread * len(tau) / (len(tau) - 3)
    np.testing.assert_allclose(u.covariance, hc1, rtol=1e-8)
    textbook = float(e @ e) / (len(tau) - 3) * bread
    np.testing.assert_allclose(np.sqrt(np.diag(u.covariance)), np.sqrt(np.diag(textbook)), rtol=0.03)
    q = 1.96  # t with 19,997 dof
    np.testing.assert_allclose(u.upper - u.values, q * u.std_error, rtol=1e-3)


def test_blocks_sum_the_gradients_of_their_samples():
    problem, X, tau, _ = linear_problem(N=100)
    est = OLS(constrained=False)
    result = est.fit(problem)
    labels = block_labels(100, 10)
    _, G, _ = derivatives(problem, result, est, labels)
    e = X @ result.theta - tau
    expected = np.array([2 * X[labels == b].T @ e[labels == b] for b in range(10)])
    np.testing.assert_allclose(G, expected, rtol=1e-10, atol=1e-10)
    assert [len(s) for s in run_segments([5, 7], 2)] == [3, 2, 4, 3]


def test_dm_paper_gradient_and_hessian_match_finite_differences():
    problem, _ = drag_problem(np.random.default_rng(1), N=80, noise=0.05)
    est = DualMetric()
    result = est.fit(problem)
    theta = result.theta + 0.01  # away from the optimum, where the gradient is not zero
    probe = type(result)(result.method, theta, result.parameters, 0.0, "optimal", "test", 0.0)
    H, G, f = derivatives(problem, probe, est, block_labels(problem.N, None))
    assert f == pytest.approx(problem.dual_metric_objective(theta), rel=1e-12)
    h = 1e-6
    eye = np.eye(problem.p)
    fd_grad = np.array([(problem.dual_metric_objective(theta + h * e) - problem.dual_metric_objective(theta - h * e))
                        / (2 * h) for e in eye])
    np.testing.assert_allclose(G.sum(axis=0), fd_grad, rtol=1e-6, atol=1e-6 * np.abs(fd_grad).max())

    def grad(t):
        return derivatives(problem, type(result)(result.method, t, result.parameters, 0.0, "", "", 0.0), est,
                           np.zeros(problem.N, int))[1][0]

    fd_hess = np.array([(grad(theta + h * e) - grad(theta - h * e)) / (2 * h) for e in eye])
    np.testing.assert_allclose(H, fd_hess, rtol=1e-5, atol=1e-6 * np.abs(H).max())


def test_logdet_prior_adds_its_hessian():
    problem, theta_true = drag_problem(np.random.default_rng(2), N=60, noise=0.05)
    est = RegularizedWLS(theta0=theta_true * 1.2, gamma=0.01)
    result = est.fit(problem)
    H, _, _ = derivatives(problem, result, est, block_labels(problem.N, None))
    est0 = WLS(covariance=np.asarray(result.info["covariance_matrix"]))
    H0, _, _ = derivatives(problem, result, est0, block_labels(problem.N, None))
    theta0, h = np.asarray(est.theta0), 1e-5

    def R(t):
        return regularizer_value("logdet", problem.parameters, t, theta0)

    eye = np.eye(problem.p)
    t = result.theta
    fd = np.array([[(R(t + h * a + h * b) - R(t + h * a - h * b) - R(t - h * a + h * b) + R(t - h * a - h * b))
                    / (4 * h * h) for b in eye] for a in eye])
    np.testing.assert_allclose((H - H0) / result.info["gamma"], fd, rtol=1e-4, atol=1e-4 * np.abs(fd).max())


def test_dm_without_acceleration_noise_has_wls_intervals_with_the_same_covariance():
    problem, _ = drag_problem(np.random.default_rng(3), N=200, noise=0.1)
    S = np.diag([0.01, 0.02, 0.03])
    wls, dm = WLS(covariance=S), NoiseModelDM(sigma_tau=S, sigma_a=np.zeros((3, 3)))
    u_wls = base_uncertainty(problem, wls.fit(problem), wls)
    u_dm = base_uncertainty(problem, dm.fit(problem), dm)
    np.testing.assert_allclose(u_dm.covariance, u_wls.covariance, rtol=1e-5)


def test_dm_per_sample_gradients_sum_to_its_objective_gradient():
    """The sandwich's per-sample gradients of dm's objective (noise model fixed) add up to the gradient of
    Σ r_iᵀ(Σ_τ + M_i(θ)Σ_aM_i(θ))⁻¹r_i, checked by central differences at a point away from the optimum."""
    from dualid.estimators.noise_model import noise_model_objective
    from dualid.evaluation.objective_terms import derivatives

    problem, theta = drag_problem(np.random.default_rng(5), N=60, noise=0.1)
    S, A = np.diag([0.01, 0.02, 0.03]), np.diag([0.2, 0.1, 0.3])
    est = NoiseModelDM(sigma_tau=S, sigma_a=A)
    fit = est.fit(problem)
    at = type(fit)("dm", theta * 1.1, fit.parameters, 0.0, "", "", 0.0, noise=fit.noise)
    _, G, _ = derivatives(problem, at, est, np.zeros(problem.N, dtype=int))
    h = 1e-6 * np.maximum(np.abs(at.theta), 1.0)
    fd = [(noise_model_objective(problem, at.theta + h[k] * e, S, A) - noise_model_objective(problem, at.theta - h[k] * e, S, A))
          / (2 * h[k]) for k, e in enumerate(np.eye(problem.p))]
    np.testing.assert_allclose(G[0], fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())


def test_active_bound_makes_the_interval_conditional():
    blocks = (ParameterBlock("friction", "nonnegative", (2,)),)
    problem, X, tau, _ = linear_problem(N=300, blocks=blocks)
    problem = IdentificationProblem(problem.Y, problem.tau - 2.5 * problem.Y[:, :, 2], problem.metric, problem.v,
                                    problem.parameters)  # true x2 = −0.5 < 0: the fit sits on x2 = 0
    est = OLS()
    result = est.fit(problem)
    assert abs(result.theta[2]) < 1e-6
    u = base_uncertainty(problem, result, est, constraints="project")
    assert u.active == ("friction (1 zero eigenvalue)",) and u.conditional
    assert u.std_error[2] < 1e-6 * u.std_error[0]  # no freedom left along x2
    assert u.summary().endswith("conditional on 1 active constraints (friction (1 zero eigenvalue))")
    free = base_uncertainty(problem, result, est)  # the default: detected, recorded, not used
    assert free.active == ("friction (1 zero eigenvalue)",) and not free.conditional
    assert free.std_error[2] > 0.1 * free.std_error[0]
    assert "1 constraints active at the estimate (friction (1 zero eigenvalue)), not used" in free.summary()
    with pytest.raises(ConfigError, match=r"^constraints: expected 'ignore' or 'project', got True$"):
        base_uncertainty(problem, result, est, constraints=True)


def test_bootstrap_is_seeded_and_counts_failures():
    problem, *_ = linear_problem(N=200)
    est = OLS(constrained=False)
    result = est.fit(problem)
    a = bootstrap(problem, result, est, blocks=20, resamples=30, seed=7)
    b = bootstrap(problem, result, est, blocks=20, resamples=30, seed=7)
    np.testing.assert_array_equal(a.covariance, b.covariance)
    assert isinstance(a, BaseUncertainty) and a.failures == 0 and a.resamples == 30

    class Flaky:
        calls = 0

        def fit(self, problem):
            Flaky.calls += 1
            if Flaky.calls % 3 == 0:
                raise SolverError("flaky", status="failed")
            return est.fit(problem)

    c = bootstrap(problem, result, Flaky(), blocks=20, resamples=30, seed=7)
    assert c.failures == 10 and "10 failed refits" in c.summary()


def test_error_messages():
    problem, *_ = linear_problem(N=50)
    est = OLS(constrained=False)
    result = est.fit(problem)
    with pytest.raises(ConfigError, match=r"^uncertainty: 3 blocks for 3 base parameters; the sandwich needs more "
                                          r"blocks than base parameters \(use shorter segments or kind='model'\)$"):
        base_uncertainty(problem, result, est, blocks=3)
    with pytest.raises(ConfigError, match=r"^blocks: expected an integer in 1\.\.50 \(the number of samples\), got 0$"):
        base_uncertainty(problem, result, est, blocks=0)
    with pytest.raises(ConfigError, match=r"^kind: expected 'sandwich' or 'model' \(bootstrap: "):
        base_uncertainty(problem, result, est, kind="jackknife")
    class Custom:
        pass

    with pytest.raises(ConfigError, match=r"^uncertainty: no sandwich for estimator Custom \(method 'x'\); "
                                          r"supported: OLS, WLS, EnergyLS, RegularizedWLS, NoiseModelDM \(dm\), DualMetric "
                                          r"\(dm-paper\); use the block bootstrap \(dualid\.bootstrap; in a fit config: "
                                          r"uncertainty: \{method: bootstrap\}\)$"):
        base_uncertainty(problem, type(result)("x", result.theta, result.parameters, 0.0, "", "", 0.0), Custom())
    with pytest.raises(ConfigError, match=r"^resamples: expected an integer ≥ 10, got 5$"):
        bootstrap(problem, result, est, resamples=5)


def test_fit_config_uncertainty_section():
    from dualid.robot.config import FitConfig
    from dualid.robot.uncertainty import UncertaintyConfig, method_uncertainty

    base = {"model": {"urdf": "robot.urdf"}, "train": ["a.csv"]}
    assert FitConfig.from_dict(base).uncertainty == UncertaintyConfig()
    cfg = FitConfig.from_dict({**base, "uncertainty": {"method": "bootstrap", "blocks": "runs", "resamples": 50}})
    assert cfg.uncertainty == UncertaintyConfig("bootstrap", "runs", None, 50, 0)
    assert cfg.as_dict()["uncertainty"]["method"] == "bootstrap"
    with pytest.raises(ConfigError, match=r"^uncertainty\.method: expected 'sandwich', 'bootstrap' or 'none', "
                                          r"got 'jackknife'$"):
        FitConfig.from_dict({**base, "uncertainty": {"method": "jackknife"}})
    with pytest.raises(ConfigError, match=r"^uncertainty: unknown keys \['level'\]; known keys: "):
        FitConfig.from_dict({**base, "uncertainty": {"level": 0.9}})
    with pytest.raises(ConfigError, match=r"^uncertainty\.resamples: expected an integer ≥ 10, got 3$"):
        UncertaintyConfig(resamples=3)
    problem, *_ = linear_problem(N=60)
    est = OLS(constrained=False)
    result = est.fit(problem)
    base_params = problem.identifiability().base
    unc, why = method_uncertainty(problem, result, est, base_params, [30, 30], UncertaintyConfig(method="none"))
    assert unc is None and why == "not requested (uncertainty.method: none)"
    unc, why = method_uncertainty(problem, result, est, base_params, [30, 30], UncertaintyConfig(blocks="runs"))
    assert unc is None and why.startswith("ConfigError: uncertainty: 2 blocks for 3 base parameters")
    unc, why = method_uncertainty(problem, result, est, base_params, [30, 30],
                                  UncertaintyConfig("bootstrap", "segments", 5, 20, 1))
    assert why == "" and unc.kind == "bootstrap" and unc.blocks == 10 and unc.resamples == 20


def test_a_strong_prior_shrinks_the_intervals():
    # the estimating equation is Σ_b g_b + γ∇R = 0: B is the spread of the g_b around their mean, not around
    # zero (the mean is the prior's pull); uncentred, a strong prior would inflate B by (γ∇R)(γ∇R)ᵀ/K
    problem, theta_true = drag_problem(np.random.default_rng(4), N=200, noise=0.1)
    wls = WLS()
    u_wls = base_uncertainty(problem, wls.fit(problem), wls)
    for gamma, most in ((1e-3, 1.5), (1e5, 0.1)):  # data Hessian ≈ 2e6, γ·N·n·∇²R ≈ 6e7 at 1e5
        est = RegularizedWLS(theta0=theta_true * 1.5, gamma=gamma)
        u = base_uncertainty(problem, est.fit(problem), est)
        assert np.all(u.std_error < most * u_wls.std_error), (gamma, u.std_error / u_wls.std_error)


def test_rank_deficient_problem_reduces_to_its_base_regressor():
    # a planar 2R arm (rank 6 of 20): the textbook covariance of β equals σ̂²(Y_bᵀY_b)⁻¹ of the base regressor
    # Y_b = Y[:, independent] (closed form), and the dm-paper sandwich is finite, symmetric and positive
    from dualid import RigidBodyModel, build_problem
    from dualid.data.trajectory import Trajectory
    from tests.test_base_parameters import planar_2r

    rng = np.random.default_rng(5)
    model = RigidBodyModel(planar_2r(), gravity=(0.0, -9.81, 0.0))
    T = 400
    q, v, a = rng.uniform(-3, 3, (T, 2)), rng.normal(size=(T, 2)), rng.normal(size=(T, 2))
    tau = model.regressor(q, v, a) @ model.nominal + 0.05 * rng.normal(size=(T, 2))
    problem = build_problem(model, Trajectory(t=np.arange(T) * 0.01, q=q, v=v, a=a, tau=tau,
                                              coordinates=model.coordinates))
    base = problem.identifiability().base
    est = OLS(constrained=False, allow_unidentifiable=True)
    result = est.fit(problem)
    u = base_uncertainty(problem, result, est, base, kind="model")
    Yb = base.regressor(problem.Y).reshape(-1, base.rank)
    e = problem.residual(result.theta).reshape(-1)
    np.testing.assert_allclose(u.covariance, float(e @ e) / (e.size - 6) * np.linalg.inv(Yb.T @ Yb), rtol=1e-7)
    dm = DualMetric(allow_unidentifiable=True)
    c = base_uncertainty(problem, dm.fit(problem), dm, base).covariance
    assert np.all(np.isfinite(c)) and np.allclose(c, c.T) and np.linalg.eigvalsh(c)[0] > 0
