"""The simulated Crazyflie–pendulum: true parameters, controller, measurement model, data sets."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from dualid.estimators import OLS
from dualid.evaluation.prediction import forward_dynamics
from dualid.model.rigid_body import RigidBodyModel
from dualid.problem import build_problem
from dualid.systems import crazyflie as cfs
from dualid.systems import crazyflie_model as cfm
from dualid.systems.base import make_system


@pytest.fixture(scope="module")
def exact():
    return cfs.make(seed=0, noise="none", size="small")


@pytest.fixture(scope="module")
def realistic():
    return cfs.make(seed=0, noise="realistic", size="small")


# --- model and numbers --------------------------------------------------------------------------
def test_model_structure():
    model = cfm.build_model()
    assert [model.names[j] for j in range(1, model.njoints)] == ["base", "alpha1", "alpha2"]
    assert (model.nq, model.nv) == (9, 8)
    rbm = RigidBodyModel(model)
    assert rbm.coordinates == ("vx", "vy", "vz", "wx", "wy", "wz", "alpha1", "alpha2")
    assert rbm.parameters.p == 30
    np.testing.assert_allclose(rbm.nominal, cfm.TRUE_THETA)
    np.testing.assert_allclose(cfm.TRUE_THETA[[0, 10, 20]], [0.030, 0.001, 0.008])
    # the quadrotor's inertia about its own CoM is Förster's (the mount adds a point mass below)
    I_com = model.inertias[1].inertia - cfm.MOUNT_MASS * np.diag([0.012**2, 0.012**2, 0.0]) * cfm.CF_MASS / 0.030
    np.testing.assert_allclose(np.diag(I_com), np.diag(cfm.CF_INERTIA), rtol=1e-12)


def test_nominal_is_consistent_and_off_the_truth():
    space = RigidBodyModel(cfm.build_model()).parameters
    assert space.is_consistent(np.array(cfm.TRUE_THETA))
    assert space.is_consistent(np.array(cfm.NOMINAL_THETA))
    assert min(space.consistency_margins(np.array(cfm.NOMINAL_THETA)).values()) > 0
    masses_true, masses_nom = cfm.TRUE_THETA[[0, 10, 20]], cfm.NOMINAL_THETA[[0, 10, 20]]
    assert np.all(np.abs(masses_nom / masses_true - 1) >= 0.09)
    assert np.all(np.abs(masses_nom / masses_true - 1) <= 0.35)
    assert np.linalg.norm(cfm.NOMINAL_THETA - cfm.TRUE_THETA) > 0.05 * np.linalg.norm(cfm.TRUE_THETA)


@settings(max_examples=200, deadline=None)
@given(st.integers(0, cfm.PWM_MAX))
def test_thrust_curve_inverse_round_trips(c):
    assert cfm.inverse_thrust_curve(cfm.thrust_curve(c)) == c


def test_thrust_curve_numbers_and_clamping():
    np.testing.assert_allclose(cfm.thrust_curve(0), 5.484560e-4)
    np.testing.assert_allclose(cfm.thrust_curve(65535), 2.130295e-11 * 65535**2 + 1.032633e-6 * 65535 + 5.484560e-4)
    np.testing.assert_array_equal(cfm.inverse_thrust_curve([-1.0, 0.0, 1.0]), [0, 0, cfm.PWM_MAX])


def test_body_wrench_from_motor_thrusts():
    # a single motor's thrust: force along body z, torque r × f plus the yaw reaction torque
    for i in range(4):
        f = np.zeros(4)
        f[i] = 0.1
        x, y = cfm.MOTOR_XY[i]
        torque = np.cross([x, y, 0.0], [0.0, 0.0, 0.1]) + [0.0, 0.0, cfm.SPIN[i] * cfm.YAW_PER_THRUST * 0.1]
        np.testing.assert_allclose(cfm.body_wrench(f), [0, 0, 0.1, *torque], atol=1e-15)
    np.testing.assert_allclose(np.hypot(*cfm.MOTOR_XY.T), cfm.ARM)


def test_drag_equals_pinocchio_external_force():
    model = cfm.build_model()
    plant = cfs._Plant(model, cfs.CrazyflieNoise(joint_viscous=0.0, joint_coulomb=0.0))
    rng = np.random.default_rng(3)
    q = pin.randomConfiguration(model, -np.ones(9), np.ones(9))
    v, tau = rng.normal(size=8), rng.normal(size=8) * 0.01
    data = model.createData()
    expected = pin.aba(model, data, q, v, tau, plant.external_force(v))
    np.testing.assert_allclose(plant.accel(q, v, tau), expected, rtol=1e-10, atol=1e-10)


def test_shape_angles_recover_the_universal_joint():
    rng = np.random.default_rng(1)
    alpha = rng.uniform(-1.2, 1.2, size=(50, 2))
    R = Rotation.random(50, random_state=2).as_matrix()
    model, data = cfm.build_model(), None
    data = model.createData()
    R_pend = []
    for k in range(50):
        q = np.concatenate([np.zeros(3), Rotation.from_matrix(R[k]).as_quat(), alpha[k]])
        pin.forwardKinematics(model, data, q)
        R_pend.append(data.oMi[3].rotation.copy())
    np.testing.assert_allclose(cfs.shape_angles(R, np.array(R_pend)), alpha, atol=1e-12)


# --- data sets ----------------------------------------------------------------------------------
def test_true_parameters_predict_noiseless_data_exactly(exact):
    model, theta = exact.model, exact.theta_true
    for run in exact.train + exact.test:
        Y = model.regressor(run.q, run.v, run.a)
        scale = np.abs(run.tau).max()
        assert np.abs(Y @ theta - run.tau).max() <= 1e-8 * scale
        a = forward_dynamics(model, theta, run.q, run.v, run.tau)
        np.testing.assert_allclose(a, run.a, atol=1e-8 * np.abs(run.a).max())
        np.testing.assert_array_equal(run.tau[:, 6:], 0.0)


def test_system_data_contract(exact):
    assert exact.name == "crazyflie"
    assert (len(exact.train), len(exact.test)) == (2, 2)
    assert exact.low_data_samples == 20
    assert exact.shape_coordinates == ("alpha1", "alpha2")
    assert exact.slowest_period == max(cfs.REFERENCE_PERIODS)
    run = exact.train[0]
    assert run.coordinates == exact.model.coordinates
    assert run.T == 800 and np.allclose(np.diff(run.t), 0.01)
    np.testing.assert_allclose(np.linalg.norm(run.q[:, 3:7], axis=1), 1.0, atol=1e-12)


def test_time_stamps_match_the_motion(exact):
    # central differences of the positions over the time stamps = R(q) v_lin (Pinocchio's free flyer)
    run = exact.train[0]
    p_dot = (run.q[2:, :3] - run.q[:-2, :3]) / (run.t[2:] - run.t[:-2])[:, None]
    R = Rotation.from_quat(run.q[1:-1, 3:7]).as_matrix()
    v_world = np.einsum("tij,tj->ti", R, run.v[1:-1, :3])
    np.testing.assert_allclose(p_dot, v_world, atol=2e-3 * np.abs(v_world).max())
    alpha_dot = (run.q[2:, 7:] - run.q[:-2, 7:]) / (run.t[2:] - run.t[:-2])[:, None]
    np.testing.assert_allclose(alpha_dot, run.v[1:-1, 6:], atol=2e-2 * np.abs(run.v[:, 6:]).max())


def test_controller_tracks_references_and_pendulum_swings(realistic):
    for run in realistic.train + realistic.test:
        true_q, ref = run.meta["true"]["q"], run.meta["reference"]
        err = np.abs(true_q[:, :3] - ref[:, :3]).max(axis=0)
        assert np.all(err < 0.1), err  # [m]
        yaw = Rotation.from_quat(true_q[:, 3:7]).as_euler("ZYX")[:, 0]
        assert np.abs(np.angle(np.exp(1j * (yaw - ref[:, 3])))).max() < 0.2  # [rad] (25 ms motor lag, pendulum swinging)
        assert np.abs(true_q[:, 7:9]).max() > 0.08  # the pendulum swings (0.1–0.2 rad peaks)
        assert np.all((run.meta["pwm"] >= 0) & (run.meta["pwm"] <= cfm.PWM_MAX))
        np.testing.assert_array_equal(run.meta["pwm"], np.rint(run.meta["pwm"]))


def test_test_runs_start_at_other_phases(realistic):
    starts = np.array([run.meta["reference"][0] for run in realistic.train + realistic.test])
    assert np.min(np.linalg.norm(starts[:, None] - starts[None], axis=-1) + np.eye(len(starts))) > 1e-3


def test_realistic_measurements_are_close_but_not_exact(realistic):
    run = realistic.train[0]
    true = run.meta["true"]
    inner = slice(50, -50)
    for key, rel in (("v", 0.3), ("a", 1.0)):
        err = np.sqrt(np.mean((getattr(run, key) - true[key])[inner] ** 2, axis=0))
        size = np.sqrt(np.mean(true[key][inner] ** 2, axis=0))
        assert np.all(err > 0)
        assert np.all(err[[0, 1, 2, 5]] < rel * size[[0, 1, 2, 5]]), (key, err, size)
    # the measured thrust carries the calibration error: a few per cent off the truth, not more
    ratio = run.tau[inner, 2] / true["tau"][inner, 2]
    assert 0.005 < abs(np.median(ratio) - 1) < 0.06
    np.testing.assert_array_equal(run.tau[:, 6:], 0.0)


def test_ideal_has_exact_states_and_noisy_forces():
    _, train, _, theta = cfs.dataset(seed=4, n_train=1, n_test=0, duration=3.0, noise="ideal")
    run = train[0]
    np.testing.assert_array_equal(run.a, run.meta["true"]["a"])
    noise = run.tau - run.meta["true"]["tau"]
    np.testing.assert_allclose(noise[:, :6].std(axis=0), cfs.CrazyflieNoise.ideal().force_std, rtol=0.2)


def test_seeds_reproduce():
    a = cfs.dataset(seed=7, n_train=1, n_test=0, duration=1.0, noise="realistic")
    b = cfs.dataset(seed=7, n_train=1, n_test=0, duration=1.0, noise="realistic")
    c = cfs.dataset(seed=8, n_train=1, n_test=0, duration=1.0, noise="realistic")
    for ra, rb, rc in zip(a[1] + a[2], b[1] + b[2], c[1] + c[2]):
        for key in ("q", "v", "a", "tau"):
            np.testing.assert_array_equal(getattr(ra, key), getattr(rb, key))
        assert not np.allclose(ra.q, rc.q)


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match=r"noise: expected one of \['ideal', 'none', 'realistic'\], got 'loud'"):
        cfs.make(noise="loud")
    with pytest.raises(ValueError, match=r"size: expected one of \['default', 'small'\], got 'huge'"):
        cfs.make(size="huge")
    with pytest.raises(ValueError, match="duration must be at least 1 s"):
        cfs.dataset(duration=0.5)
    with pytest.raises(ValueError, match=r"cutoff = 0 means exact states and forces, but measurement errors \{'angle_std'"):
        cfs.CrazyflieNoise(angle_std=0.01, position_std=0.0, voltage_std=0.0, gain_error=(0.0, 0.0),
                           motor_spread=0.0, cutoff=0.0)
    with pytest.raises(ValueError, match="force_std: expected 6 non-negative"):
        cfs.CrazyflieNoise.none().with_force_noise((1.0, 2.0))


def test_registered_factory():
    # the registry reaches this module's make (checked through its argument validation, no simulation)
    with pytest.raises(ValueError, match=r"size: expected one of \['default', 'small'\], got 'huge'"):
        make_system("crazyflie", size="huge")


def test_ols_fits_realistic_data_consistently(realistic):
    problem = build_problem(realistic.model, list(realistic.train))
    result = OLS(constrained=True, allow_unidentifiable=True).fit(problem)
    assert realistic.model.parameters.is_consistent(result.theta, tol=1e-7)
    # the fit explains the measured forces about as well as the truth does
    r_fit = np.sum(problem.residual(result.theta) ** 2)
    r_true = np.sum(problem.residual(realistic.theta_true) ** 2)
    assert r_fit <= r_true * (1 + 1e-6)
    np.testing.assert_allclose(result.theta[[0, 10, 20]].sum(), realistic.theta_true[[0, 10, 20]].sum(), rtol=0.1)


def test_base_drag_variant_models_the_rotor_drag():
    from dualid.systems.base import make_system
    from dualid.systems.crazyflie import NOMINAL_DRAG, CrazyflieNoise

    plain = make_system("crazyflie", size="small")
    drag = make_system("crazyflie", size="small", base_drag=True)
    assert drag.model.parameters.p == plain.model.parameters.p + 3
    np.testing.assert_array_equal(drag.theta_true[-3:], CrazyflieNoise().drag)
    np.testing.assert_array_equal(drag.theta_nominal[-3:], NOMINAL_DRAG)
    assert "linear base drag" in drag.description
    # exact states and forces, rotor drag the only effect: the true θ with the drag explains the forces, the
    # rigid model's true θ does not
    import dataclasses

    from dualid.problem import build_problem

    only_drag = dataclasses.replace(CrazyflieNoise.none(), drag=CrazyflieNoise().drag)
    exact = make_system("crazyflie", size="small", noise=only_drag, base_drag=True)
    problem = build_problem(exact.model, list(exact.train))
    rigid = build_problem(plain.model, list(exact.train))
    assert np.abs(problem.residual(exact.theta_true)).max() < 1e-6 * np.abs(problem.tau).max()
    assert np.abs(rigid.residual(exact.theta_true[:-3])).max() > 1e-3 * np.abs(rigid.tau).max()
