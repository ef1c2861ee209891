"""ROS bags in: the DFKI pendulum and a floating box written as ROS 1 / rosbag2 sqlite3 / rosbag2 MCAP bags by
the rosbags library's writers, fitted through the CLI and compared with the same data from CSV; ``dualid
inspect`` and its starter config; multi-rate topics and the base's message types."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from typer.testing import CliRunner

from dualid.cli import app
from tests.bag_files import EPOCH, KINDS, Messages, bag_name, write_bag

ROOT = Path(__file__).resolve().parents[1]
DFKI = ROOT / "examples" / "dfki" / "data"  # the DFKI double-pendulum logs shipped with the repository
URDF = DFKI / "pendubot_model_2.1.urdf"
BOX = ROOT / "examples" / "floating" / "box"
JS = "sensor_msgs/msg/JointState"
runner = CliRunner()
STEPS = [{"resample": {"rate": 500}}, {"differentiate": {"method": "savgol", "window": 0.1, "velocity": True}},
         {"filter_lowpass": {"cutoff": 10, "fields": ["tau"]}}, {"downsample": {"factor": 5}}]
QUICK = {"methods": ["ols", "wls"], "prior": {"plausible": False}, "uncertainty": {"method": "none"}}


def dfki_frame(rows: int = 1500) -> tuple[pd.DataFrame, np.ndarray]:
    """The first rows of DFKI run 00 with its stamps in whole nanoseconds (as a bag holds them), and the stamps."""
    df = pd.read_csv(DFKI / "trajectory_00.csv").iloc[:rows].copy()
    ns = np.round(df["time"].to_numpy() * 1e9).astype(np.int64)
    df["time"] = ns / 1e9
    return df, ns


def joint_messages(kind: str, df: pd.DataFrame, ns, topic="/joint_states", **change):
    """JointState messages in two alternating joint orders, with a joint the model does not have."""
    m = Messages(kind)
    out = []
    for k, (n, r) in enumerate(zip(ns, df.itertuples())):
        names, pos, vel, eff = (["Joint2", "gripper", "Joint1"], [r.pos_meas2, 0.5, r.pos_meas1],
                                [r.vel_meas2, 0.0, r.vel_meas1], [r.tau_meas2, 0.0, r.tau_meas1])
        if k % 2:
            names, pos, vel, eff = ([x[2], x[0], x[1]] for x in (names, pos, vel, eff))
        fields = dict(names=names, position=pos, velocity=vel, effort=eff)
        fields.update(change.get(k, {}))
        out.append((topic, JS, EPOCH + int(n) + 250_000, m.joint_state(EPOCH + int(n), **fields)))
    return out


def fit(tmp: Path, name: str, config: dict) -> dict:
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump(config))
    result = runner.invoke(app, ["fit", "--config", str(path), "--out", str(tmp / name)])
    assert result.exit_code == 0, result.output
    return json.loads((tmp / name / "parameters.json").read_text())["methods"]


def theta(methods: dict, method: str) -> np.ndarray:
    return np.array([p["value"] for p in methods[method]["parameters"]])


@pytest.fixture(scope="module")
def dfki_csv_fit(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("dfki_csv")
    df, ns = dfki_frame()
    df.to_csv(tmp / "run.csv", index=False)
    cfg = {"model": {"urdf": str(URDF)}, "train": [str(tmp / "run.csv")], "preprocessing": STEPS, **QUICK}
    return df, ns, fit(tmp, "csv", cfg)


@pytest.mark.parametrize("kind", KINDS)
def test_dfki_fit_from_each_bag_kind_equals_the_csv_fit(tmp_path, kind, dfki_csv_fit):
    """Joints matched by name (two orders, an extra joint): θ of every method equal to the CSV fit's to 1e-12."""
    df, ns, csv = dfki_csv_fit
    bag = write_bag(bag_name(tmp_path, kind), kind, joint_messages(kind, df, ns))
    cfg = {"model": {"urdf": str(URDF)}, "columns": {"topics": {"joint_states": "/joint_states"}},
           "train": [str(bag)], "preprocessing": STEPS, **QUICK}
    got = fit(tmp_path, "bag", cfg)
    for method in QUICK["methods"]:
        assert np.abs(theta(got, method) - theta(csv, method)).max() <= 1e-12, method
        assert theta(got, method).std() > 0


