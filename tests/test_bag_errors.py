"""Malformed bags through ``dualid fit``: each is exit code 2 and one typed line naming the bag, the topic and
the field (or, for a file that is no bag at all, the file and what the reader found)."""

from __future__ import annotations

import inspect
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from dualid.cli import app
from tests.bag_files import EPOCH, Messages, write_bag

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "examples" / "dfki" / "data" / "pendubot_model_2.1.urdf"
BOX = ROOT / "examples" / "floating" / "box" / "box.urdf"
JS, WRENCH = "sensor_msgs/msg/JointState", "geometry_msgs/msg/WrenchStamped"
STEPS = [{"resample": {"rate": 500}}, {"differentiate": {"method": "savgol", "window": 0.1}}]
# the messages go to stderr, apart from stdout: click 8.1 (typer's floor 0.15.4 caps click < 8.2) mixes them
# unless told not to; click 8.2 keeps them apart and has no such option
runner = CliRunner(**({"mix_stderr": False} if "mix_stderr" in inspect.signature(CliRunner).parameters else {}))
N = 200


def joints(kind="ros1", topic="/joint_states", stamps=None, change=None):
    """N JointState messages at 500 Hz; change[k] replaces fields of message k."""
    m = Messages(kind)
    out = []
    for k in range(N):
        ns = EPOCH + k * 2_000_000 if stamps is None else stamps[k]
        f = dict(names=["Joint1", "Joint2", "gripper"], position=[math.sin(k / 30), math.cos(k / 20), 0.0],
                 velocity=[math.cos(k / 30) / 15, -math.sin(k / 20) / 10, 0.0], effort=[0.1 * math.sin(k / 10), 0.05, 0.0])
        f.update((change or {}).get(k, {}))
        out.append((topic, JS, EPOCH + k * 2_000_000 + 1000, m.joint_state(ns, **f)))
    return out


def wrenches(frames=("Link2",), every=1, start=0, stop=N, skip=()):
    m = Messages("ros1")
    return [("/ft", WRENCH, EPOCH + k * 2_000_000 + 2000, m.wrench(EPOCH + k * 2_000_000, frames[k % len(frames)],
                                                                   [0, 0, 1], [0, 0, 0]))
            for k in range(start, stop, every) if k not in skip]


def poses(msgtype, kind="ros1"):
    m = Messages(kind)
    out = []
    for k in range(N):
        ns, p, q = EPOCH + k * 2_000_000, [k * 1e-3, 0, 0], [0, 0, 0, 1]
        msg = m.pose_stamped(ns, p, q) if msgtype == "pose" else m.tf(ns, "map", "base_link", p, q)
        out.append(("/base", "geometry_msgs/msg/PoseStamped" if msgtype == "pose" else "tf2_msgs/msg/TFMessage", ns, msg))
    return out


def _bag(tmp: Path, messages, kind="ros1", topics=None) -> Path:
    return write_bag(tmp / ("run.bag" if kind == "ros1" else f"run_{kind}"), kind, sorted(messages, key=lambda x: x[2]),
                     topics)


