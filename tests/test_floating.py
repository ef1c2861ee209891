"""Floating base from logs: Lie-group differentiation, quaternion columns, external wrenches, a single
floating body, and the CLI on the demo (examples/floating)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml
from typer.testing import CliRunner

from dualid.cli import app
from dualid.data import lie
from dualid.data.io import ColumnMap, load_log
from dualid.data.preprocessing import differentiate, downsample, filter_lowpass, resample
from dualid.data.trajectory import Trajectory
from dualid.errors import DataError, ModelError
from dualid.estimators import OLS
from dualid.model.external_wrench import apply_wrenches, wrench_force
from dualid.model.rigid_body import FREE_FLYER_COORDINATES, RigidBodyModel
from dualid.problem import build_problem
from dualid.robot.config import FitConfig
from dualid.robot.fit import build_model

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "floating"
BOX_URDF = EXAMPLES / "box" / "box.urdf"
CF_URDF = EXAMPLES / "crazyflie" / "crazyflie_pendulum.urdf"
BASE = {"position": ["x", "y", "z"], "quaternion": ["qx", "qy", "qz", "qw"]}


def _ff_rx() -> pin.Model:
    model = pin.Model()
    j = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    model.addJoint(j, pin.JointModelRX(), pin.SE3.Identity(), "a1")
    return model


def _screw(model, T=300, fs=100.0, v0=(0.3, -0.2, 0.1, 0.5, -0.6, 0.7, 0.4)):
    """A constant twist v0 from a generic q0: q(t) = q0 · exp(t v0)."""
    t = np.arange(T) / fs
    q0 = pin.integrate(model, pin.neutral(model), np.array([1, 2, 3, 0.3, 0.2, 0.1, 0.5]))
    return t, np.array([pin.integrate(model, q0, tk * np.asarray(v0)) for tk in t]), np.asarray(v0)


def _same_configuration(model, q1, q2, atol):
    """Equal on the group (a quaternion and its negative are the same rotation)."""
    err = max(np.abs(pin.difference(model, a, b)).max() for a, b in zip(q1, q2))
    assert err < atol, err


# --- the Lie group ------------------------------------------------------------------------------
def test_group_is_the_models_configuration_space():
    model = _ff_rx()
    G = lie.group(model.nq, model.nv)
    rng = np.random.default_rng(0)
    for _ in range(20):
        q0 = pin.integrate(model, pin.neutral(model), rng.normal(size=7))
        q1 = pin.integrate(model, q0, rng.normal(size=7))
        np.testing.assert_allclose(G.difference(q0, q1), pin.difference(model, q0, q1), atol=1e-12)
        np.testing.assert_allclose(G.integrate(q0, q1[:7].sum() * np.ones(7)),
                                   pin.integrate(model, q0, q1[:7].sum() * np.ones(7)), atol=1e-12)
    assert lie.BASE_COORDINATES is FREE_FLYER_COORDINATES


@pytest.mark.parametrize("kw", [{}, {"cutoff": 5.0}, {"method": "central"}, {"window": 0.15, "polyorder": 4}])
def test_constant_twist_gives_exact_body_velocity_and_zero_acceleration(kw):
    model = _ff_rx()
    t, q, v0 = _screw(model)
    traj = Trajectory(t, q, np.zeros((t.size, 7)), np.zeros((t.size, 7)), meta={"logged": ["q", "tau"]})
    out = differentiate(traj, **kw)
    np.testing.assert_allclose(out.v, np.tile(v0, (t.size, 1)), atol=1e-10)  # edges included (odd extension)
    np.testing.assert_allclose(out.a, 0.0, atol=1e-8)
    assert out.meta["steps"][-1]["differentiate"]["on"].startswith("Lie group")


def test_velocity_and_acceleration_match_a_simulated_trajectory():
    """Non-constant twist: group Savitzky–Golay vs the simulator's own v and a (aba, 1 kHz)."""
    rigid = RigidBodyModel.from_urdf(BOX_URDF, floating_base=True)
    model, data = rigid.model, rigid.model.createData()
    dt, T = 1e-3, 3000
    q, v = pin.neutral(model), np.array([0.2, 0.0, 0.1, 0.5, -0.3, 0.8])
    Q, V, A = [], [], []
    for k in range(T):
        tau = np.concatenate([[0, 0, 36.0 + 5 * np.sin(7 * k * dt)], 0.2 * np.sin([3 * k * dt, 5 * k * dt, 2 * k * dt])])
        a = pin.aba(model, data, q, v, tau)
        Q.append(q.copy()), V.append(v.copy()), A.append(a)
        q, v = pin.integrate(model, q, dt * v + 0.5 * dt * dt * a), v + dt * a
    sub = 10
    traj = Trajectory(np.arange(T)[::sub] * dt, np.array(Q)[::sub], np.zeros((T // sub, 6)), np.zeros((T // sub, 6)),
                      meta={"logged": ["q", "tau"]})
    out = differentiate(traj, window=0.05)
    inner = slice(5, -5)
    scale = np.abs(np.array(A)).max(0)
    assert np.abs(out.v - np.array(V)[::sub])[inner].max() < 1e-4  # |v| ~ 1
    assert (np.abs(out.a - np.array(A)[::sub])[inner].max(0) / scale).max() < 0.01


def test_resample_and_filter_on_the_group():
    model = _ff_rx()
    t, q, v0 = _screw(model)
    traj = Trajectory(t, q, np.tile(v0, (t.size, 1)), np.zeros((t.size, 7)))
    out = resample(traj, 250)
    truth = np.array([pin.integrate(model, q[0], (tk - t[0]) * v0) for tk in out.t])
    _same_configuration(model, out.q, truth, 1e-10)  # geodesic interpolation is exact for a screw
    np.testing.assert_allclose(np.linalg.norm(out.q[:, 3:7], axis=1), 1.0, atol=1e-12)
    with pytest.raises(DataError) as err:
        resample(traj, 250, method="cubic")
    assert str(err.value) == ("resample: method 'cubic' is not defined for a floating base's configuration (a Lie "
                              "group); use method 'linear' (geodesic interpolation between samples)")
    _same_configuration(model, filter_lowpass(traj, 5.0, fields=("q", "v")).q, q, 1e-10)  # a screw is its own low-pass
    down = downsample(traj, 2)
    assert "q" in down.meta["steps"][-1]["downsample"]["filtered"]
    _same_configuration(model, down.q, q[::2], 1e-10)


def test_a_window_spanning_half_a_turn_is_refused():
    model = _ff_rx()
    t, q, _ = _screw(model, v0=(0, 0, 0, 0, 0, 6.0, 0))  # 6 rad/s: ±0.6 s spans 3.6 rad
    traj = Trajectory(t, q, np.zeros((t.size, 7)), np.zeros((t.size, 7)))
    with pytest.raises(DataError) as err:
        differentiate(traj, cutoff=5.0)
    assert str(err.value) == (
        "the base turns by 3.12 rad between samples 0 and 52, within the filter window (±94 samples): too far for the "
        "tangent space about one sample (valid below 2.83 rad); shorten the window, raise the cutoff or log faster")


# --- log columns ----------------------------------------------------------------------------------
def _write_log(path, t, q, extra=None):
    quat = q[:, 3:7]
    cols = {"time": t, "x": q[:, 0], "y": q[:, 1], "z": q[:, 2]}
    cols.update(dict(zip(["qx", "qy", "qz", "qw"], quat.T)))
    cols.update(extra or {})
    names = list(cols)
    np.savetxt(path, np.column_stack([cols[n] for n in names]), delimiter=",", header=",".join(names), comments="",
               fmt="%.17g")
    return path


def test_quaternion_sign_flips_and_orders_give_the_same_run(tmp_path):
    model = _ff_rx()
    t, q, v0 = _screw(model)
    q6 = q[:, :7].copy()
    rng = np.random.default_rng(1)
    flipped = q6.copy()
    flips = rng.random(t.size) < 0.3
    flipped[flips, 3:7] *= -1  # what a mocap export with w ≥ 0, or a careless one, does
    cmap = {"time": "time", "base": BASE}
    ref = load_log(_write_log(tmp_path / "a.csv", t, q6), cmap, velocity="gradient")
    run = load_log(_write_log(tmp_path / "b.csv", t, flipped), cmap, velocity="gradient")
    assert run.meta["base"]["quaternion_sign_flips"] > 10
    wxyz = load_log(tmp_path / "b.csv",
                    {"time": "time", "base": {**BASE, "quaternion": ["qw", "qx", "qy", "qz"], "quaternion_order": "wxyz"}},
                    velocity="gradient")
    np.testing.assert_allclose(np.abs(np.sum(run.q[:, 3:7] * ref.q[:, 3:7], 1)), 1.0, atol=1e-12)
    assert np.all(np.sum(run.q[1:, 3:7] * run.q[:-1, 3:7], 1) > 0)  # sign-continuous, as component-wise uses need
    np.testing.assert_allclose(wxyz.q, run.q, atol=1e-14)
    assert run.coordinates == FREE_FLYER_COORDINATES and run.q.shape == (t.size, 7)
    np.testing.assert_allclose(run.v, np.tile(v0[:6], (t.size, 1)), atol=1e-9)  # group differences on the raw stamps
    out = differentiate(run)
    np.testing.assert_allclose(out.v, np.tile(v0[:6], (t.size, 1)), atol=1e-9)


def test_matrix_columns_and_a_world_aligned_twist(tmp_path):
    model = _ff_rx()
    t, q, v0 = _screw(model)
    M = [pin.XYZQUATToSE3(x[:7]).homogeneous for x in q]
    R = np.array([m[:3, :3] for m in M])
    twist_world = np.concatenate([R @ v0[:3], R @ v0[3:6]], axis=1)
    extra = {f"T{i}{j}": np.array([m[i, j] for m in M]) for i in range(4) for j in range(4)}
    extra.update({f"w{k}": twist_world[:, k] for k in range(6)})
    path = _write_log(tmp_path / "m.csv", t, q[:, :7], extra)
    run = load_log(path, {"time": "time", "base": {"matrix": [f"T{i}{j}" for i in range(4) for j in range(4)],
                                                   "twist": [f"w{k}" for k in range(6)],
                                                   "twist_frame": "local_world_aligned"}})
    _same_configuration(lie_model(), run.q, q[:, :7], 1e-12)
    np.testing.assert_allclose(run.v, np.tile(v0[:6], (t.size, 1)), atol=1e-12)


def lie_model():
    model = pin.Model()
    model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    return model


def _message(tmp_path, cmap, q=None) -> str:
    model = _ff_rx()
    t, qq, _ = _screw(model, T=20)
    q = qq[:, :7] if q is None else q
    path = _write_log(tmp_path / "bad.csv", t, q)
    with pytest.raises(DataError) as err:
        load_log(path, cmap, velocity="gradient")
    return str(err.value).replace(str(path), "LOG")


def test_bad_quaternion_columns_have_exact_messages(tmp_path):
    model = _ff_rx()
    _, q, _ = _screw(model, T=20)
    q = q[:, :7].copy()
    q[7, 3:7] *= 0.9
    assert _message(tmp_path, {"time": "time", "base": BASE}, q) == (
        "LOG: the quaternion columns ['qx', 'qy', 'qz', 'qw'] have norm 0.9 at row 7 (expected 1 within 0.001; 1 rows "
        "off); check the columns and their order (quaternion_order: xyzw or wxyz)")
    assert _message(tmp_path, {"time": "time", "base": {**BASE, "quaternion": ["qx", "qy", "qz", "q_w"]}}) == (
        "LOG: missing columns ['q_w']; available columns: ['time', 'x', 'y', 'z', 'qx', 'qy', 'qz', 'qw']")
    assert _message(tmp_path, {"time": "time", "base": {**BASE, "quaternion": ["qx", "qy", "qz"]}}) == (
        "column map: base.quaternion: expected a list of 4 column names, got ['qx', 'qy', 'qz']")
    assert _message(tmp_path, {"time": "time", "base": {"position": ["x", "y", "z"]}}) == (
        "column map: base needs columns for ['quaternion']")
    assert _message(tmp_path, {"time": "time", "base": {**BASE, "matrix": ["x"] * 16}}) == (
        "column map: base needs either 'position' and 'quaternion' (7 columns) or 'matrix' (16 columns), not both")
    assert _message(tmp_path, {"time": "time", "base": {**BASE, "quaternion_order": "wxzy"}}) == (
        "column map: base.quaternion_order: expected one of ['xyzw', 'wxyz'], got 'wxzy'")


def test_floating_base_and_base_columns_must_agree():
    from dualid.robot.inputs import check_floating

    with pytest.raises(DataError) as err:
        check_floating(True, ColumnMap.pattern(["alpha1"]))
    assert str(err.value) == (
        "model.floating_base is true but the column map has no 'base' section: map the base pose (columns.base: "
        "{position: [x, y, z], quaternion: [qx, qy, qz, qw]} or {matrix: [16 columns]})")
    with pytest.raises(DataError) as err:
        check_floating(False, ColumnMap.from_dict({"time": "time", "base": BASE}))
    assert str(err.value) == ("the column map has a 'base' section but model.floating_base is false; set "
                              "model.floating_base: true (a free-flyer root joint)")


def test_passive_joints_and_zero_wrench_components_round_trip():
    d = {"time": "time", "base": BASE, "joints": {"alpha1": {"position": "a1", "effort": 0}},
         "wrenches": {"thrust": {"frame": "base_link", "reference": "local", "force": [0, 0, "fz"],
                                 "torque": ["tx", "ty", "tz"]}}}
    cmap = ColumnMap.from_dict(d)
    assert cmap.joints[0].effort is None
    assert cmap.columns() == ["time", "x", "y", "z", "qx", "qy", "qz", "qw", "a1", "fz", "tx", "ty", "tz"]
    assert ColumnMap.from_dict(cmap.to_dict()) == cmap
    with pytest.raises(DataError) as err:
        ColumnMap.from_dict({**d, "joints": {"alpha1": {"position": "a1", "effort": 1}}})
    assert str(err.value) == ("column map: joint 'alpha1' effort: expected a column name, a motor current or 0 "
                              "(a passive joint), got 1")


# --- external wrenches ----------------------------------------------------------------------------
def _fext_reference(model, data, q, frames, wrenches):
    """Pinocchio's rnea with fext: each frame wrench moved into its parent joint's frame by SE3 actions."""
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    fext = pin.StdVec_Force()
    for _ in range(model.njoints):
        fext.append(pin.Force.Zero())
    for (name, ref), w in zip(frames, wrenches):
        frame = model.frames[model.getFrameId(name)]
        f = pin.Force(w)
        if ref == "local":
            f_joint = frame.placement.act(f)
        else:
            if ref == "local_world_aligned":  # world axes at the frame origin -> world origin
                f = pin.SE3(np.eye(3), data.oMf[model.getFrameId(name)].translation).act(f)
            f_joint = data.oMi[frame.parentJoint].actInv(f)
        fext[frame.parentJoint] = fext[frame.parentJoint] + f_joint
    return fext


def test_inverse_dynamics_with_external_wrenches_match_pinocchio_fext():
    rigid = RigidBodyModel.from_urdf(CF_URDF, floating_base=True)
    model, data = rigid.model, rigid.model.createData()
    frames = [("base_link", "local"), ("pendulum", "local_world_aligned"), ("core", "world"), ("alpha2", "local")]
    specs = [{"name": f"w{k}", "frame": f, "reference": r} for k, (f, r) in enumerate(frames)]
    rng = np.random.default_rng(3)
    T = 6
    q = np.array([pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq)) for _ in range(T)])
    v, a = rng.normal(size=(T, model.nv)), rng.normal(size=(T, model.nv))
    W = rng.normal(size=(T, 6 * len(frames)))
    Y = rigid.regressor(q, v, a)
    generalized = wrench_force(rigid, q, W, specs)
    for t in range(T):
        fext = _fext_reference(model, data, q[t], frames, W[t].reshape(-1, 6))
        tau_ref = pin.rnea(model, data, q[t], v[t], a[t], fext)
        np.testing.assert_allclose(Y[t] @ rigid.nominal - generalized[t], tau_ref, atol=1e-12)
    with pytest.raises(ModelError, match=r"external wrench: the model has no frame 'rotor'; its frames are \['root_joint'"):
        wrench_force(rigid, q, W[:, :6], [{"name": "x", "frame": "rotor", "reference": "local"}])


