"""The recursive fit against batch references: the package's OLS/WLS on the same samples, the batch fit of a window,
its constrained fit (cvxpy, certified) on the same statistics; the change detector on a payload change and on a log
without one; the ``dualid track`` command."""

import numpy as np
import pinocchio as pin
import pytest

from dualid.errors import ConfigError, ModelError
from dualid.estimators.least_squares import OLS, WLS
from dualid.estimators.newton.objective import statistics
from dualid.estimators.quadratic_fit import fit_quadratic
from dualid.model.rigid_body import RigidBodyModel
from dualid.online import ChiSquareDetector, RecursiveFit, restrict
from dualid.problem import IdentificationProblem

BATCH = 50


def _arm(extra_mass: float = 0.0) -> RigidBodyModel:
    m, parent = pin.Model(), 0
    for j in range(3):
        joint = (pin.JointModelRZ(), pin.JointModelRY(), pin.JointModelRY())[j]
        parent = m.addJoint(parent, joint, pin.SE3(np.eye(3), np.array([0, 0, 0.3 if j else 0.0])), f"j{j}")
        inertia = pin.Inertia(2.0 - 0.4 * j, np.array([0.02, 0.01, 0.12]), np.diag([0.05, 0.04, 0.01]))
        if j == 2 and extra_mass:  # a point payload 0.2 m out along the last link
            inertia = inertia + pin.Inertia(extra_mass, np.array([0.0, 0.0, 0.2]), np.zeros((3, 3)))
        m.appendBodyToJoint(parent, inertia, pin.SE3.Identity())
    return RigidBodyModel(m)


def _samples(seed: int, N: int, model: RigidBodyModel, noise: float = 0.05):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2, 2, size=(N, model.nq))
    v, a = rng.normal(size=(N, model.nv)), rng.normal(size=(N, model.nv))
    tau = model.regressor(q, v, a) @ model.nominal
    return q, v, a, tau + noise * rng.normal(size=tau.shape)


@pytest.fixture(scope="module")
def data():
    model = _arm()
    q, v, a, tau = _samples(3, 700, model)
    whole = IdentificationProblem(model.regressor(q, v, a), tau, model.metric(q), v, model.parameters,
                                  coordinates=model.coordinates)
    return model, (q, v, a, tau), whole


def _run(fit, samples, start=0):
    q, v, a, tau = samples
    steps = []
    for s in range(start, len(q), BATCH):
        steps.append(fit.update(q[s:s + BATCH], v[s:s + BATCH], a[s:s + BATCH], tau[s:s + BATCH]))
    return steps


def _rel(x, y):
    return float(np.max(np.abs(np.asarray(x) - np.asarray(y))) / np.max(np.abs(y)))


def test_without_forgetting_the_recursive_estimate_is_the_batch_ols(data):
    model, samples, whole = data
    fit = RecursiveFit(model.parameters, 1.2 * model.nominal, model=model, free=["j2"])
    _run(fit, samples)
    reference = OLS(constrained=False).fit(restrict(whole, fit.idx, fit.theta0))
    assert _rel(fit.theta[fit.idx], reference.theta) < 1e-10
    assert np.array_equal(fit.theta[:20], fit.theta0[:20])  # the held parameters stay at θ₀


def test_the_held_parameters_are_subtracted_and_the_metric_is_the_full_one(data):
    model, (q, v, a, _), whole = data
    exact = model.regressor(q, v, a) @ model.nominal  # noise-free: the free block is recovered exactly
    start = model.nominal.copy()
    start[20:30] *= 1.5
    fit = RecursiveFit(model.parameters, start, model=model, free=["j2"])
    _run(fit, (q, v, a, exact))
    assert _rel(fit.theta, model.nominal) < 1e-9
    sub = restrict(whole, fit.idx, start)
    theta = start.copy()
    theta[20:30] = model.nominal[20:30]
    assert np.allclose(sub.metric.evaluate(theta[20:30]), whole.metric.evaluate(theta), rtol=1e-12, atol=1e-14)


def test_with_a_given_covariance_it_is_the_batch_wls(data):
    model, samples, whole = data
    S = np.array([[1.0, 0.2, 0.0], [0.2, 2.0, 0.1], [0.0, 0.1, 0.5]])
    fit = RecursiveFit(model.parameters, 1.2 * model.nominal, model=model, free=["j2"], weight="wls", covariance=S)
    _run(fit, samples)
    reference = WLS(constrained=False, covariance=S).fit(restrict(whole, fit.idx, fit.theta0))
    assert _rel(fit.theta[fit.idx], reference.theta) < 1e-10


