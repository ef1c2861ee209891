"""Reading ROS 1 bags (``.bag``) and rosbag2 recordings (a folder with metadata.yaml, sqlite3 or MCAP
storage) with the pure-Python ``rosbags`` library: the topics a ``TopicMap`` names become float channels on
one time base, which ``load_log`` then reads through its column map like the columns of a CSV file.

Time: each message's header.stamp (or, with ``stamps: receive``, the time the bag recorded it), in integer
nanoseconds, relative to the first sample of the time base (``TopicMap.primary``): t = (stamp − stamp₀)/1e9.
Topics at other rates are interpolated onto the time-base stamps where all topics overlap, vectors linearly
(``preprocessing.interpolate``) and a base pose along the geodesic (``lie.interpolate_on_group``), the
interpolation ``preprocessing.resample`` uses; a topic with the time base's own stamps is taken as it is.
Every error names the bag, the topic and the field.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dualid.data.bag_topics import BASE_TYPES, JOINT_STATE, ODOMETRY, POSE, TF, WRENCH, XYZ, XYZW, TopicMap
from dualid.data.checks import check_gaps
from dualid.data.lie import interpolate_on_group, unit_quaternions
from dualid.data.preprocessing import interpolate
from dualid.data.tables import read_once
from dualid.errors import DataError, MissingFileError

BAG_SUFFIXES = (".bag", ".mcap", ".db3")


def is_bag(path) -> bool:
    """A ROS 1 bag, a rosbag2 storage file, or a rosbag2 folder (with metadata.yaml)."""
    p = Path(path)
    return p.suffix.lower() in BAG_SUFFIXES or (p.is_dir() and (p / "metadata.yaml").is_file())


def _reader(path: Path):
    from rosbags.highlevel import AnyReader

    if not path.exists():
        raise MissingFileError(f"bag not found: {path}")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise DataError(f"{path}: a folder but not a rosbag2 recording (no metadata.yaml)")
    return AnyReader([path])


def open_bag(path: Path, body):
    """body(reader) inside an open reader; the library's errors as a DataError naming the bag."""
    from rosbags.highlevel import AnyReaderError

    try:
        with _reader(path) as reader:
            return body(reader)
    except AnyReaderError as exc:  # a damaged, truncated or foreign file (rosbags wraps its readers' errors)
        raise DataError(f"{path}: cannot read it as a ROS bag ({exc})") from None


def _stamp(msg) -> int:
    s = msg.header.stamp
    return int(s.sec) * 1_000_000_000 + int(s.nanosec)


@dataclass
class _Series:
    """One topic's messages: stamps [ns] and named float channels."""

    topic: str
    stamps: list
    values: dict
    frames: set


def _joint_values(where: str, msg, k: int, fields: dict[str, list[str]]) -> dict:
    """{field[joint]: value} of one JointState message; ``fields``: the joints (message names) read per field."""
    names = list(msg.name)
    index = {n: i for i, n in enumerate(names)}
    missing = [j for j in fields["position"] if j not in index]
    if missing:
        raise DataError(f"{where} field name: joint {missing[0]!r} is missing in message {k} (names there: {names}); "
                        "map model joints to other names with columns.topics.joint_states.names")
    out: dict[str, float] = {}
    for field, joints in fields.items():
        x = np.asarray(getattr(msg, field), dtype=float)
        if joints and x.size != len(names):
            hint = {"velocity": "; set columns.topics.joint_states.velocity: false to take v from dq/dt",
                    "effort": "; list unactuated joints in columns.topics.joint_states.passive"}.get(field, "")
            raise DataError(f"{where} field {field}: message {k} has {x.size} values for {len(names)} joint names{hint}")
        out.update((f"{field}[{j}]", x[index[j]]) for j in joints)
    return out


def _vec(obj, keys) -> list[float]:
    return [float(getattr(obj, c)) for c in keys]


POSE_FIELDS = [f"position.{c}" for c in XYZ] + [f"orientation.{c}" for c in XYZW]
TWIST_FIELDS = [f"twist.{k}.{c}" for k in ("linear", "angular") for c in XYZ]
WRENCH_FIELDS = [f"wrench.{k}.{c}" for k in ("force", "torque") for c in XYZ]


