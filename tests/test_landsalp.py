"""LandSalp model and simulator: kinematics against independent references, the drag identity
τ = M(q) v, exact recovery from noiseless data, reproducibility, estimators and gait directions."""

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dualid.errors import DataError
from dualid.estimators import OLS, DualMetric, EnergyLS
from dualid.evaluation.prediction import forward_dynamics
from dualid.model import Model
from dualid.model.landsalp import LINK_LENGTH, LandSalpModel, configuration
from dualid.problem import build_problem
from dualid.systems import landsalp as sim
from dualid.systems.base import make_system

MODEL = LandSalpModel()
THETA = sim.TRUE_THETA


def _random_q(rng, T):
    return configuration(
        rng.uniform(-1, 1, T), rng.uniform(-1, 1, T), rng.uniform(-np.pi, np.pi, T),
        rng.uniform(-1.5, 1.5, T), rng.uniform(-1.5, 1.5, T),
    )


def _wheel_pose(q):
    """World (x, y, heading) of the three wheel frames, from framesForwardKinematics only."""
    model = MODEL.pinocchio_model
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    out = []
    for fid in MODEL.wheel_frames:
        M = data.oMf[fid]
        out.append((M.translation[0], M.translation[1], np.arctan2(M.rotation[1, 0], M.rotation[0, 0]), M.rotation[:2, :2]))
    return out


def test_protocol_and_shapes():
    assert isinstance(MODEL, Model)
    assert MODEL.kind == "drag" and MODEL.coordinates == ("x", "y", "theta", "alpha1", "alpha2")
    assert MODEL.parameters.p == 11
    assert [b.kind for b in MODEL.parameters.blocks] == ["drag_diagonal"] * 3 + ["nonnegative"]
    q = _random_q(np.random.default_rng(0), 4)
    assert MODEL.regressor(q, np.ones((4, 5)), None).shape == (4, 5, 11)
    assert np.all(MODEL.bias_regressor(q, np.ones((4, 5))) == 0)


def test_wheel_jacobians_match_finite_differences_of_forward_kinematics():
    """J_b v = wheel-frame velocity obtained by differentiating wheel poses along q ⊕ εv (central)."""
    rng = np.random.default_rng(1)
    model = MODEL.pinocchio_model
    q = _random_q(rng, 5)
    J = MODEL.wheel_jacobians(q)
    eps = 1e-6
    for i in range(5):
        v = rng.standard_normal(5)
        plus = _wheel_pose(pin.integrate(model, q[i], eps * v))
        minus = _wheel_pose(pin.integrate(model, q[i], -eps * v))
        for b in range(3):
            dx = (np.array(plus[b][:2]) - np.array(minus[b][:2])) / (2 * eps)
            dphi = np.angle(np.exp(1j * (plus[b][2] - minus[b][2]))) / (2 * eps)
            R = _wheel_pose(q[i])[b][3]
            expected = np.concatenate([R.T @ dx, [dphi]])
            np.testing.assert_allclose(J[i, b] @ v, expected, atol=1e-7)


def test_straight_chain_closed_form():
    """Straight chain: wheel b velocity = R(φ_b)ᵀ [vx − ω y_b + …, vy + ω x_b + lever·α̇, ω + α̇] by hand."""
    L = LINK_LENGTH
    J = MODEL.wheel_jacobians(configuration(0.3, -0.2, 1.0, 0.0, 0.0))[0]
    link = np.array(
        [
            [[1, 0, 0, 0, 0], [0, 1, -L, -L / 2, 0], [0, 0, 1, 1, 0]],  # link 1, centre at −L, joint at −L/2
            [[1, 0, 0, 0, 0], [0, 1, 0, 0, 0], [0, 0, 1, 0, 0]],
            [[1, 0, 0, 0, 0], [0, 1, L, 0, L / 2], [0, 0, 1, 0, 1]],  # link 3, centre at +L
        ],
        dtype=float,
    )
    for b, phi in enumerate(np.deg2rad([-57.0, -130.0, -57.0])):
        c, s = np.cos(phi), np.sin(phi)
        Rt = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])
        np.testing.assert_allclose(J[b], Rt @ link[b], atol=1e-12)