def test_a_sliding_window_is_the_batch_fit_of_the_window(data):
    model, samples, whole = data
    fit = RecursiveFit(model.parameters, 1.2 * model.nominal, model=model, free=["j2"], window=200)
    _run(fit, samples)
    assert fit.count == 200
    reference = OLS(constrained=False).fit(restrict(whole.subset(slice(500, 700)), fit.idx, fit.theta0))
    assert _rel(fit.theta[fit.idx], reference.theta) < 1e-10


def test_forgetting_weights_each_sample_by_its_age(data):
    model, samples, whole = data
    lam = 0.995
    fit = RecursiveFit(model.parameters, 1.2 * model.nominal, model=model, free=["j2"], forgetting=lam)
    _run(fit, samples)
    sub = restrict(whole, fit.idx, fit.theta0)
    w = np.sqrt(lam ** np.arange(sub.N - 1, -1, -1.0))[:, None]
    A = (sub.Y * w[..., None]).reshape(-1, sub.p)
    assert _rel(fit.theta[fit.idx], np.linalg.lstsq(A, (sub.tau * w).reshape(-1), rcond=None)[0]) < 1e-10


def test_the_projection_is_the_batch_constrained_fit_of_the_statistics(data):
    model, samples, whole = data
    q, v, a, tau = samples
    # a payload-free last link fitted with a biased torque: the unconstrained fit leaves the feasible set
    biased = (q, v, a, tau - 1.5 * whole.Y[:, :, 20] * model.nominal[20])
    fit = RecursiveFit(model.parameters, model.nominal, model=model, free=["j2"], project_every=200)
    _run(fit, biased)
    assert fit.projections >= 3 and fit.projection_failures == 0
    fit.project()
    sub = restrict(whole, fit.idx, fit.theta0)
    sub = IdentificationProblem(sub.Y, biased[3] - (whole.tau - sub.tau), sub.metric, sub.v, sub.parameters)
    assert not sub.parameters.is_consistent(fit.theta[fit.idx])
    reference = fit_quadratic(sub, statistics(sub), method="ols", constrained=True, solver="CLARABEL",
                              solver_options=None, allow_unidentifiable=False)
    assert sub.parameters.is_consistent(fit.consistent[fit.idx])
    f_online = statistics(sub).objective(sub, fit.consistent[fit.idx])
    assert abs(f_online - reference.objective) <= 1e-8 * reference.objective
    assert _rel(fit.consistent[fit.idx], reference.theta) < 1e-5


def _payload_log(seed: int, change: int | None, N: int = 6000):
    before, after = _arm(), _arm(1.0)
    q, v, a, tau = _samples(seed, N, before)
    if change is not None:
        tau[change:] += after.regressor(q[change:], v[change:], a[change:]) @ (after.nominal - before.nominal)
    return before, after, (q, v, a, tau)


def _tracker(model):
    detector = ChiSquareDetector(n=3, window=50, alpha=1e-6, memory=2000, warmup=1000)
    return RecursiveFit(model.parameters, model.nominal, model=model, free=["j2"], time_constant=2000,
                        detector=detector, reset_samples=100)


def test_the_detector_flags_a_payload_and_the_fit_follows_it():
    before, after, samples = _payload_log(11, change=3000)
    fit = _tracker(before)
    steps = _run(fit, samples)
    events = [w[0] for s in steps for w in s.windows if w[2]]
    assert len(events) == 1 and 3000 <= events[0] < 3100  # one event: the fit re-converges, Ŝ is re-learnt
    assert any(s.reset for s in steps)
    assert abs(fit.theta[20] - after.nominal[20]) < 0.05  # the last link's mass: 1.2 kg → 2.2 kg


def test_the_detector_stays_quiet_without_a_change():
    before, _, samples = _payload_log(12, change=None)
    steps = _run(_tracker(before), samples)
    windows = [w for s in steps for w in s.windows]
    assert len(windows) >= 90 and not any(w[2] for w in windows)


def test_the_detector_threshold_is_the_chi_square_quantile():
    from scipy.stats import chi2

    d = ChiSquareDetector(n=7, window=20, alpha=1e-4)
    assert d.threshold == pytest.approx(chi2.isf(1e-4, 140))
    assert d.false_alarm_rate(1000.0) == pytest.approx(1e-4 * 1000 / 20)


def test_after_an_event_the_detector_pauses_and_relearns_the_covariance():
    rng = np.random.default_rng(5)
    d = ChiSquareDetector(n=2, window=20, alpha=1e-6, memory=4000, warmup=400, hold=300)
    assert d.push(rng.normal(size=(400, 2))) == []  # learning Ŝ ≈ I
    quiet = d.push(rng.normal(size=(400, 2)))
    assert len(quiet) == 20 and not any(e for _, _, e in quiet)
    louder = d.push(3.0 * rng.normal(size=(2000, 2)))  # the innovations' covariance ×9 from now on
    events = [i for i, _, e in louder if e]
    assert events == [819]  # the first window of the louder data
    assert louder[1][0] >= 819 + 300 + 400  # nothing tested in the pause (hold) and the re-learning (warmup)
    assert all(z < d.threshold for _, z, _ in louder[1:])
    assert abs(np.median([z for _, z, _ in louder[1:]]) - 40) < 6  # Ŝ learnt afresh: z ~ χ²(n·w = 40) again


