"""Checks and defaults for the inputs of a real-robot fit: the column map of a log of (T, n) arrays,
units against the joint types, and training/held-out logs that are the same data."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from dualid.data.io import LINEAR_UNITS, SI_UNITS, UNITS, ColumnMap
from dualid.data.tables import read_table
from dualid.errors import DataError, DualidError, DualidWarning
from dualid.model.rigid_body import RigidBodyModel


def array_column_map(joints: tuple[str, ...], available: list[str]) -> ColumnMap | None:
    """The map of a log of (T, n) arrays: time 't' or 'time', 'q', 'tau' and optionally 'v' (or 'dq', 'qd'),
    one column per model joint in the model's order; None when the log is not of that form."""
    time = next((t for t in ("time", "t") if t in available), None)
    n = len(joints)
    has = lambda name: all(f"{name}[{k}]" in available for k in range(n)) and f"{name}[{n}]" not in available
    if time is None or not (has("q") and has("tau")):
        return None
    velocity = next((f"{v}[{{k}}]" for v in ("v", "dq", "qd") if has(v)), None)
    return ColumnMap.pattern(joints, position="q[{k}]", velocity=velocity, effort="tau[{k}]", time=time)


def check_units(rigid: RigidBodyModel, cmap: ColumnMap) -> None:
    """DataError when a joint's unit does not fit its type: a linear unit (m, mm, N, …) on a revolute
    joint, or an angular one (rad, deg, N m, …) on a prismatic joint (one not given is SI, which fits both)."""
    for name in cmap.joint_names:
        if not rigid.model.existJointName(name):
            continue
        prismatic = rigid.model.joints[rigid.model.getJointId(name)].shortname().startswith("JointModelP")
        for quantity in ("position", "velocity", "acceleration", "effort"):
            unit = cmap.unit(quantity, name)
            linear = unit in LINEAR_UNITS
            if linear and not prismatic:
                raise DataError(f"column map: joint {name!r} is revolute but its {quantity} unit is {unit!r} (linear)")
            stated = (name, quantity) in cmap.stated or ("", quantity) in cmap.stated  # not SI by default
            if prismatic and not linear and (unit != SI_UNITS[quantity] or stated):
                linear_units = [u for u in UNITS[quantity] if u in LINEAR_UNITS]
                raise DataError(f"column map: joint {name!r} is prismatic but its {quantity} unit is {unit!r} (angular); "
                                f"expected one of {linear_units}")


def check_floating(floating_base: bool, cmap: ColumnMap) -> None:
    """DataError when model.floating_base and the column map's 'base' section disagree."""
    if floating_base and cmap.base is None:
        raise DataError("model.floating_base is true but the column map has no 'base' section: map the base pose "
                        "(columns.base: {position: [x, y, z], quaternion: [qx, qy, qz, qw]} or {matrix: [16 columns]})")
    if cmap.base is not None and not floating_base:
        raise DataError("the column map has a 'base' section but model.floating_base is false; set "
                        "model.floating_base: true (a free-flyer root joint)")


def check_runs_differ(train, test) -> None:
    """DualidWarning when a log is used twice in training, or a held-out log is also a training log
    (same file, or a file with the same bytes): the held-out scores would not be held out."""
    import hashlib

    def key(p: Path) -> str:
        p = Path(p)
        return hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else str(p.resolve())

    seen: dict[str, Path] = {}
    for p in train:
        k = key(p)
        if k in seen:
            warnings.warn(f"training logs {seen[k]} and {p} are the same data; it is counted twice", DualidWarning,
                          stacklevel=3)
        seen.setdefault(k, p)
    train_rows: dict[Path, set[bytes]] | None = None
    for p in test:
        k = key(p)
        if k in seen:
            warnings.warn(f"held-out log {p} is the same data as training log {seen[k]}; its scores are not "
                          "held-out scores", DualidWarning, stacklevel=3)
            continue
        test_rows = _rows(p)
        if train_rows is None:  # each training log is read once, not once per held-out log
            train_rows = {q: _rows(q) for q in dict.fromkeys(seen.values())}
        for q, rows in train_rows.items():
            shared = len(test_rows & rows) / max(len(test_rows), 1)
            if shared >= OVERLAP:
                warnings.warn(f"held-out log {p} shares {shared:.0%} of its rows with training log {q}; its scores are "
                              "not fully held-out scores", DualidWarning, stacklevel=3)


OVERLAP = 0.1  # warn when this fraction of a held-out log's rows also appear in a training log


def _rows(path) -> set[bytes]:
    """The numeric rows of a log file (every column, as logged), for overlap tests; empty if unreadable."""
    try:
        data, columns = read_table(Path(path))
        cols = [np.asarray(data[c], dtype=float) for c in columns]
    except (DualidError, OSError, ValueError, TypeError):
        return set()  # loading reports the problem with its own message
    table = np.ascontiguousarray(np.column_stack(cols))
    return {row.tobytes() for row in table}


# --- model ------------------------------------------------------------------------------------