def _check_topics(path: Path, topics: TopicMap, info) -> dict[str, str]:
    """topic -> message type, after checking each mapped topic is in the bag, of its type and not empty."""
    types = {}
    for topic, key in topics.topics().items():
        expected = (JOINT_STATE,) if key == "joint_states" else BASE_TYPES if key == "base" else (WRENCH,)
        where = f"{path}: topic {topic!r} (columns.topics.{key})"
        if topic not in info:
            raise DataError(f"{where} is not in the bag; its topics: {sorted(info)}")
        types[topic] = info[topic].msgtype
        if types[topic] not in expected:
            raise DataError(f"{where} has message type {types[topic]}; expected {' or '.join(expected)}")
        if info[topic].msgcount == 0:
            raise DataError(f"{where} has no messages")
    if topics.base is not None:
        b, kind = topics.base, types[topics.base.topic]
        where = f"{path}: topic {b.topic!r} (columns.topics.base)"
        if kind == TF and not (b.parent and b.child):
            raise DataError(f"{where} is a {TF}: name the transform with parent and child frames")
        if kind != TF and b.is_tf:
            raise DataError(f"{where} is a {kind}, not a {TF}: leave out parent and child")
        if kind == POSE and b.twist:
            raise DataError(f"{where} is a {POSE}: it has no field twist; set columns.topics.base.twist: false")
    return types


def _samples(kind: str, msg, topics: TopicMap, where: str, k: int, joints: list[str]) -> list[tuple]:
    """(the part of the message whose header stamps it, its values by field) for each sample in message k."""
    if kind == JOINT_STATE:
        passive = {topics.message_name(j) for j in topics.passive}
        velocity = topics.velocity is not False and (topics.base is None or topics.base_twist)
        fields = {"position": joints, "velocity": joints if velocity else [],
                  "effort": [j for j in joints if j not in passive]}
        return [(msg, _joint_values(where, msg, k, fields))]
    if kind == WRENCH:
        return [(msg, dict(zip(WRENCH_FIELDS, _vec(msg.wrench.force, XYZ) + _vec(msg.wrench.torque, XYZ))))]
    if kind == TF:
        base = topics.base
        return [(tr, dict(zip(POSE_FIELDS, _vec(tr.transform.translation, XYZ) + _vec(tr.transform.rotation, XYZW))))
                for tr in msg.transforms if (tr.header.frame_id, tr.child_frame_id) == (base.parent, base.child)]  # type: ignore[union-attr]
    pose = msg.pose.pose if kind == ODOMETRY else msg.pose
    values = dict(zip(POSE_FIELDS, _vec(pose.position, XYZ) + _vec(pose.orientation, XYZW)))
    if kind == ODOMETRY and topics.base_twist:
        values.update(zip(TWIST_FIELDS, _vec(msg.twist.twist.linear, XYZ) + _vec(msg.twist.twist.angular, XYZ)))
    return [(msg, values)]


def _collect(path: Path, topics: TopicMap, joints: list[str], reader) -> tuple[dict[str, _Series], dict[str, str]]:
    types = _check_topics(path, topics, reader.topics)
    series = {t: _Series(t, [], {}, set()) for t in types}
    rows: dict[str, list] = {t: [] for t in types}
    seen: dict[str, int] = {t: 0 for t in types}  # messages per topic
    for conn, received, raw in reader.messages(connections=[c for c in reader.connections if c.topic in types]):
        topic, kind, s = conn.topic, types[conn.topic], series[conn.topic]
        msg = reader.deserialize(raw, conn.msgtype)
        for part, values in _samples(kind, msg, topics, f"{path}: topic {topic!r}", seen[topic], joints):
            s.stamps.append(_stamp(part) if topics.stamps == "header" else received)
            rows[topic].append(values)
        seen[topic] += 1
        if kind == WRENCH:
            s.frames.add(msg.header.frame_id)
        elif kind == TF and not rows[topic]:  # listed in the error when the base's transform never comes
            s.frames.update(f"{tr.header.frame_id}->{tr.child_frame_id}" for tr in msg.transforms)
    for topic, s in series.items():
        if not rows[topic]:  # only a /tf topic without the base's transform: the others have messages
            pair = "" if topics.base is None else f"{topics.base.parent}->{topics.base.child} "
            raise DataError(f"{path}: topic {topic!r} field transforms: no transform {pair}(header.frame_id->"
                            f"child_frame_id); transforms there: {sorted(s.frames)}")
        s.values = {f"{topic}.{c}": np.array([r[c] for r in rows[topic]]) for c in rows[topic][0]}
    frames = {}
    for w in topics.wrenches:
        found = series[w.topic].frames
        if len(found) != 1 and w.frame is None:
            raise DataError(f"{path}: topic {w.topic!r} field header.frame_id: the messages name {len(found)} frames "
                            f"{sorted(found)}; expected one (or set columns.topics.wrenches.{w.name}.frame)")
        frames[w.name] = w.frame or next(iter(found))
    return series, frames