def test_the_dm_weight_is_the_noise_model_at_the_frozen_estimate(data):
    model, samples, whole = data
    sigma_tau, sigma_a = 0.01 * np.eye(3), 0.02 * np.eye(3)
    fit = RecursiveFit(model.parameters, model.nominal, model=model, free=["j2"], weight="dm",
                       sigma_tau=sigma_tau, sigma_a=sigma_a)
    _run(fit, samples)  # no projection: every batch weighted at θ₀
    sub = restrict(whole, fit.idx, fit.theta0)
    M = sub.metric.evaluate(fit.theta0[fit.idx])
    L = np.linalg.cholesky(sigma_tau + M @ sigma_a @ M)
    A = np.linalg.solve(L, sub.Y).reshape(-1, sub.p)
    t = np.linalg.solve(L, sub.tau[..., None]).reshape(-1)
    assert _rel(fit.theta[fit.idx], np.linalg.lstsq(A, t, rcond=None)[0]) < 1e-10


def test_bad_settings_are_config_errors(data):
    model = data[0]
    with pytest.raises(ConfigError):
        RecursiveFit(model.parameters, model.nominal, forgetting=1.5)
    with pytest.raises(ConfigError):
        RecursiveFit(model.parameters, model.nominal, forgetting=0.99, window=100)
    with pytest.raises(ConfigError):
        RecursiveFit(model.parameters, model.nominal, weight="dm")
    with pytest.raises(ModelError):
        RecursiveFit(model.parameters, model.nominal, free=["j2.m"])  # part of a block


# --- dualid track ---------------------------------------------------------------------------------------------------

def _track_log(tmp_path, drop: str | None = None):
    import pandas as pd

    from tests.test_bad_inputs import URDF

    urdf = tmp_path / "arm.urdf"
    urdf.write_text(URDF)
    model = RigidBodyModel.from_urdf(urdf)
    q, v, a, tau = _samples(1, 600, model, noise=0.01)
    cols = {f"q_{j}": q[:, j] for j in range(model.nq)}
    for name, x in (("v", v), ("a", a), ("tau", tau)):
        cols.update({f"{name}_{c}": x[:, k] for k, c in enumerate(model.coordinates)})
    cols.pop(drop, None)
    pd.DataFrame(cols).to_parquet(tmp_path / "run.parquet", index=False)
    return ["track", "--model", str(urdf), "--data", str(tmp_path / "run.parquet"), "--out", str(tmp_path / "t.csv"),
            "--batch", "20", "--project-every", "100"], model


def _invoke(args):
    from typer.testing import CliRunner

    from dualid.cli import app

    return CliRunner().invoke(app, args)


def test_track_writes_theta_over_time_and_never_overwrites_without_force(tmp_path):
    import pandas as pd

    args, model = _track_log(tmp_path)
    result = _invoke(args)
    assert result.exit_code == 0, result.output
    table = pd.read_csv(tmp_path / "t.csv")
    assert len(table) == 30 and list(table["samples"])[-1] == 600
    assert {"alarm", "memory_reset", *model.parameters.names} <= set(table.columns)
    assert np.isfinite(table[f"consistent.{model.parameters.names[0]}"].iloc[-1])
    before = (tmp_path / "t.csv").read_bytes()
    again = _invoke(args)
    assert again.exit_code == 2 and "--force" in again.output and len(again.output.strip().splitlines()) == 1
    assert (tmp_path / "t.csv").read_bytes() == before
    assert _invoke(args + ["--force"]).exit_code == 0


def test_track_with_a_missing_column_is_one_line_exit_2(tmp_path):
    args, _ = _track_log(tmp_path, drop="tau_Joint2")
    result = _invoke(args)
    assert result.exit_code == 2
    assert len(result.output.strip().splitlines()) == 1 and "tau_Joint2" in result.output
    assert not (tmp_path / "t.csv").exists()


def test_track_reads_a_csv_log_as_fit_does(tmp_path):
    import pandas as pd

    from tests.test_bad_inputs import URDF, write_log

    urdf = tmp_path / "arm.urdf"
    urdf.write_text(URDF)
    out = tmp_path / "t.parquet"
    result = _invoke(["track", "--model", str(urdf), "--data", str(write_log(tmp_path)), "--out", str(out),
                      "--free", "Joint2"])
    assert result.exit_code == 0, result.output
    table = pd.read_parquet(out)
    assert len(table) >= 5 and table["Joint1.m"].nunique() == 1  # held at the URDF's value