def test_a_bag_loads_as_its_csv_bit_for_bit_and_receive_stamps_are_the_record_times(tmp_path):
    from dualid.data.io import load_log

    df, ns = dfki_frame(300)
    df.to_csv(tmp_path / "run.csv", index=False)
    cmap = {"time": "time", "joints": {f"Joint{i}": {"position": f"pos_meas{i}", "velocity": f"vel_meas{i}",
                                                     "effort": f"tau_meas{i}"} for i in (1, 2)}}
    ref = load_log(tmp_path / "run.csv", cmap)
    bag = write_bag(bag_name(tmp_path, "mcap"), "mcap", joint_messages("mcap", df, ns))
    got = load_log(bag, {"topics": {"joint_states": "/joint_states"}}, joints=["Joint1", "Joint2"])
    for key in ("t", "q", "v", "tau"):
        assert np.array_equal(getattr(got, key), getattr(ref, key)), key
    # record times: the messages were written 0.25 ms after their stamps, and the second one 1 ms later still
    msgs = joint_messages("mcap", df, ns)
    msgs[1] = (msgs[1][0], msgs[1][1], msgs[1][2] + 1_000_000, msgs[1][3])
    late = write_bag(tmp_path / "late", "mcap", msgs)
    rec = load_log(late, {"topics": {"stamps": "receive", "joint_states": "/joint_states"}}, joints=["Joint1", "Joint2"])
    expected = (np.array([m[2] for m in msgs]) - msgs[0][2]) / 1e9
    assert np.array_equal(rec.t, expected) and not np.array_equal(rec.t, ref.t)


def test_topics_at_other_rates_are_interpolated_onto_the_time_base(tmp_path):
    """A 100 Hz wrench linear in time and a 50 Hz odometry of a constant twist (a screw motion), read on the 500 Hz
    joint-state stamps inside their common span: the wrench exactly linear, the pose on the screw."""
    import pinocchio as pin

    from dualid.data.bag_topics import TopicMap
    from dualid.data.bags import read_bag

    m = Messages("ros1")
    step = 2_000_000  # 500 Hz
    js = [("/js", JS, EPOCH + k * step, m.joint_state(EPOCH + k * step, ["a"], [0.0], [0.0], [0.0])) for k in range(501)]
    wr = [("/ft", "geometry_msgs/msg/WrenchStamped", EPOCH + k * 10_000_000 + 3_000_000,
           m.wrench(EPOCH + k * 10_000_000 + 3_000_000, "tool", [k * 0.01 + 0.003, 1, 2], [3, 4, 5])) for k in range(100)]
    xi = np.array([0.3, -0.2, 0.1, 0.4, 0.2, -0.5])

    def pose(s):
        M = pin.exp6(pin.Motion(xi * s))
        return M.translation, pin.Quaternion(M.rotation).coeffs()

    od = [("/odom", "nav_msgs/msg/Odometry", EPOCH + k * 20_000_000 + 1_000_000,
           m.odometry(EPOCH + k * 20_000_000 + 1_000_000, *pose(k * 0.02 + 0.001), xi)) for k in range(50)]
    bag = write_bag(tmp_path / "multi.bag", "ros1", sorted(js + wr + od, key=lambda x: x[2]))
    topics = TopicMap.from_dict({"joint_states": "/js", "base": "/odom", "wrenches": {"ft": "/ft"}})
    data, _, frames = read_bag(bag, topics, ["a"])
    t = data["/js.header.stamp"]
    first = 2  # the first joint-state stamp inside every topic's span: 4 ms
    assert frames == {"ft": "tool"} and t[0] == 0 and np.allclose(np.diff(t), 0.002)
    s = t + first * 0.002  # absolute seconds after EPOCH
    assert s[-1] <= 0.981 + 1e-12  # the odometry's last stamp bounds the span
    assert np.allclose(data["/ft.wrench.force.x"], s, atol=1e-12, rtol=0)
    for k in range(0, t.size, 37):
        p, q = pose(s[k])
        got = np.array([data[f"/odom.position.{c}"][k] for c in "xyz"])
        quat = np.array([data[f"/odom.orientation.{c}"][k] for c in "xyzw"])
        assert np.allclose(got, p, atol=1e-12) and min(np.abs(quat - q).max(), np.abs(quat + q).max()) < 1e-12
    assert np.allclose(data["/odom.twist.angular.z"], xi[5], atol=1e-12)