# --- a single floating body -----------------------------------------------------------------------
def _box_truth():
    m, (a, b, c) = 4.0, (0.4, 0.3, 0.2)
    return pin.Inertia(m, np.array([0.012, -0.008, 0.005]), m / 12 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b]))


def test_single_floating_body_fit_recovers_mass_and_inertia_on_exact_data():
    cfg = FitConfig.from_dict({"model": {"urdf": str(BOX_URDF), "floating_base": True, "gravity": [0, 0, 0]},
                               "train": ["unused.csv"]})
    rigid, model = build_model(cfg)  # joint terms default on: there is no joint, so none are added
    assert model is rigid and rigid.coordinates == FREE_FLYER_COORDINATES and rigid.parameters.p == 10
    truth = rigid.model.copy()
    truth.inertias[1] = _box_truth()
    data = truth.createData()
    specs = [{"name": "push", "frame": "handle", "reference": "local"}]
    rng = np.random.default_rng(5)
    T = 200
    q = np.array([pin.randomConfiguration(truth, -np.ones(7), np.ones(7)) for _ in range(T)])
    v, W = rng.normal(size=(T, 6)), rng.normal(size=(T, 6))
    handle = truth.frames[truth.getFrameId("handle")]
    a = np.empty((T, 6))
    for t in range(T):
        fext = pin.StdVec_Force()
        for _ in range(truth.njoints):
            fext.append(pin.Force.Zero())
        fext[1] = handle.placement.act(pin.Force(W[t]))
        a[t] = pin.aba(truth, data, q[t], v[t], np.zeros(6), fext)
    run = Trajectory(np.arange(T) * 0.01, q, v, np.zeros((T, 6)), a, rigid.coordinates, "exact",
                     {"wrenches": specs}, wrench=W)
    run = apply_wrenches(rigid, run)
    assert run.wrench is None and run.meta["steps"] == [{"external_wrenches": ["push on handle (local)"]}]
    theta = OLS().fit(build_problem(rigid, [run])).theta
    np.testing.assert_allclose(theta, _box_truth().toDynamicParameters(), rtol=1e-8, atol=1e-10)