def _truncated(tmp: Path, kind: str) -> Path:
    bag = _bag(tmp, joints(kind), kind)
    f = bag if kind == "ros1" else next(bag.glob("*.mcap"))
    f.write_bytes(f.read_bytes()[: f.stat().st_size // 2])
    return bag


def _text_file(tmp: Path, name: str) -> Path:
    path = tmp / name
    path.write_text("time,pos_meas1\n0.0,1.0\n")
    return path


TOPICS = {"joint_states": "/joint_states"}
CASES = {
    # name: (make the log, columns, expected in the one error line)
    "truncated ROS 1 bag": (lambda t: _truncated(t, "ros1"), TOPICS,
                            ["run.bag: cannot read it as a ROS bag", "damaged"]),
    "truncated MCAP storage": (lambda t: _truncated(t, "mcap"), TOPICS,
                               ["run_mcap: cannot read it as a ROS bag", "magic"]),
    "a text file named .bag": (lambda t: _text_file(t, "run.bag"), TOPICS,
                               ["run.bag: cannot read it as a ROS bag", "magic is invalid"]),
    "a CSV file with topics": (lambda t: _text_file(t, "run.csv"), TOPICS,
                               ["run.csv: columns.topics names ROS bag topics, but this is not a bag"]),
    "a bag with a column map": (lambda t: _bag(t, joints()), {"joints": {"Joint1": {"position": "q1", "effort": "t1"},
                                                                        "Joint2": {"position": "q2", "effort": "t2"}}},
                                ["run.bag: a ROS bag needs its topics named in the column map (columns.topics)"]),
    "wrong message type": (lambda t: _bag(t, [(topic, WRENCH, ns, Messages("ros1").wrench(ns, "Link2", [0] * 3, [0] * 3))
                                              for topic, _, ns, _ in joints()]), TOPICS,
                           ["topic '/joint_states' (columns.topics.joint_states) has message type "
                            "geometry_msgs/msg/WrenchStamped; expected sensor_msgs/msg/JointState"]),
    "a joint name missing": (lambda t: _bag(t, joints(change={7: dict(names=["Joint2", "J1", "gripper"])})), TOPICS,
                             ["topic '/joint_states' field name: joint 'Joint1' is missing in message 7",
                              "names there: ['Joint2', 'J1', 'gripper']"]),
    "stamps going backwards": (lambda t: _bag(t, joints(stamps=[EPOCH + k * 2_000_000 - (4_000_001 if k == 5 else 0)
                                                                for k in range(N)])), TOPICS,
                               ["topic '/joint_states' field header.stamp goes back at message 5",
                                f"{EPOCH + 8_000_000} ns then {EPOCH + 5_999_999} ns"]),
    "a repeated stamp": (lambda t: _bag(t, joints(stamps=[EPOCH + (k - (k == 9)) * 2_000_000 for k in range(N)])), TOPICS,
                         ["topic '/joint_states' field header.stamp repeats at message 9"]),
    "an empty topic": (lambda t: _bag(t, joints(), topics={"/ft": WRENCH}), {**TOPICS, "wrenches": {"ft": "/ft"}},
                       ["topic '/ft' (columns.topics.wrenches.ft) has no messages"]),
    "a missing topic": (lambda t: _bag(t, joints(topic="/robot/joint_states")), TOPICS,
                        ["topic '/joint_states' (columns.topics.joint_states) is not in the bag; its topics: "
                         "['/robot/joint_states']"]),
    "no velocities": (lambda t: _bag(t, joints(change={k: dict(velocity=[]) for k in range(N)})), TOPICS,
                      ["topic '/joint_states' field velocity: message 0 has 0 values for 3 joint names",
                       "velocity: false"]),
    "an effort array too short": (lambda t: _bag(t, joints(change={3: dict(effort=[0.1, 0.2])})), TOPICS,
                                  ["topic '/joint_states' field effort: message 3 has 2 values for 3 joint names"]),
    "a NaN effort": (lambda t: _bag(t, joints(change={11: dict(effort=[np.nan, 0.0, 0.0])})), TOPICS,
                     ["column '/joint_states.effort[Joint1]' has non-finite values (NaN or inf), first at row 11"]),
    "wrench frames changing": (lambda t: _bag(t, joints() + wrenches(("Link2", "Link1"))),
                               {**TOPICS, "wrenches": {"ft": "/ft"}},
                               ["topic '/ft' field header.frame_id: the messages name 2 frames ['Link1', 'Link2']"]),
    "a gap in a topic": (lambda t: _bag(t, joints() + wrenches(skip=range(50, 150))), {**TOPICS, "wrenches": {"ft": "/ft"}},
                         ["topic '/ft': a gap of 0.202 s", "refusing to interpolate across it"]),
    "topics that do not overlap": (lambda t: _bag(t, joints(stamps=[EPOCH + k * 2_000_000 for k in range(N)])
                                                  + wrenches(start=N, stop=2 * N)),
                                   {**TOPICS, "wrenches": {"ft": "/ft"}},
                                   ["the topics do not overlap in time (header.stamp)", "'/ft': '[1700000000.400000000, 1700000000.798000000] s'"]),
    "a pose has no twist": (lambda t: _bag(t, poses("pose")), {"base": "/base"},
                            ["topic '/base' (columns.topics.base) is a geometry_msgs/msg/PoseStamped: it has no field "
                             "twist; set columns.topics.base.twist: false"]),
    "a transform not on /tf": (lambda t: _bag(t, poses("tf", "sqlite3"), "sqlite3"), {"base": {"topic": "/base", "parent": "odom",
                                                                         "child": "base_link"}},
                               ["topic '/base' field transforms: no transform odom->base_link", "['map->base_link']"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_malformed_bag_is_one_typed_line_naming_topic_and_field_and_exit_2(tmp_path, case):
    make, columns, expected = CASES[case]
    log = make(tmp_path)
    floating = "base" in columns
    model = {"urdf": str(BOX if floating else URDF), "floating_base": floating}
    config = {"model": model, "columns": columns if "joints" in columns else {"topics": columns}, "train": [str(log)], "preprocessing": STEPS,
              "methods": ["ols"]}
    (tmp_path / "fit.yaml").write_text(yaml.safe_dump(config))
    result = runner.invoke(app, ["fit", "--config", str(tmp_path / "fit.yaml"), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2, result.output
    assert isinstance(result.exception, SystemExit) and "Traceback" not in result.output + result.stderr
    errors = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, result.stderr  # the whole message on that one line (below)
    assert str(log) in errors[0]
    for text in expected:
        assert text in errors[0], errors[0]
    debug = runner.invoke(app, ["--debug", "fit", "--config", str(tmp_path / "fit.yaml"), "--out", str(tmp_path / "o")])
    from dualid.errors import DataError

    assert isinstance(debug.exception, DataError)  # the project's error tree, not a library's exception
    shutil.rmtree(tmp_path / "o", ignore_errors=True)


@pytest.mark.parametrize("topics,message", [
    ({"joint_states": "/js", "rate": 500}, "column map: topics.: unknown keys ['rate']"),
    ({"joint_states": "/js", "time_base": "/odom"}, "topics.time_base: '/odom' is none of the mapped topics ['/js']"),
    ({"joint_states": {"topic": "/js", "velocity": True}, "base": {"topic": "/tf", "parent": "odom", "child": "base"}},
     "joint_states.velocity: true needs a base twist too"),
    ({"joint_states": {"topic": "/js", "names": {"Joint9": "j9"}}}, "joint_states.names: ['Joint9'] are not model joints"),
    ({"joint_states": {"topic": "/js", "passive": ["Joint9"]}}, "joint_states.passive: ['Joint9'] are not model joints"),
    ({"stamps": "sent", "joint_states": "/js"}, "topics.stamps: expected one of ['header', 'receive'], got 'sent'"),
    ({"wrenches": {"ft": "/ft"}}, "topics: name a joint_states topic or a base topic"),
])
def test_a_topic_map_that_cannot_be_used_names_its_key(topics, message):
    from dualid.data.io import ColumnMap
    from dualid.errors import DataError

    with pytest.raises(DataError, match=message.replace("[", r"\[").replace("(", r"\(")):
        ColumnMap.from_dict({"topics": topics}, ["Joint1", "Joint2"])


def test_a_bag_with_two_joint_state_topics_needs_a_config_and_inspect_refuses_a_non_bag(tmp_path):
    bag = _bag(tmp_path, joints() + joints(topic="/arm/joint_states"))
    result = runner.invoke(app, ["fit", "--model", str(URDF), "--data", str(bag), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert (f"{bag}: 2 sensor_msgs/msg/JointState topics ['/arm/joint_states', '/joint_states']; name the joint states "
            "in a config") in " ".join(result.stderr.split())
    (tmp_path / "t").mkdir()
    for path, text in ((_text_file(tmp_path, "run.csv"), "not a ROS bag"),
                       (_truncated(tmp_path / "t", "ros1"), "cannot read it as a ROS bag")):
        listing = runner.invoke(app, ["inspect", str(path)])
        assert listing.exit_code == 2 and text in listing.stderr and str(path) in listing.stderr


def test_the_topics_form_needs_the_model_joints_from_the_library():
    from dualid.data.io import ColumnMap
    from dualid.errors import DataError

    with pytest.raises(DataError, match=r"the joints to read are the model's; pass them \(load_log\(\.\.\., joints=…\)\)"):
        ColumnMap.from_dict({"topics": {"joint_states": "/js"}})
    assert ColumnMap.from_dict({"topics": {"base": "/odom"}}).base is not None  # a single floating body has none