def test_odometry_pose_and_tf_give_the_same_base_pose(tmp_path):
    from dualid.data.io import load_log

    m = Messages("sqlite3")
    rng = np.random.default_rng(0)
    p = np.cumsum(rng.normal(0, 0.01, (50, 3)), axis=0)
    q = np.tile([0.0, 0.0, np.sin(0.1), np.cos(0.1)], (50, 1))
    ns = [EPOCH + k * 10_000_000 for k in range(50)]
    msgs = []
    for k, n in enumerate(ns):
        msgs += [("/odom", "nav_msgs/msg/Odometry", n, m.odometry(n, p[k], q[k], np.zeros(6))),
                 ("/pose", "geometry_msgs/msg/PoseStamped", n, m.pose_stamped(n, p[k], q[k])),
                 ("/tf", "tf2_msgs/msg/TFMessage", n, m.tf(n, "map", "other", -p[k], q[k])),
                 ("/tf", "tf2_msgs/msg/TFMessage", n, m.tf(n, "odom", "base_link", p[k], q[k]))]
    bag = write_bag(tmp_path / "bases", "sqlite3", msgs)
    bases = [{"topic": "/odom", "twist": False}, {"topic": "/pose", "twist": False},
             {"topic": "/tf", "parent": "odom", "child": "base_link"}]
    runs = [load_log(bag, {"topics": {"base": b}}, joints=[], velocity="gradient") for b in bases]
    assert np.allclose(runs[0].q[:, :3], p, atol=1e-15)
    for r in runs[1:]:
        assert np.array_equal(r.q, runs[0].q) and np.array_equal(r.t, runs[0].t)


def _box_twists(df: pd.DataFrame) -> np.ndarray:
    from dualid.data.lie import gradient_on_group, unit_quaternions

    q = df[["base_x", "base_y", "base_z", "base_qx", "base_qy", "base_qz", "base_qw"]].to_numpy(copy=True)
    q[:, 3:], _ = unit_quaternions(q[:, 3:], "box", "q")
    return gradient_on_group(df["time"].to_numpy(), q, 6)


