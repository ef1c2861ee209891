"""What a ROS bag holds (``dualid inspect``): its topics with their message types, counts, rates and
durations (from the bag's record times), the joint names of joint-state topics and the frames of wrench
and /tf topics; and the ``columns.topics`` section that reads the topics dualid knows."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dualid.data.bag_topics import JOINT_STATE, ODOMETRY, POSE, TF, WRENCH
from dualid.data.bags import open_bag
from dualid.errors import DataError


@dataclass(frozen=True)
class TopicSummary:
    topic: str
    msgtype: str
    count: int
    start: float  # [s] first record time after the bag's start
    duration: float  # [s] first to last record time
    rate: float  # [Hz] (count − 1) / duration; 0 for fewer than 2 messages
    joints: tuple[str, ...] = ()  # a JointState's names (its first message)
    velocity: bool = False  # a JointState's first message carries velocities
    frames: tuple[str, ...] = ()  # a WrenchStamped's header.frame_id, a TFMessage's parent->child pairs (first message)


@dataclass(frozen=True)
class BagSummary:
    path: Path
    kind: str  # "ROS 1" or "rosbag2 (sqlite3)" / "rosbag2 (mcap)"
    duration: float  # [s]
    topics: tuple[TopicSummary, ...]

    def of_type(self, msgtype: str) -> list[TopicSummary]:
        return [t for t in self.topics if t.msgtype == msgtype]


def _topic(reader, topic: str, info, times: list[int], first, start: int) -> TopicSummary:
    t = np.asarray(times, dtype=np.int64)
    duration = float(t[-1] - t[0]) / 1e9 if t.size else 0.0
    joints: tuple[str, ...] = ()
    frames: tuple[str, ...] = ()
    velocity = False
    if first is not None:
        msg = reader.deserialize(first[1], first[0].msgtype)
        if info.msgtype == JOINT_STATE:
            joints, velocity = tuple(msg.name), len(msg.velocity) == len(msg.name) > 0
        elif info.msgtype == WRENCH:
            frames = (msg.header.frame_id,)
        elif info.msgtype == TF:
            frames = tuple(f"{tr.header.frame_id}->{tr.child_frame_id}" for tr in msg.transforms)
    return TopicSummary(topic, str(info.msgtype), t.size, float(t[0] - start) / 1e9 if t.size else 0.0, duration,
                        (t.size - 1) / duration if duration > 0 else 0.0, joints, velocity, frames)


def bag_summary(path) -> BagSummary:
    """The topics of a bag (see the module docstring)."""
    path = Path(path)

    def body(reader) -> BagSummary:
        info = reader.topics
        times: dict[str, list[int]] = {t: [] for t in info}
        first: dict[str, tuple] = {}
        for conn, stamp, raw in reader.messages():
            times[conn.topic].append(stamp)
            first.setdefault(conn.topic, (conn, raw))
        start = reader.start_time if reader.message_count else 0
        topics = tuple(_topic(reader, t, info[t], times[t], first.get(t), start) for t in sorted(info))
        storage = "ROS 1" if not reader.is2 else "rosbag2 (mcap)" if any(
            p.suffix == ".mcap" or list(p.glob("*.mcap")) for p in reader.paths) else "rosbag2 (sqlite3)"
        return BagSummary(path, storage, reader.duration / 1e9 if reader.message_count else 0.0, topics)

    return open_bag(path, body)


def _name(topic: str) -> str:
    return re.sub(r"\W+", "_", topic).strip("_") or "wrench"


def default_topics(summary: BagSummary, everything: bool = False) -> dict:
    """The ``columns.topics`` section for the bag's one JointState topic; with ``everything`` (a starter config)
    the JointState topic with the most messages, the first Odometry (else PoseStamped) topic as the floating
    base and every WrenchStamped topic as a wrench."""
    js = sorted(summary.of_type(JOINT_STATE), key=lambda t: -t.count)  # with everything: the longest of several
    if not everything and len(js) != 1:
        raise DataError(f"{summary.path}: {len(js)} {JOINT_STATE} topics {[t.topic for t in js]}; name the joint "
                        "states in a config (columns.topics.joint_states; dualid inspect prints a starter)")
    out: dict = {"stamps": "header"}
    base = (summary.of_type(ODOMETRY) or summary.of_type(POSE)) if everything else []
    if js:
        out["joint_states"] = {"topic": js[0].topic}
        if not js[0].velocity or (base and base[0].msgtype == POSE):
            out["joint_states"]["velocity"] = False
    if base:
        out["base"] = {"topic": base[0].topic, "twist": base[0].msgtype == ODOMETRY}
    wrenches = summary.of_type(WRENCH) if everything else []
    if wrenches:
        out["wrenches"] = {_name(w.topic): {"topic": w.topic, "reference": "local"} for w in wrenches}
    return out