# --- the CLI on the demo ----------------------------------------------------------------------------
def test_cli_fits_the_box_demo_end_to_end(tmp_path):
    out = tmp_path / "out"
    result = CliRunner().invoke(app, ["fit", "--config", str(EXAMPLES / "box" / "fit.yaml"), "--method", "ols",
                                      "--method", "dm", "--out", str(out)])
    assert result.exit_code == 0, result.output
    params = yaml.safe_load((out / "parameters.yaml").read_text())
    for method in ("ols", "dm"):
        values = {p["name"]: p["value"] for p in params["methods"][method]["parameters"]}
        assert values["root_joint.m"] == pytest.approx(4.0, rel=0.03)  # truth 4.0 kg; the URDF's prior says 3.7
    assert (out / "dm.urdf").is_file()
    RigidBodyModel.from_urdf(out / "dm.urdf", floating_base=True)  # the written URDF loads back


def test_a_configuration_without_unit_quaternions_is_not_taken_for_a_floating_base():
    T = 30
    q = np.zeros((T, 7))  # nq = n + 1, but columns 3–6 are no quaternion (e.g. (cos, sin) pairs elsewhere)
    traj = Trajectory(np.arange(T) / 100.0, q, np.zeros((T, 6)), np.zeros((T, 6)))
    with pytest.raises(DataError) as err:
        differentiate(traj)
    assert str(err.value) == ("differentiate: q has 7 columns for 6 velocity coordinates; only a floating base "
                              "(free flyer first, nq = n + 1) is supported")


def test_the_demo_log_generator_still_runs(tmp_path):
    """examples/floating/make_logs.py (how the committed demo logs are regenerated) against the current simulator:
    a short Crazyflie run gives the logged columns a user maps, finite."""
    import importlib.util

    from dualid.systems import crazyflie_model as cfm

    spec = importlib.util.spec_from_file_location("make_logs", EXAMPLES / "make_logs.py")
    make_logs = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_logs)
    nominal = cfm._nominal_model()
    urdf = tmp_path / "crazyflie_pendulum.urdf"
    urdf.write_text(make_logs.crazyflie_urdf(nominal.inertias[1], nominal.inertias[2], nominal.inertias[3],
                                             cfm.MOUNT_OFFSET))
    (log,) = make_logs.crazyflie_logs(urdf, 1, 0.5, seed=0)
    assert {"thrust", "torque_x", "torque_y", "torque_z"} <= set(log)
    assert all(np.all(np.isfinite(np.asarray(v, dtype=float))) for v in log.values())