def test_the_floating_box_fits_from_a_bag_with_odometry_and_wrench_topics(tmp_path):
    """examples/floating/box: the base pose and twist as nav_msgs/Odometry, the push as a WrenchStamped in the
    handle frame: θ equal to the CSV fit's (pose, twist and wrench columns) to 1e-12."""
    df = pd.read_csv(BOX / "train_0.csv").iloc[:400].copy()
    ns = np.round(df["time"].to_numpy() * 1e9).astype(np.int64)
    df["time"] = ns / 1e9
    twist = _box_twists(df)
    for k, c in enumerate(["vx", "vy", "vz", "wx", "wy", "wz"]):
        df[c] = twist[:, k]
    df.to_csv(tmp_path / "box.csv", index=False)
    m = Messages("mcap")
    msgs = []
    for k, (n, r) in enumerate(zip(ns, df.itertuples())):
        n = EPOCH + int(n)
        msgs += [("/mocap/odom", "nav_msgs/msg/Odometry", n + 100_000,
                  m.odometry(n, [r.base_x, r.base_y, r.base_z], [r.base_qx, r.base_qy, r.base_qz, r.base_qw], twist[k])),
                 ("/handle/wrench", "geometry_msgs/msg/WrenchStamped", n + 200_000,
                  m.wrench(n, "handle", [r.fx, r.fy, r.fz], [r.tx, r.ty, r.tz]))]
    bag = write_bag(tmp_path / "box_mcap", "mcap", msgs)
    common = {"model": {"urdf": str(BOX / "box.urdf"), "floating_base": True, "gravity": [0, 0, 0]},
              "preprocessing": [{"differentiate": {"method": "savgol", "window": 0.1, "cutoff": 3, "velocity": True}},
                                {"filter_lowpass": {"cutoff": 3, "fields": ["tau"]}}], **QUICK}
    columns = {"time": "time", "base": {"position": ["base_x", "base_y", "base_z"],
                                        "quaternion": ["base_qx", "base_qy", "base_qz", "base_qw"],
                                        "twist": ["vx", "vy", "vz", "wx", "wy", "wz"]},
               "wrenches": {"push": {"frame": "handle", "force": ["fx", "fy", "fz"], "torque": ["tx", "ty", "tz"]}}}
    csv = fit(tmp_path, "csv", {**common, "columns": columns, "train": [str(tmp_path / "box.csv")]})
    topics = {"base": "/mocap/odom", "wrenches": {"push": "/handle/wrench"}}
    got = fit(tmp_path, "bag", {**common, "columns": {"topics": topics}, "train": [str(bag)]})
    for method in QUICK["methods"]:
        assert np.abs(theta(got, method) - theta(csv, method)).max() <= 1e-12, method
    assert abs(theta(got, "ols")[0] - 3.7) < 0.5  # the box's mass, from the pushes


def test_inspect_lists_the_topics_and_its_starter_config_fits_unchanged(tmp_path):
    df, ns = dfki_frame(600)
    m = Messages("ros1")
    wrench = [("/ft", "geometry_msgs/msg/WrenchStamped", EPOCH + int(n) + 1,
               m.wrench(EPOCH + int(n), "Link2", [0.0, 0.0, 0.1], [0.0] * 3)) for n in ns[::10]]
    bag = write_bag(tmp_path / "run.bag", "ros1", sorted(joint_messages("ros1", df, ns) + wrench, key=lambda x: x[2]))
    result = runner.invoke(app, ["inspect", str(bag), "--model", str(URDF)])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    row = next(line for line in lines if "/joint_states" in line and JS in line).split()
    span = (ns[599] - ns[0]) / 1e9  # record times: the stamps plus a constant delay
    assert row[-3:] == ["600", f"{599 / span:.4g}", f"{span:.4g}"]
    assert "#     joints: Joint2, gripper, Joint1" in lines and "#     frames: Link2" in lines
    config = yaml.safe_load(result.stdout)
    assert config["columns"]["topics"]["joint_states"] == {"topic": "/joint_states"}
    assert config["columns"]["topics"]["wrenches"] == {"ft": {"topic": "/ft", "reference": "local"}}
    assert config["model"] == {"urdf": str(URDF.resolve()), "floating_base": False}
    (tmp_path / "fit.yaml").write_text(result.stdout)  # unchanged, as printed
    fitted = runner.invoke(app, ["fit", "--config", str(tmp_path / "fit.yaml"), "--out", str(tmp_path / "o")])
    assert fitted.exit_code == 0, fitted.output
    report = json.loads((tmp_path / "o" / "parameters.json").read_text())
    assert report["methods"]["ols"]["status"] == "optimal" and report["methods"]["dm"]["status"] == "optimal"
    listing = runner.invoke(app, ["inspect", str(bag), "--list-topics"])
    assert listing.exit_code == 0 and "model:" not in listing.stdout and "/ft" in listing.stdout


def test_a_bag_without_a_config_fits_from_its_one_joint_state_topic(tmp_path):
    df, ns = dfki_frame(1000)
    bag = write_bag(tmp_path / "run_sqlite", "sqlite3", joint_messages("sqlite3", df, ns))
    result = runner.invoke(app, ["fit", "--model", str(URDF), "--data", str(bag), "--method", "ols",
                                 "--out", str(tmp_path / "o")])
    assert result.exit_code == 0, result.output
    report = json.loads((tmp_path / "o" / "parameters.json").read_text())
    assert report["data"]["columns"]["topics"]["joint_states"]["topic"] == "/joint_states"