def test_metric_is_sum_of_wheel_drags_plus_joint_damping_and_regressor_is_M_v():
    rng = np.random.default_rng(2)
    q, v = _random_q(rng, 20), rng.standard_normal((20, 5))
    J = MODEL.wheel_jacobians(q)
    D = [np.diag(THETA[3 * b : 3 * b + 3]) for b in range(3)]
    M_ref = sum(np.swapaxes(J[:, b], 1, 2) @ D[b] @ J[:, b] for b in range(3)) + np.diag([0, 0, 0, *THETA[9:]])
    M = MODEL.metric(q).evaluate(THETA)
    np.testing.assert_allclose(M, M_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(MODEL.regressor(q, v, None) @ THETA, np.einsum("tij,tj->ti", M, v), atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(
    st.floats(-1.5, 1.5), st.floats(-1.5, 1.5), st.floats(-3, 3), st.floats(-5, 5), st.floats(-5, 5),
    st.lists(st.floats(1e-3, 100.0), min_size=11, max_size=11),
)
def test_metric_depends_on_shape_only_and_is_positive_definite(a1, a2, heading, x, y, theta):
    theta = np.array(theta)
    M = MODEL.metric(configuration([x, 0.0], [y, 0.0], [heading, 0.0], a1, a2)).evaluate(theta)
    np.testing.assert_allclose(M[0], M[1], rtol=1e-10, atol=1e-10)
    assert np.linalg.eigvalsh(M[0])[0] > 0


def test_generalized_force_is_wheel_jacobian_transpose_times_drive_force():
    rng = np.random.default_rng(3)
    q, F = _random_q(rng, 6), rng.standard_normal((6, 3))
    J = MODEL.wheel_jacobians(q)
    tau = MODEL.generalized_force(q, F)
    np.testing.assert_allclose(tau, sum(J[:, b, 0, :] * F[:, b : b + 1] for b in range(3)), atol=1e-14)


def test_bad_configuration_is_rejected_with_a_clear_message():
    with pytest.raises(DataError, match=r"expected q of shape \(T, 6\) = \(x, y, cos heading"):
        MODEL.metric(np.zeros((3, 5)))
    with pytest.raises(DataError, match=r"LandSalp velocities: expected shape \(2, 5\), got \(2, 4\)"):
        MODEL.regressor(configuration([0, 0], 0, 0, 0, 0), np.zeros((2, 4)), None)
    with pytest.raises(ValueError, match=r"noise: expected one of \['ideal', 'none', 'realistic'\], got 'loud'"):
        sim.make(noise="loud")
    with pytest.raises(ValueError, match=r"unknown LandSalp gait 'moonwalk'"):
        sim.gait_inputs("moonwalk")


@pytest.fixture(scope="module")
def exact():
    return make_system("landsalp", seed=0, noise="none", size="small")


@pytest.fixture(scope="module")
def realistic():
    return sim.make(seed=0, noise="realistic", size="small")


def test_true_parameters_predict_noiseless_velocities_exactly(exact):
    assert exact.theta_true.shape == (11,) and len(exact.train) == 2 and len(exact.test) == 2
    for traj in exact.train + exact.test:
        v_hat = forward_dynamics(exact.model, exact.theta_true, traj.q, traj.v, traj.tau)
        np.testing.assert_allclose(v_hat, traj.v, atol=1e-8, rtol=0)
    np.testing.assert_allclose(OLS().fit(build_problem(exact.model, list(exact.train))).theta, THETA, rtol=1e-6)


def test_system_data_contract(realistic):
    assert realistic.name == "landsalp" and realistic.low_data_samples == 40
    assert realistic.slowest_period == 6.0 and realistic.shape_coordinates == ("alpha1", "alpha2")
    ratio = realistic.theta_nominal / realistic.theta_true
    assert np.all(realistic.theta_nominal > 0) and np.all((np.abs(ratio - 1) >= 0.2 - 1e-9) & (np.abs(ratio - 1) <= 0.4 + 1e-9))
    assert MODEL.parameters.is_consistent(realistic.theta_nominal)
    traj = realistic.train[0]
    assert traj.q.shape[1] == 6 and traj.v.shape[1] == 5 and traj.coordinates == MODEL.coordinates
    np.testing.assert_allclose(traj.q[:, 2] ** 2 + traj.q[:, 3] ** 2, 1.0)
    assert [s["step"] for s in traj.meta["steps"]][:2] == ["motion_capture", "lowpass"]
    # realistic data are not exact: the true parameters leave a visible residual
    v_hat = forward_dynamics(realistic.model, THETA, traj.q, traj.v, traj.tau)
    assert 1e-4 < np.sqrt(np.mean((v_hat - traj.v) ** 2))


def test_seeds_reproduce_and_differ(realistic):
    again = sim.make(seed=0, noise="realistic", size="small")
    other = sim.make(seed=1, noise="realistic", size="small")
    for a, b in zip(realistic.train + realistic.test, again.train + again.test):
        np.testing.assert_array_equal(a.q, b.q)
        np.testing.assert_array_equal(a.v, b.v)
        np.testing.assert_array_equal(a.tau, b.tau)
    assert not np.allclose(realistic.train[0].tau, other.train[0].tau)


def test_ideal_noise_has_exact_states_and_force_noise_only():
    data = sim.make(seed=0, noise="ideal", size="small")
    traj = data.train[0]
    v_hat = forward_dynamics(data.model, THETA, traj.q, traj.v, traj.tau)
    err = v_hat - traj.v
    assert 1e-6 < np.abs(err).max() < 5e-2


def test_estimators_fit_a_realistic_subsample_with_nonnegative_drag(realistic):
    problem = build_problem(realistic.model, list(realistic.train))
    idx = np.random.default_rng(0).choice(problem.N, size=200, replace=False)
    sub = problem.subset(np.sort(idx))
    for est in (OLS(), EnergyLS(), DualMetric(solver="cvxpy")):
        res = est.fit(sub)
        assert np.all(res.theta[:9] >= -1e-6), (type(est).__name__, res.theta)
        assert MODEL.parameters.is_consistent(res.theta, tol=1e-6)
    dm = DualMetric(solver="cvxpy").fit(sub).theta
    # the dominant drags (longitudinal / lateral, N s/m) are recovered to within a factor of two
    big = [0, 1, 3, 4, 6]
    assert np.all(np.abs(np.log(dm[big] / THETA[big])) < np.log(2)), dm


@pytest.mark.parametrize("effects", [sim.TrueEffects.none(), sim.TrueEffects()], ids=["exact", "realistic"])
def test_gaits_move_in_their_named_directions(effects):
    model, _, test, _ = sim.dataset(0, n_train=0, effects=effects, measurement=None)
    moves = {}
    for traj in test:
        state = traj.meta["state_true"]
        h0 = state[0, 2]
        R0 = np.array([[np.cos(h0), np.sin(h0)], [-np.sin(h0), np.cos(h0)]])
        moves[traj.name.removeprefix("test_")] = (R0 @ (state[-1, :2] - state[0, :2]), state[-1, 2] - h0)
        assert np.abs(state[:, 3:]).max() < 1.4  # the chain does not fold over
    for gait, direction in sim.GAIT_DIRECTIONS.items():
        d, dh = moves[gait]
        if gait == "turn":
            assert abs(dh) > 1.0 and np.linalg.norm(d) < 0.3 * abs(dh) * LINK_LENGTH * 3
            continue
        dist = np.linalg.norm(d)
        assert dist > (0.08 if gait == "forward" else 0.3), (gait, d)
        assert d @ np.asarray(direction) / dist > 0.85, (gait, d)
