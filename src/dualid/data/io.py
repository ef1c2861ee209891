"""Loading robot logs (CSV, Parquet, NPZ, ROS bags) into Trajectories through an explicit column map.

A ``ColumnMap`` says which column holds time and, per joint, position, velocity, acceleration and
effort, and in which units; ``load_log`` checks the file against it and converts to SI
(s, rad, rad/s, rad/s², N m).

Velocity rule. ``Trajectory`` needs v. If the map names a velocity column for every joint, v is the
logged one. If it names none, ``load_log`` raises unless called with ``velocity="gradient"``: then v
is a placeholder by central differences on the raw time stamps (``np.gradient(q, t)``, valid for
irregular stamps), meta["logged"] omits "v" and ``preprocessing.differentiate`` (default
velocity=None) replaces it by its own derivative. Accelerations are kept only if logged
(else a=None; ``differentiate`` computes them).

A ROS bag's map names topics (``columns.topics``, ``dualid.data.bag_topics``); ``dualid.data.bags`` reads
them into channels on one time base, and from there a bag is read exactly as a table is.

Rows are counted from 0 (the first data row, after any header) in error messages.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from dualid.data.bag_topics import TopicMap
from dualid.data.bags import is_bag, read_bag
from dualid.data.checks import check_magnitude, check_time, check_velocity
from dualid.data.floating_columns import BaseColumns, WrenchColumns, read_wrenches, with_base
from dualid.data.lie import BASE_COORDINATES
from dualid.data.tables import FORMATS, read_table
from dualid.data.trajectory import Trajectory
from dualid.data.units import LINEAR_UNITS, SI_UNITS, UNITS, motor_factors, normalize_unit  # noqa: F401 (re-exported)
from dualid.errors import DataError, MissingFileError

_JOINT_KEYS = ("position", "velocity", "acceleration", "effort")


@dataclass(frozen=True)
class JointColumns:
    """The columns of one joint; velocity and acceleration are optional."""

    name: str
    position: str
    effort: str | None  # the effort column, the motor-current column when ``motor`` is given, None: passive (τ = 0)
    velocity: str | None = None
    acceleration: str | None = None
    motor: tuple[tuple[str, float], ...] = ()  # (torque_constant [N m/A], gear_ratio, efficiency): τ = I·kt·N·η

    @property
    def effort_scale(self) -> float | None:
        """kt·N·η [N m/A] for a motor current, None for an effort column."""
        return float(np.prod([v for _, v in self.motor])) if self.motor else None


@dataclass(frozen=True)
class ColumnMap:
    """Which columns hold what, and in which units (converted to SI on load)."""

    time: str
    joints: tuple[JointColumns, ...]
    units: tuple[tuple[str, str], ...] = ()  # (quantity, unit) pairs; missing quantities are SI
    joint_units: tuple[tuple[str, str, str], ...] = ()  # (joint, quantity, unit): overrides ``units`` per joint
    base: BaseColumns | None = None  # a floating base's pose (and twist) columns (dualid.data.floating_columns)
    wrenches: tuple[WrenchColumns, ...] = ()  # external wrenches on named frames
    topics: TopicMap | None = None  # a ROS bag's topics (dualid.data.bag_topics): the columns are its channels
    # (joint or "", quantity) of each unit the map was given (the others are SI by default): set by __post_init__
    stated: tuple[tuple[str, str], ...] = field(default=(), compare=False, repr=False)

    def __post_init__(self) -> None:
        joints = tuple(self.joints)
        if not joints and self.base is None:
            raise DataError("column map: no joints given")
        names = [j.name for j in joints]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise DataError(f"column map: joints named more than once: {dup}")
        units = dict(self.units.items() if isinstance(self.units, Mapping) else self.units)
        per_joint = list(self.joint_units)
        for quantity, unit in list(units.items()):
            if quantity not in UNITS:
                raise DataError(f"column map: unknown quantity {quantity!r} in units; allowed: {list(UNITS)}")
            if isinstance(unit, Mapping):  # {Joint1: deg, Joint2: mm}: per joint
                unknown = [j for j in unit if j not in names]
                if unknown:
                    raise DataError(f"column map: units.{quantity} names joints {unknown} that are not mapped; joints: {names}")
                per_joint += [(str(j), quantity, u) for j, u in unit.items()]
                del units[quantity]
        object.__setattr__(self, "stated", tuple(sorted({("", q) for q in units} | {(j, q) for j, q, _ in per_joint})))
        checked = []
        for where, quantity, unit in [(f"units.{q}", q, u) for q, u in units.items()] + \
                [(f"units.{q}.{j}", q, u) for j, q, u in per_joint]:
            u = normalize_unit(unit)
            if u not in UNITS[quantity]:
                raise DataError(f"column map: {where}: unknown {quantity} unit {unit!r}; allowed: {list(UNITS[quantity])}")
            checked.append(u)
        units = {q: checked[k] for k, q in enumerate(units)}
        per_joint = tuple((j, q, checked[len(units) + k]) for k, (j, q, _) in enumerate(per_joint))
        full = {q: units.get(q, SI_UNITS[q]) for q in UNITS}
        per_joint = tuple(sorted({(j, q, u) for j, q, u in per_joint if u != full[q]}))  # one canonical form
        object.__setattr__(self, "joints", joints)
        object.__setattr__(self, "units", tuple(full.items()))
        object.__setattr__(self, "joint_units", per_joint)

    # -- constructors ------------------------------------------------------------------------------
    @staticmethod
    def from_dict(d: Mapping, joints: Sequence[str] | None = None) -> "ColumnMap":
        """From the YAML form {time: "time", joints: {Joint1: {position: pos_meas1, velocity: vel_meas1,
        effort: tau_meas1}, ...}, units: {position: rad}}, or a bag's {topics: {...}, units: {...}} for the
        model's ``joints`` (names; the floating base's coordinates left out)."""
        if not isinstance(d, Mapping):
            raise DataError(f"column map must be a mapping with keys time, joints, units; got {type(d).__name__}")
        if "topics" in d:
            if set(d) - {"topics", "units"}:
                raise DataError(f"column map: the topics form takes 'topics' and 'units' only, got {sorted(d)}")
            topics = TopicMap.from_dict(d["topics"])
            if joints is None and topics.joint_states is not None:
                raise DataError("column map: topics: the joints to read are the model's; pass them (load_log(..., joints=…))")
            names = tuple(joints or ())
            cmap = ColumnMap.from_dict({**topics.columns(names), "units": d.get("units") or {}})
            return cmap.with_fields(topics=topics)
        allowed = ["time", "joints", "units", "base", "wrenches", "topics"]
        unknown = sorted(set(d) - set(allowed))
        if unknown:
            raise DataError(f"column map: unknown keys {unknown}; allowed: {allowed}")
        base = None if d.get("base") is None else BaseColumns.from_dict(d["base"])
        wrenches = d.get("wrenches") or {}
        if not isinstance(wrenches, Mapping):
            raise DataError(f"column map: 'wrenches' must map names to {{frame, reference, force, torque}}, got {wrenches!r}")
        if base is not None and d.get("joints") is None:
            d = {**d, "joints": {}}
        if "joints" not in d or not isinstance(d["joints"], Mapping):
            raise DataError("column map: 'joints' must map each joint name to {position, velocity, acceleration, effort}")
        joints = []
        for name, cols in d["joints"].items():
            if not isinstance(cols, Mapping):
                raise DataError(f"column map: joint {name!r} must map to a mapping of columns, got {cols!r}")
            bad = sorted(set(cols) - set(_JOINT_KEYS))
            if bad:
                raise DataError(f"column map: joint {name!r} has unknown keys {bad}; allowed: {list(_JOINT_KEYS)}")
            missing = [k for k in ("position", "effort") if cols.get(k) is None or cols.get(k) == ""]
            if missing:
                raise DataError(f"column map: joint {name!r} needs columns for {missing}")
            cols = dict(cols)
            if not isinstance(cols["effort"], (str, Mapping)):  # a number: 0 marks a passive (unactuated) joint
                if isinstance(cols["effort"], bool) or cols["effort"] != 0:
                    raise DataError(f"column map: joint {name!r} effort: expected a column name, a motor current or 0 "
                                    f"(a passive joint), got {cols['effort']!r}")
                cols["effort"] = None
            motor = motor_factors(name, cols["effort"]) if isinstance(cols["effort"], Mapping) else ()
            if motor:
                cols["effort"] = cols["effort"]["current"]
            joints.append(JointColumns(str(name), **{k: (None if v is None else str(v)) for k, v in cols.items()},
                                       motor=motor))
        units = d.get("units") or {}
        if not isinstance(units, Mapping):
            raise DataError(f"column map: 'units' must be a mapping quantity -> unit, got {units!r}")
        return ColumnMap(time=str(d.get("time", "time")), joints=tuple(joints), units=tuple(units.items()), base=base,
                         wrenches=tuple(WrenchColumns.from_dict(k, w) for k, w in wrenches.items()))

    @staticmethod
    def pattern(
        joints: Sequence[str],
        position: str = "pos_meas{i}",
        velocity: str | None = "vel_meas{i}",
        effort: str = "tau_meas{i}",
        acceleration: str | None = None,
        time: str = "time",
        units: Mapping[str, str] | None = None,
    ) -> "ColumnMap":
        """Columns named by patterns: {i} = 1-based joint index, {k} = 0-based (e.g. "q[{k}]" for a (T, n)
        array q), {name} = joint name (defaults follow the
        DFKI double-pendulum logs). Pass velocity=None when no velocity is logged."""

        def fmt(pat, i, name):
            return None if pat is None else pat.format(i=i, k=i - 1, name=name)

        cols = tuple(
            JointColumns(
                name,
                position=fmt(position, i, name),
                effort=fmt(effort, i, name),
                velocity=fmt(velocity, i, name),
                acceleration=fmt(acceleration, i, name),
            )
            for i, name in enumerate(joints, start=1)
        )
        return ColumnMap(time=time, joints=cols, units=tuple((units or {}).items()))

    def with_fields(self, **changes) -> "ColumnMap":
        """A copy with some fields replaced, its derived fields (``stated``, the canonical units) kept as they are
        (dataclasses.replace would run __post_init__ again on the canonical units)."""
        out = copy.copy(self)
        for key, value in changes.items():
            object.__setattr__(out, key, value)
        return out

    # -- queries -----------------------------------------------------------------------------------
    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    def unit(self, quantity: str, joint: str | None = None) -> str:
        """The unit of ``quantity`` (of ``joint``, when it has its own)."""
        for j, q, u in self.joint_units:
            if j == joint and q == quantity:
                return u
        return dict(self.units)[quantity]

    def columns(self) -> list[str]:
        """Every column the map reads (time first)."""
        out = [self.time] + ([] if self.base is None else self.base.columns())
        for j in self.joints:
            out += [c for c in (j.position, j.velocity, j.acceleration, j.effort) if c is not None]
        return out + [c for w in self.wrenches for c in w.columns()]

    def to_dict(self) -> dict:
        """The YAML form (inverse of from_dict)."""
        joints = {
            j.name: {k: getattr(j, k) for k in _JOINT_KEYS if getattr(j, k) is not None} for j in self.joints
        }
        for j in self.joints:
            if j.effort is None:
                joints[j.name]["effort"] = 0
        for j in self.joints:
            if j.motor:
                joints[j.name]["effort"] = {"current": j.effort, **dict(j.motor)}
        units: dict = dict(self.units)
        for j, q, u in self.joint_units:
            if not isinstance(units[q], dict):
                units[q] = {n: units[q] for n in self.joint_names}
            units[q][j] = u
        out = {"time": self.time, "joints": joints, "units": units}
        if self.topics is not None:
            return {"topics": self.topics.to_dict(), "units": units}
        if self.base is not None:
            out["base"] = self.base.to_dict()
        if self.wrenches:
            out["wrenches"] = {w.name: w.to_dict() for w in self.wrenches}
        return out


def load_log(
    path,
    columns: ColumnMap | Mapping,
    joints: Sequence[str] | None = None,
    velocity: str = "logged",
    name: str | None = None,
) -> Trajectory:
    """One log file as a Trajectory in SI units.

    path: .csv or .parquet (pyarrow) or .npz (numpy). NPZ arrays may be 1-D channels
    or 2-D (T, n) arrays, Parquet columns may hold one list per row: column k of an array "q" is the
    channel "q[k]" (0-based) in the column map.
    columns: a ColumnMap or its dict form. joints: the model's joint names; the trajectory's
    coordinates follow this order and every model joint must be mapped (default: the map's order).
    velocity: "logged" (the map must name velocity columns) or "gradient" (see the module docstring).
    """
    path = Path(path)
    cmap = columns if isinstance(columns, ColumnMap) else ColumnMap.from_dict(
        columns, None if joints is None else [j for j in joints if j not in BASE_COORDINATES])
    if velocity not in ("logged", "gradient"):
        raise DataError(f"load_log: velocity must be 'logged' or 'gradient', got {velocity!r}")
    if joints is None:
        joints = cmap.joint_names
    else:
        joints = tuple(joints)
        if cmap.base is not None:  # the free flyer's coordinates come from the base columns
            joints = tuple(j for j in joints if j not in BASE_COORDINATES)
        extra = [j for j in cmap.joint_names if j not in joints]
        if extra:
            raise DataError(f"column map names joints {extra} that are not in the model; model joints: {list(joints)}")
        unmapped = [j for j in joints if j not in cmap.joint_names]
        if unmapped:
            raise DataError(f"column map has no columns for model joints {unmapped}; mapped: {list(cmap.joint_names)}")
    by_name = {j.name: j for j in cmap.joints}
    jcols = [by_name[j] for j in joints]
    has_v = [j.velocity is not None for j in jcols]
    if cmap.base is not None:
        has_v.append(bool(cmap.base.twist))
    if any(has_v) and not all(has_v):
        raise DataError(
            f"column map names velocity columns for some joints only (missing for "
            f"{[j.name for j in jcols if j.velocity is None] + (['base twist'] if cmap.base and not has_v[-1] else [])}); "
            "map all or none"
        )
    if not any(has_v) and velocity == "logged":
        raise DataError(
            "column map has no velocity columns: map a velocity column for each joint, or load with "
            "velocity='gradient' and then call preprocessing.differentiate to compute v from q"
        )
    has_a = [j.acceleration is not None for j in jcols]
    if any(has_a) and not all(has_a):
        raise DataError(
            f"column map names acceleration columns for some joints only (missing for "
            f"{[j.name for j in jcols if j.acceleration is None]}); map all or none"
        )

    if not path.exists():
        raise MissingFileError(f"log file not found: {path}")
    if is_bag(path) != (cmap.topics is not None):
        raise DataError(f"{path}: a ROS bag needs its topics named in the column map (columns.topics)" if is_bag(path)
                        else f"{path}: columns.topics names ROS bag topics, but this is not a bag (.bag, .mcap, .db3, "
                        "or a rosbag2 folder)")
    if cmap.topics is not None:
        data, available, frames = read_bag(path, cmap.topics, [cmap.topics.message_name(j.name) for j in jcols])
        cmap = cmap.with_fields(wrenches=tuple(WrenchColumns(w.name, frames[w.name], w.force, w.torque, w.reference)
                                               for w in cmap.wrenches))
    elif path.suffix.lower() not in FORMATS:
        raise DataError(f"{path}: unknown log format {path.suffix!r}; expected one of {', '.join(FORMATS)}, or a ROS bag")
    else:
        data, available = read_table(path)
    needed = [cmap.time]
    if cmap.base is not None:
        needed += [c for c in cmap.base.columns() if velocity == "logged" or c not in cmap.base.twist]
    for j in jcols:
        needed += [c for c in (j.position, j.velocity if velocity == "logged" else None, j.acceleration, j.effort) if c]
    needed += [c for w in cmap.wrenches for c in w.columns()]
    missing = [c for c in dict.fromkeys(needed) if c not in data]
    if missing:
        raise DataError(f"{path}: missing columns {missing}; available columns: {available}")
    T = len(data[cmap.time])
    if T == 0:
        raise DataError(f"{path}: log is empty (no rows)")
    if T < 2:
        raise DataError(f"{path}: log has {T} row; need at least 2")

    def column(c: str) -> np.ndarray:
        try:
            x = np.asarray(data[c], dtype=float)
        except (TypeError, ValueError):
            raise DataError(f"{path}: column {c!r} is not numeric (dtype {data[c].dtype})") from None
        bad = ~np.isfinite(x)
        if bad.any():
            raise DataError(f"{path}: column {c!r} has non-finite values (NaN or inf), first at row {int(np.argmax(bad))}")
        return x

    for c in dict.fromkeys(needed):
        column(c)  # check every mapped column before converting
    t = column(cmap.time) * UNITS["time"][cmap.unit("time")]
    check_time(path, data[cmap.time], t, cmap.time)

    def stack(key: str, quantity: str):
        cols = []
        for j in jcols:
            if key == "effort" and j.effort is None:  # a passive joint
                cols.append(np.zeros(T))
                continue
            scale = j.effort_scale if key == "effort" and j.motor else UNITS[quantity][cmap.unit(quantity, j.name)]
            x = column(getattr(j, key)) * scale
            check_magnitude(path, getattr(j, key), x)
            cols.append(x)
        return np.stack(cols, axis=1) if cols else np.zeros((T, 0))

    q = stack("position", "position")
    tau = stack("effort", "effort")
    a = stack("acceleration", "acceleration") if has_a and all(has_a) else None
    if velocity == "logged":
        v = stack("velocity", "velocity")
        check_velocity(path, t, q, v, joints)
    else:
        v = np.gradient(q, t, axis=0, edge_order=2)
    extra: dict = {}
    if cmap.base is not None:  # free flyer first, Pinocchio's layout (dualid.data.lie)
        q, v, tau, extra["base"] = with_base(cmap.base, column, str(path), t, q, v, tau, a, velocity == "logged")
        joints = BASE_COORDINATES + tuple(joints)
    wrench = read_wrenches(cmap.wrenches, column, T) if cmap.wrenches else None
    if cmap.wrenches:
        extra["wrenches"] = [w.spec for w in cmap.wrenches]
    logged = ["q", "tau"] + (["v"] if velocity == "logged" else []) + (["a"] if a is not None else [])
    meta = {
        "source": str(path),
        "columns": cmap.to_dict(),
        "units": cmap.to_dict()["units"],
        "logged": logged,
    }
    meta.update(extra)
    if velocity == "gradient":
        meta["steps"] = [{"load_velocity": {"method": "gradient"}}]
    return Trajectory(t=t, q=q, v=v, tau=tau, a=a, coordinates=tuple(joints), name=name or path.stem, meta=meta,
                      wrench=wrench)


def load_logs(
    paths: Iterable, columns: ColumnMap | Mapping, joints: Sequence[str] | None = None, velocity: str = "logged"
) -> list[Trajectory]:
    """load_log for each path, in order."""
    return [load_log(p, columns, joints, velocity=velocity) for p in paths]
