"""The ``topics`` form of a column map: which topics of a ROS bag hold the joints, the floating base and
the external wrenches, and the channel names (``topic.field``) the bag reader gives their values.

YAML form (inside ``columns``)::

    topics:
      stamps: header                      # header (each message's header.stamp, default) or receive (the bag's record time)
      time_base: /joint_states            # optional: the topic whose stamps are the time base (default: the joint
                                          # states, else the base topic); the others are interpolated onto them
      joint_states: /joint_states         # sensor_msgs/JointState; or {topic, velocity, names, passive}
      #   velocity: null (default: logged when every source has one), true, or false (v from dq/dt)
      #   names: {Joint1: shoulder_joint}  (model joint -> its name in the messages; default the same name)
      #   passive: [alpha1]               (unactuated joints: τ = 0, their effort is not read)
      base: {topic: /odom}                # nav_msgs/Odometry (pose and twist), geometry_msgs/PoseStamped
                                          # (twist: false), or tf2_msgs/TFMessage with {parent: odom, child:
                                          # base_link}; twist: false also ignores an odometry's twist
      wrenches:
        ft: {topic: /ft_sensor, reference: local}   # geometry_msgs/WrenchStamped; the frame is the messages'
                                                    # header.frame_id unless 'frame' names another one

Joints are matched by name in every message (any order; joints the model does not have are ignored).
An odometry's twist is in its child frame (REP 105), Pinocchio's LOCAL base velocity. A base without a
twist (a pose or /tf topic, or twist: false) takes every velocity from the differentiation: the joint
velocities are then not read either (velocity: null), so v is one kind of estimate throughout.
The base channels are named ``TOPIC.position.x``, ``TOPIC.orientation.w``, ``TOPIC.twist.linear.x``
whatever the message type; joints ``TOPIC.position[NAME]``; wrenches ``TOPIC.wrench.force.x``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

from dualid.errors import DataError

JOINT_STATE = "sensor_msgs/msg/JointState"
WRENCH = "geometry_msgs/msg/WrenchStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
POSE = "geometry_msgs/msg/PoseStamped"
TF = "tf2_msgs/msg/TFMessage"
BASE_TYPES = (ODOMETRY, POSE, TF)
STAMPS = ("header", "receive")
WRENCH_FRAME = "header.frame_id"  # placeholder frame of a wrench until the bag is read
XYZ, XYZW = ("x", "y", "z"), ("x", "y", "z", "w")
_WHERE = "column map: topics"


def _keys(d, allowed: tuple[str, ...], where: str, shorthand: str | None = None) -> dict:
    if isinstance(d, str) and shorthand:
        d = {shorthand: d}
    if not isinstance(d, Mapping):
        raise DataError(f"{_WHERE}.{where}: expected a mapping with keys {list(allowed)}, got {d!r}")
    bad = sorted(set(d) - set(allowed))
    if bad:
        raise DataError(f"{_WHERE}.{where}: unknown keys {bad}; allowed: {list(allowed)}")
    topic = d.get("topic")
    if "topic" in allowed and (not isinstance(topic, str) or not topic):
        raise DataError(f"{_WHERE}.{where}.topic: expected a topic name, got {topic!r}")
    return dict(d)


def _flag(x, where: str, none_ok: bool = False):
    if (x is None and none_ok) or isinstance(x, bool):
        return x
    raise DataError(f"{_WHERE}.{where}: expected true or false{' or null' if none_ok else ''}, got {x!r}")


@dataclass(frozen=True)
class BaseTopic:
    topic: str
    parent: str | None = None  # a /tf topic: the transform parent_T_child
    child: str | None = None
    twist: bool = True  # an odometry's twist (ignored with false: the base velocity from the poses)

    @property
    def is_tf(self) -> bool:
        return self.parent is not None or self.child is not None


@dataclass(frozen=True)
class WrenchTopic:
    name: str
    topic: str
    frame: str | None = None  # None: the messages' header.frame_id
    reference: str = "local"


@dataclass(frozen=True)
class TopicMap:
    """Where the joints, the base and the wrenches are in a bag (see the module docstring)."""

    joint_states: str | None = None
    velocity: bool | None = None
    names: tuple[tuple[str, str], ...] = ()  # (model joint, name in the messages)
    passive: tuple[str, ...] = ()  # model joints without an actuator (τ = 0)
    base: BaseTopic | None = None
    wrenches: tuple[WrenchTopic, ...] = ()
    stamps: str = "header"
    time_base: str | None = None

    @staticmethod
    def from_dict(d) -> "TopicMap":
        d = _keys(d, ("stamps", "time_base", "joint_states", "base", "wrenches"), "")
        if d.get("stamps", "header") not in STAMPS:
            raise DataError(f"{_WHERE}.stamps: expected one of {list(STAMPS)}, got {d.get('stamps')!r}")
        js = None if d.get("joint_states") is None else _keys(d["joint_states"], ("topic", "velocity", "names", "passive"),
                                                              "joint_states", "topic")
        names = (js or {}).get("names") or {}
        if not isinstance(names, Mapping) or not all(isinstance(v, str) and v for v in names.values()):
            raise DataError(f"{_WHERE}.joint_states.names: expected {{model joint: name in the messages}}, got {names!r}")
        passive = (js or {}).get("passive") or []
        if not isinstance(passive, list) or not all(isinstance(j, str) and j for j in passive):
            raise DataError(f"{_WHERE}.joint_states.passive: expected a list of model joints, got {passive!r}")
        base = None
        if d.get("base") is not None:
            b = _keys(d["base"], ("topic", "parent", "child", "twist"), "base", "topic")
            base = BaseTopic(b["topic"], b.get("parent"), b.get("child"), _flag(b.get("twist", True), "base.twist"))
        wrenches = d.get("wrenches") or {}
        if not isinstance(wrenches, Mapping):
            raise DataError(f"{_WHERE}.wrenches: expected {{name: {{topic, frame, reference}}}}, got {wrenches!r}")
        ws = []
        for name, w in wrenches.items():
            w = _keys(w, ("topic", "frame", "reference"), f"wrenches.{name}", "topic")
            ws.append(WrenchTopic(str(name), w["topic"], w.get("frame"), w.get("reference", "local")))
        if js is None and base is None:
            raise DataError(f"{_WHERE}: name a joint_states topic or a base topic")
        out = TopicMap(None if js is None else js["topic"], _flag((js or {}).get("velocity"), "joint_states.velocity", True),
                       tuple((str(k), str(v)) for k, v in names.items()), tuple(passive), base, tuple(ws),
                       d.get("stamps", "header"), d.get("time_base"))
        if out.time_base is not None and out.time_base not in out.topics():
            raise DataError(f"{_WHERE}.time_base: {out.time_base!r} is none of the mapped topics {list(out.topics())}")
        if out.velocity and base is not None and not out.base_twist:
            raise DataError(f"{_WHERE}.joint_states.velocity: true needs a base twist too (an odometry topic with "
                            f"twist: true); {base.topic!r} gives poses only: set velocity: false (v from dq/dt)")
        return out

    def to_dict(self) -> dict:
        out: dict = {"stamps": self.stamps}
        if self.time_base is not None:
            out["time_base"] = self.time_base
        if self.joint_states is not None:
            out["joint_states"] = {"topic": self.joint_states, "velocity": self.velocity,
                                   **({"names": dict(self.names)} if self.names else {}),
                                   **({"passive": list(self.passive)} if self.passive else {})}
        if self.base is not None:
            b = self.base
            out["base"] = {"topic": b.topic, "twist": b.twist, **({"parent": b.parent, "child": b.child} if b.parent else {})}
        if self.wrenches:
            out["wrenches"] = {w.name: {"topic": w.topic, "reference": w.reference, **({"frame": w.frame} if w.frame else {})}
                               for w in self.wrenches}
        return out

    # -- queries -----------------------------------------------------------------------------------
    def topics(self) -> dict[str, str]:
        """topic -> its key in the config (joint_states, base, wrenches.NAME)."""
        out = {} if self.joint_states is None else {self.joint_states: "joint_states"}
        if self.base is not None:
            out.setdefault(self.base.topic, "base")
        for w in self.wrenches:
            out.setdefault(w.topic, f"wrenches.{w.name}")
        return out

    @property
    def primary(self) -> str:
        """The topic whose stamps are the time base."""
        return self.time_base or self.joint_states or self.base.topic  # type: ignore[union-attr]

    @property
    def base_twist(self) -> bool:
        return self.base is not None and self.base.twist and not self.base.is_tf

    def message_name(self, joint: str) -> str:
        return dict(self.names).get(joint, joint)

    @property
    def time_channel(self) -> str:
        return f"{self.primary}.header.stamp" if self.stamps == "header" else f"{self.primary} receive time"

    def columns(self, joints) -> dict:
        """The column-map dict form reading this map's channels for the model's ``joints`` (names)."""
        logged_v = self.velocity is not False and (self.base is None or self.base_twist)
        js = self.joint_states
        if joints and js is None:
            raise DataError(f"{_WHERE}: the model has joints {list(joints)} but no joint_states topic is named")
        for key, listed in (("names", [j for j, _ in self.names]), ("passive", self.passive)):
            unknown = [j for j in listed if j not in joints]
            if unknown:
                raise DataError(f"{_WHERE}.joint_states.{key}: {unknown} are not model joints; model joints: {list(joints)}")
        out: dict = {"time": self.time_channel, "joints": {}}
        for j in joints:
            m = self.message_name(j)
            out["joints"][j] = {"position": f"{js}.position[{m}]", "effort": 0 if j in self.passive else f"{js}.effort[{m}]",
                                **({"velocity": f"{js}.velocity[{m}]"} if logged_v else {})}
        if self.base is not None:
            b = self.base.topic
            out["base"] = {"position": [f"{b}.position.{c}" for c in XYZ], "quaternion": [f"{b}.orientation.{c}" for c in XYZW]}
            if logged_v:
                out["base"]["twist"] = [f"{b}.twist.{k}.{c}" for k in ("linear", "angular") for c in XYZ]
        out["wrenches"] = {w.name: {"frame": w.frame or WRENCH_FRAME, "reference": w.reference,
                                    "force": [f"{w.topic}.wrench.force.{c}" for c in XYZ],
                                    "torque": [f"{w.topic}.wrench.torque.{c}" for c in XYZ]} for w in self.wrenches}
        return out