def test_validate_and_fit_stream_read_a_bag_as_its_csv(tmp_path):
    import re

    df, ns = dfki_frame(1000)
    df.to_csv(tmp_path / "run.csv", index=False)
    bag = write_bag(tmp_path / "run_sqlite", "sqlite3", joint_messages("sqlite3", df, ns))
    outputs = {}
    for log in (bag, tmp_path / "run.csv"):
        val = runner.invoke(app, ["validate", "--model", str(URDF), "--data", str(log)])
        assert val.exit_code == 0, val.output
        columns = {"columns": {"topics": {"joint_states": "/joint_states"}}} if log == bag else {}
        cfg = tmp_path / f"{log.name}.yaml"
        cfg.write_text(yaml.safe_dump({"model": str(URDF), "train": [str(log)], "preprocessing": STEPS, **columns}))
        stream = runner.invoke(app, ["fit-stream", "--model", str(URDF), "--data", str(log), "--config", str(cfg),
                                     "--chunk", "100"])
        assert stream.exit_code == 0, stream.output
        outputs[log] = (val.stdout, re.sub(r"passes over the data, [\d.]+ s", "", stream.stdout))
    assert outputs[bag] == outputs[tmp_path / "run.csv"]
    assert "objective" in outputs[bag][1] and "Joint1.m " in outputs[bag][1]


def test_a_bag_is_read_once_inside_reading_once(tmp_path, monkeypatch):
    """dualid fit loads the first log twice (to choose the preprocessing, then to fit): a bag is parsed once."""
    import dualid.data.bags as bags
    from dualid.data.io import load_log
    from dualid.data.tables import reading_once

    df, ns = dfki_frame(100)
    bag = write_bag(tmp_path / "run_mcap", "mcap", joint_messages("mcap", df, ns))
    calls = []
    read = bags._read_bag
    monkeypatch.setattr(bags, "_read_bag", lambda *a: calls.append(a) or read(*a))
    cmap = {"topics": {"joint_states": "/joint_states"}}
    with reading_once():
        first, again = (load_log(bag, cmap, joints=["Joint1", "Joint2"]) for _ in range(2))
    assert len(calls) == 1 and np.array_equal(first.q, again.q)
    load_log(bag, cmap, joints=["Joint1", "Joint2"])
    assert len(calls) == 2  # outside: read each time


def test_the_crazyflie_pendulum_fits_from_odometry_passive_joint_states_and_thrust(tmp_path):
    """examples/floating/crazyflie: the base as Odometry without its twist, the passive pendulum joints as JointState
    messages without velocities or efforts (passive), the thrust as a WrenchStamped on base_link (ROS 1): θ equal to the
    example config's CSV fit to 1e-12."""
    cf = ROOT / "examples" / "floating" / "crazyflie"
    example = yaml.safe_load((cf / "fit.yaml").read_text())
    df = pd.read_csv(cf / "train_0.csv").iloc[:600].copy()
    ns = np.round(df["time"].to_numpy() * 1e9).astype(np.int64)
    df["time"] = ns / 1e9
    df.to_csv(tmp_path / "cf.csv", index=False)
    m = Messages("ros1")
    msgs = []
    for n, r in zip(ns, df.itertuples()):
        n = EPOCH + int(n)
        msgs += [("/odom", "nav_msgs/msg/Odometry", n + 1, m.odometry(n, [r.base_x, r.base_y, r.base_z],
                                                                      [r.base_qx, r.base_qy, r.base_qz, r.base_qw],
                                                                      np.zeros(6))),
                 ("/joint_states", JS, n + 2, m.joint_state(n, ["alpha2", "alpha1"], [r.alpha2, r.alpha1])),
                 ("/thrust", "geometry_msgs/msg/WrenchStamped", n + 3,
                  m.wrench(n, "base_link", [0, 0, r.thrust], [r.torque_x, r.torque_y, r.torque_z]))]
    bag = write_bag(tmp_path / "cf.bag", "ros1", msgs)
    common = {"model": {"urdf": str(cf / example["model"]["urdf"]), "floating_base": True},
              "preprocessing": example["preprocessing"], "joint_terms": example["joint_terms"], **QUICK}
    csv = fit(tmp_path, "csv", {**common, "columns": example["columns"], "train": [str(tmp_path / "cf.csv")]})
    topics = {"base": {"topic": "/odom", "twist": False}, "wrenches": {"thrust": "/thrust"},
              "joint_states": {"topic": "/joint_states", "passive": ["alpha1", "alpha2"]}}
    got = fit(tmp_path, "bag", {**common, "columns": {"topics": topics}, "train": [str(bag)]})
    for method in QUICK["methods"]:
        assert np.abs(theta(got, method) - theta(csv, method)).max() <= 1e-12, method


