"""The statistical-quality benchmark's data generator (dualid.bench.arms) and its method specs.

The true torque is Pinocchio's rnea plus friction and armature; the identification model's regressor
(Pinocchio's joint-torque regressor + joint terms) must reproduce it exactly at θ_true on noise-free,
exactly known states, and must not in the model-error cases. The re-chart must leave the dual-metric
objective unchanged sample by sample.
"""

import importlib.util
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from dualid.bench import arms as sb
from dualid.problem import build_problem


@pytest.fixture(scope="module")
def arm():
    return sb.random_arm(np.random.default_rng(3), 4)


def test_true_parameters_are_consistent_and_not_what_the_model_is_told(arm):
    assert arm.ident.parameters.is_consistent(arm.theta_true, tol=1e-9)
    told = arm.ident.base.nominal  # the CAD-like inertias the identification model carries
    k = slice(0, told.size)
    assert np.linalg.norm(told - arm.theta_true[k]) > 0.05 * np.linalg.norm(arm.theta_true[k])


def test_noise_free_model_torque_is_reproduced_exactly_by_the_identification_model(arm):
    run = sb.make_run(arm, np.random.default_rng(0), 2.0, noise=0.0)
    # independent reference: pin.rnea on the true model plus the joint terms written out here
    data = arm.true_model.createData()
    ref = np.stack([pin.rnea(arm.true_model, data, q, v, a) for q, v, a in zip(run.q, run.v, run.a)])
    ref += arm.viscous * run.v + arm.coulomb * np.tanh(run.v / sb.COULOMB_VELOCITY) + arm.armature * run.a
    assert np.allclose(run.tau_clean, ref, rtol=0, atol=1e-10)
    Y = arm.ident.regressor(run.q, run.v, run.a)
    scale = np.abs(ref).max()
    assert np.abs(Y @ arm.theta_true - ref).max() < 1e-10 * scale
    assert np.abs(run.unmodelled).max() < 1e-10 * scale
    # what the estimators get: quantised q, differentiated v and a close to the commanded ones
    step = 2 * np.pi / 2**sb.ENCODER_BITS
    m = run.measured
    assert np.allclose(m.q / step, np.round(m.q / step), atol=1e-6)
    assert np.abs(m.q - run.q).max() <= step / 2 + 1e-12
    assert np.sqrt(np.mean((m.v - run.v) ** 2)) < 1e-2 * np.sqrt(np.mean(run.v**2))
    assert np.sqrt(np.mean((m.a - run.a) ** 2)) < 5e-2 * np.sqrt(np.mean(run.a**2))
    assert np.array_equal(m.tau, run.tau_clean)


def test_torque_noise_has_the_requested_size(arm):
    clean = sb.make_run(arm, np.random.default_rng(1), 5.0, noise=0.0)
    noisy = sb.make_run(arm, np.random.default_rng(1), 5.0, noise=0.05)
    assert np.array_equal(clean.q, noisy.q)  # same seed, same motion: runs are paired across noise levels
    rel = np.std(noisy.measured.tau - clean.tau_clean, axis=0) / np.sqrt(np.mean(clean.tau_clean**2, axis=0))
    assert np.all(np.abs(rel - 0.05) < 0.01)


@pytest.mark.parametrize("case", sb.MODEL_ERROR_CASES)
def test_model_error_cases_leave_torque_the_model_cannot_explain(arm, case):
    run = sb.make_run(arm, np.random.default_rng(2), 2.0, noise=0.0, case=case, payload=True, case_seed=5)
    ratio = np.sqrt(np.mean(run.unmodelled**2, axis=0) / np.mean(run.inertial**2, axis=0))
    assert ratio.max() > 0.3, (case, ratio)
    again = sb.make_run(arm, np.random.default_rng(2), 2.0, noise=0.0, case=case, payload=True, case_seed=5)
    assert np.array_equal(again.tau_clean, run.tau_clean)  # the case's constants belong to the arm, not the run


def test_payload_only_where_carried_and_sensor_errors_only_in_the_logged_torque(arm):
    off = sb.make_run(arm, np.random.default_rng(2), 2.0, noise=0.0, case="payload", payload=False)
    assert np.abs(off.unmodelled).max() < 1e-9 * np.abs(off.tau_clean).max()
    sensor = sb.make_run(arm, np.random.default_rng(2), 2.0, noise=0.0, case="sensor", case_seed=5)
    assert np.allclose(sensor.tau_phys, off.tau_phys)  # the actuators do the same; only the sensor lies
    assert not np.allclose(sensor.tau_clean, sensor.tau_phys)


def test_rechart_is_configuration_dependent_and_leaves_the_dual_metric_objective_unchanged(arm):
    run = sb.make_run(arm, np.random.default_rng(4), 1.0, noise=0.05)
    problem = build_problem(arm.ident, run.measured)
    B = sb.rechart(np.random.default_rng(5), run.measured.q)
    assert B.shape == (problem.N, problem.n, problem.n)
    assert np.linalg.cond(B).max() < 1e6  # invertible
    assert np.ptp(B, axis=0).max() > 0.02 * np.abs(B).max()  # varies with q
    other = problem.in_coordinates(B)
    rng = np.random.default_rng(6)
    for theta in (arm.theta_true, arm.theta_true * rng.uniform(0.9, 1.1, arm.theta_true.size)):
        f, f_other = problem.dual_metric_objective(theta), other.dual_metric_objective(theta)
        assert np.isfinite(f) and abs(f_other - f) < 1e-9 * f
        assert np.abs(other.residual(theta) - problem.residual(theta)).max() > 1e-3  # OLS's residual does change


def test_metric_eigen_range_is_one_at_the_truth_and_scales(arm):
    q = sb.excitation(np.random.default_rng(7), arm.n, 0.5)[1]
    M = arm.ident.metric(q).evaluate(arm.theta_true)
    assert np.allclose(sb.metric_eigen_range(M, M), (1.0, 1.0))
    lo, hi = sb.metric_eigen_range(3.0 * M, M)
    assert np.isclose(lo, 3.0) and np.isclose(hi, 3.0)


def test_driver_parses_builtin_and_plugin_methods():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "statistical_quality.py"
    spec = importlib.util.spec_from_file_location("statistics_driver", path)
    driver = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(driver)
    label, est = driver.make_method("dualid.estimators.least_squares:OLS")
    assert label == "ols" and est.allow_unidentifiable  # set when the class accepts it
    label, est = driver.make_method('mine=dualid.estimators.dual_metric:DualMetric:{"solver": "cvxpy"}')
    assert label == "mine" and est.solver == "cvxpy"
    assert driver._split_methods('ols,a=m:C:{"x": 1, "y": 2},wls') == ["ols", 'a=m:C:{"x": 1, "y": 2}', "wls"]
    with pytest.raises(ValueError):
        driver.make_method("nonsense")
