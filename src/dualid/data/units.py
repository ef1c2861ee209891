"""Units of logged quantities and their factors to SI, and a joint effort given as a motor current."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from dualid.errors import DataError

# unit -> factor to SI, per quantity
UNITS: dict[str, dict[str, float]] = {
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6},
    "position": {"rad": 1.0, "deg": np.pi / 180, "m": 1.0, "mm": 1e-3},  # m, mm: prismatic joints
    "velocity": {"rad/s": 1.0, "deg/s": np.pi / 180, "m/s": 1.0, "mm/s": 1e-3},
    "acceleration": {"rad/s^2": 1.0, "deg/s^2": np.pi / 180, "m/s^2": 1.0, "mm/s^2": 1e-3},
    "effort": {"N m": 1.0, "N mm": 1e-3, "N": 1.0},  # N: prismatic joints
}
SI_UNITS = {q: next(iter(u)) for q, u in UNITS.items()}  # the first unit of each quantity is SI
LINEAR_UNITS = frozenset({"m", "mm", "m/s", "mm/s", "m/s^2", "mm/s^2", "N"})  # of prismatic joints


def normalize_unit(unit) -> str:
    """The spelling used in UNITS: "Nm", "N·m", "N*m", "N.m" → "N m"; "Nmm" → "N mm"; "s²" → "s^2"; "µs" → "us"."""
    u = " ".join(str(unit).split()).replace("²", "^2").replace("µ", "u").replace("μ", "u")
    for sep in ("·", "*", "."):
        u = u.replace(f"N{sep}m", "N m")
    if u in ("Nm", "Nmm"):
        u = "N " + u[1:]
    return u


_MOTOR_KEYS = {"current": None, "torque_constant": None, "gear_ratio": 1.0, "efficiency": 1.0}


def motor_factors(joint, spec: Mapping) -> tuple[tuple[str, float], ...]:
    """(torque_constant, gear_ratio, efficiency) of an effort given as {current: COLUMN, torque_constant: kt
    [N m/A], gear_ratio: N (default 1), efficiency: η in (0, 1] (default 1)}: τ = I·kt·N·η at the joint."""
    where = f"column map: joint {joint!r} effort"
    bad = sorted(set(spec) - set(_MOTOR_KEYS))
    if bad:
        raise DataError(f"{where}: unknown keys {bad}; allowed: {list(_MOTOR_KEYS)}")
    missing = [k for k in ("current", "torque_constant") if spec.get(k) is None]
    if missing:
        raise DataError(f"{where}: a motor current needs {missing}")
    out = []
    for key in ("torque_constant", "gear_ratio", "efficiency"):
        x = spec.get(key, _MOTOR_KEYS[key])
        ok = isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) and x > 0
        if not ok or (key == "efficiency" and x > 1):
            expected = "a number in (0, 1]" if key == "efficiency" else "a finite number > 0"
            raise DataError(f"{where}.{key}: expected {expected}, got {x!r}")
        out.append((key, float(x)))
    return tuple(out)