def test_joints_renamed_in_the_messages_and_another_time_base(tmp_path):
    """names maps model joints to the messages' names; time_base puts every topic on another topic's stamps."""
    from dualid.data.io import load_log

    df, ns = dfki_frame(300)
    msgs = joint_messages("ros1", df, ns)
    m = Messages("ros1")
    renamed = []
    for topic, msgtype, rec, msg in msgs:
        names = [{"Joint1": "shoulder", "Joint2": "elbow"}.get(n, n) for n in msg.name]
        renamed.append((topic, msgtype, rec, m.joint_state(_stamp(msg), names, msg.position, msg.velocity, msg.effort)))
    ft = [("/ft", "geometry_msgs/msg/WrenchStamped", EPOCH + int(n) + 7, m.wrench(EPOCH + int(n) + 5, "tool", [1, 0, 0],
                                                                                  [0, 0, 0])) for n in ns[::3]]
    bag = write_bag(tmp_path / "named.bag", "ros1", sorted(renamed + ft, key=lambda x: x[2]))
    plain = write_bag(tmp_path / "plain.bag", "ros1", msgs)
    names = {"topics": {"joint_states": {"topic": "/joint_states", "names": {"Joint1": "shoulder", "Joint2": "elbow"}}}}
    got = load_log(bag, names, joints=["Joint1", "Joint2"])
    ref = load_log(plain, {"topics": {"joint_states": "/joint_states"}}, joints=["Joint1", "Joint2"])
    assert np.array_equal(got.q, ref.q) and np.array_equal(got.tau, ref.tau)
    on_ft = load_log(bag, {"topics": {**names["topics"], "wrenches": {"ft": "/ft"}, "time_base": "/ft"}},
                     joints=["Joint1", "Joint2"])
    expected = (ns[::3] - ns[0]) / 1e9  # the wrench stamps, 5 ns after joint samples 0, 3, …, 297 of 300
    assert np.array_equal(on_ft.t, expected) and on_ft.T == 100
    k = 10  # a wrench stamp lies 5 ns after joint sample 3k: q interpolated linearly between samples 3k and 3k + 1
    u = 5 / (ns[3 * k + 1] - ns[3 * k])
    assert np.allclose(on_ft.q[k], (1 - u) * ref.q[3 * k] + u * ref.q[3 * k + 1], rtol=0, atol=1e-12)


def _stamp(msg) -> int:
    return int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)


def test_the_topics_form_keeps_which_units_were_stated():
    """check_units reads ColumnMap.stated (a prismatic joint with an angular unit stated is refused): the topics form
    states the same units as the column form."""
    from dualid.data.io import ColumnMap

    topics = ColumnMap.from_dict({"topics": {"joint_states": "/js"}, "units": {"position": "deg"}}, ["Joint1"])
    plain = ColumnMap.from_dict({"joints": {"Joint1": {"position": "q", "effort": "t"}}, "units": {"position": "deg"}})
    assert topics.stated == plain.stated == (("", "position"),) and topics.topics is not None
