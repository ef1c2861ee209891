"""ROS bags written with the ``rosbags`` library's own writers (ROS 1, rosbag2 sqlite3, rosbag2 MCAP), for
the bag-reading tests: messages are given as (topic, msgtype, stamp [ns], fields) and serialized by the
library's typestores."""

from __future__ import annotations

from pathlib import Path

import numpy as np

KINDS = ("ros1", "sqlite3", "mcap")
EPOCH = 1_700_000_000 * 10**9  # [ns] stamps as a robot's clock gives them


def _typestore(kind: str):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)


class Messages:
    """Builds messages of one typestore (ROS 1 headers carry a seq)."""

    def __init__(self, kind: str):
        self.kind, self.ts = kind, _typestore(kind)
        self.T = self.ts.types

    def header(self, ns: int, frame: str = ""):
        Time, Header = self.T["builtin_interfaces/msg/Time"], self.T["std_msgs/msg/Header"]
        extra = {"seq": 0} if "seq" in Header.__dataclass_fields__ else {}
        return Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id=frame, **extra)

    def vec(self, x, name="geometry_msgs/msg/Vector3"):
        return self.T[name](*[float(v) for v in x])

    def quat(self, x):
        return self.T["geometry_msgs/msg/Quaternion"](*[float(v) for v in x])

    def joint_state(self, ns, names, position, velocity=(), effort=()):
        a = lambda x: np.asarray(x, dtype=np.float64)
        return self.T["sensor_msgs/msg/JointState"](self.header(ns), list(names), a(position), a(velocity), a(effort))

    def wrench(self, ns, frame, force, torque):
        W = self.T["geometry_msgs/msg/Wrench"](self.vec(force), self.vec(torque))
        return self.T["geometry_msgs/msg/WrenchStamped"](self.header(ns, frame), W)

    def pose(self, p, q):
        return self.T["geometry_msgs/msg/Pose"](self.vec(p, "geometry_msgs/msg/Point"), self.quat(q))

    def pose_stamped(self, ns, p, q, frame="world"):
        return self.T["geometry_msgs/msg/PoseStamped"](self.header(ns, frame), self.pose(p, q))

    def odometry(self, ns, p, q, twist, frame="world", child="base_link"):
        T = self.T
        cov = np.zeros(36)
        pose = T["geometry_msgs/msg/PoseWithCovariance"](self.pose(p, q), cov)
        tw = T["geometry_msgs/msg/TwistWithCovariance"](T["geometry_msgs/msg/Twist"](self.vec(twist[:3]),
                                                                                      self.vec(twist[3:])), cov)
        return T["nav_msgs/msg/Odometry"](self.header(ns, frame), child, pose, tw)

    def tf(self, ns, parent, child, p, q):
        T = self.T
        tr = T["geometry_msgs/msg/TransformStamped"](self.header(ns, parent), child,
                                                     T["geometry_msgs/msg/Transform"](self.vec(p), self.quat(q)))
        return T["tf2_msgs/msg/TFMessage"]([tr])


def write_bag(path: Path, kind: str, messages, topics: dict[str, str] | None = None) -> Path:
    """A bag at ``path`` (a .bag file for ROS 1, a folder for rosbag2) holding ``messages``: (topic, msgtype,
    record time [ns], message) in record order; ``topics`` adds topics with no messages {topic: msgtype}."""
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    ts = _typestore(kind)
    conns = {}
    messages = list(messages)
    types = dict(topics or {})
    types.update({t: m for t, m, _, _ in messages})
    if kind == "ros1":
        writer = Writer1(path)
    else:
        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer = Writer2(path, version=9, storage_plugin=plugin)
    with writer:
        for topic, msgtype in types.items():
            conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
        for topic, msgtype, ns, msg in messages:
            raw = ts.serialize_ros1(msg, msgtype) if kind == "ros1" else ts.serialize_cdr(msg, msgtype)
            writer.write(conns[topic], ns, raw)
    return path


def bag_name(tmp: Path, kind: str, stem: str = "run") -> Path:
    return tmp / (f"{stem}.bag" if kind == "ros1" else f"{stem}_{kind}")