def _check_stamps(path: Path, s: _Series, field: str) -> np.ndarray:
    st = np.asarray(s.stamps, dtype=np.int64)
    if st.size < 2:
        raise DataError(f"{path}: topic {s.topic!r} has {st.size} sample; need at least 2")
    d = np.diff(st)
    if np.any(d <= 0):
        k = int(np.argmax(d <= 0))
        what = "repeats" if d[k] == 0 else "goes back"
        raise DataError(f"{path}: topic {s.topic!r} field {field} {what} at message {k + 1}: {st[k]} ns then "
                        f"{st[k + 1]} ns ({int(np.sum(d <= 0))} such steps); stamps must increase")
    return st


def read_bag(path, topics: TopicMap, joints) -> tuple[dict[str, np.ndarray], list[str], dict[str, str]]:
    """(channels name -> (T,) on the time base, their order, wrench name -> frame) of a bag; ``joints``: the names
    in the joint-state messages to read. Inside ``tables.reading_once`` each bag is read once per map."""
    path = Path(path)
    if not path.exists():
        raise MissingFileError(f"bag not found: {path}")
    return read_once(path, (topics, tuple(joints)), lambda: _read_bag(path, topics, joints))


def _read_bag(path: Path, topics: TopicMap, joints) -> tuple[dict[str, np.ndarray], list[str], dict[str, str]]:
    series, frames = open_bag(path, lambda r: _collect(path, topics, list(joints), r))
    field = "header.stamp" if topics.stamps == "header" else "receive time"
    stamps = {t: _check_stamps(path, s, field) for t, s in series.items()}
    lo, hi = max(int(s[0]) for s in stamps.values()), min(int(s[-1]) for s in stamps.values())
    base_st = stamps[topics.primary]
    keep = (base_st >= lo) & (base_st <= hi)
    if keep.sum() < 2:
        sec = lambda ns: f"{int(ns) // 10**9}.{int(ns) % 10**9:09d}"
        spans = {t: f"[{sec(s[0])}, {sec(s[-1])}] s" for t, s in stamps.items()}
        raise DataError(f"{path}: the topics do not overlap in time ({field}): {spans}")
    grid = base_st[keep]
    t0 = int(grid[0])
    t = (grid - t0) / 1e9
    out = {topics.time_channel: t}
    for topic, s in series.items():
        st = stamps[topic]
        same = st.size == base_st.size and np.array_equal(st, base_st)
        values = {k: (v[keep] if same else v) for k, v in s.values.items()}
        if not same:
            ts = (st - t0) / 1e9
            check_gaps(ts, f"{path}: topic {topic!r}")
            values = _interpolated(path, topic, ts, values, t)
        out.update(values)
    return out, list(out), frames


def _interpolated(path: Path, topic: str, ts: np.ndarray, values: dict, t: np.ndarray) -> dict:
    """The channels of one topic at times t: a pose on SE(3) (geodesic), the rest linearly."""
    names = list(values)
    pose = [n for n in names if ".position." in n or ".orientation." in n]
    out = {}
    if pose:
        x = np.stack([values[n] for n in pose], axis=1)
        x[:, 3:7], _ = unit_quaternions(x[:, 3:7], f"{path}: topic {topic!r}", pose[3:7])
        x = interpolate_on_group(ts, x, 6, t)
        out.update({n: x[:, k] for k, n in enumerate(pose)})
    rest = [n for n in names if n not in pose]
    if rest:
        x = interpolate(ts, np.stack([values[n] for n in rest], axis=1), t)
        out.update({n: x[:, k] for k, n in enumerate(rest)})
    return {n: out[n] for n in names}
