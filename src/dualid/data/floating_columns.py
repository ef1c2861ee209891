"""Log columns of a floating base and of external wrenches (the ``base`` and ``wrenches`` sections of
a column map), and reading them into Pinocchio's free-flyer configuration and velocity.

YAML form (inside ``columns``)::

    base:
      position: [x, y, z]                  # [m] base-frame origin in the world frame
      quaternion: [qx, qy, qz, qw]         # world_R_base; listed in the order of quaternion_order
      quaternion_order: xyzw               # (default; Pinocchio, ROS, scipy) or wxyz (scalar first)
      # instead of position + quaternion: matrix: [16 columns], world_T_base row by row (4×4, last row 0 0 0 1)
      twist: [vx, vy, vz, wx, wy, wz]      # optional [m/s, rad/s]
      twist_frame: local                   # (default) base frame axes, Pinocchio's free flyer; or
                                           # local_world_aligned (world axes, at the base origin)
    wrenches:
      thrust: {frame: base_link, reference: local, force: [0, 0, fz], torque: [tx, ty, tz]}

A wrench acts on the named Pinocchio frame (a URDF link or joint); ``reference`` says where it is
expressed, as Pinocchio's ReferenceFrame: local (frame axes, at the frame origin), local_world_aligned
(world axes, at the frame origin) or world (world axes, about the world origin). Force [N], torque
[N m]; a 0 in place of a column name is a component known to be zero. Wrenches enter the inverse
dynamics as τ = rnea(q, v, a) − Σ_f J_f(q)ᵀ f (``dualid.model.external_wrench``). All in SI units.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np

from dualid.data.lie import gradient_on_group, unit_quaternions
from dualid.errors import DataError, DualidWarning

QUATERNION_ORDERS = ("xyzw", "wxyz")
TWIST_FRAMES = ("local", "local_world_aligned")
REFERENCES = ("local", "local_world_aligned", "world")
_BASE_KEYS = ("position", "quaternion", "quaternion_order", "matrix", "twist", "twist_frame")
_WRENCH_KEYS = ("frame", "reference", "force", "torque")
MATRIX_TOL = 1e-3  # a logged rotation whose RᵀR is off I by more than this is refused


def _names(x, count: int, where: str, zero_ok: bool = False) -> tuple:
    """``count`` column names (or 0 where allowed) from a list."""
    if not isinstance(x, (list, tuple)) or len(x) != count:
        raise DataError(f"column map: {where}: expected a list of {count} column names, got {x!r}")
    out = []
    for c in x:
        if zero_ok and isinstance(c, (int, float)) and not isinstance(c, bool) and c == 0:
            out.append(0)
        elif isinstance(c, str) and c:
            out.append(c)
        else:
            expected = "a column name or 0 (a component known to be zero)" if zero_ok else "a column name"
            raise DataError(f"column map: {where}: expected {expected} for each entry, got {c!r}")
    return tuple(out)


def _choice(x, choices: tuple[str, ...], where: str) -> str:
    if x not in choices:
        raise DataError(f"column map: {where}: expected one of {list(choices)}, got {x!r}")
    return str(x)


@dataclass(frozen=True)
class BaseColumns:
    """The pose (position + quaternion, or a 4×4 matrix) and optional twist columns of a floating base."""

    position: tuple[str, ...] = ()
    quaternion: tuple[str, ...] = ()  # in the order of quaternion_order
    quaternion_order: str = "xyzw"
    matrix: tuple[str, ...] = ()  # 16, row-major world_T_base
    twist: tuple[str, ...] = ()
    twist_frame: str = "local"

    @staticmethod
    def from_dict(d) -> "BaseColumns":
        if not isinstance(d, Mapping):
            raise DataError(f"column map: 'base' must be a mapping with keys {list(_BASE_KEYS)}, got {d!r}")
        bad = sorted(set(d) - set(_BASE_KEYS))
        if bad:
            raise DataError(f"column map: base has unknown keys {bad}; allowed: {list(_BASE_KEYS)}")
        has_matrix = d.get("matrix") is not None
        has_quat = d.get("quaternion") is not None or d.get("position") is not None
        if has_matrix == has_quat:
            raise DataError("column map: base needs either 'position' and 'quaternion' (7 columns) or 'matrix' "
                            f"(16 columns), not {'both' if has_matrix else 'neither'}")
        if has_quat:
            missing = [k for k in ("position", "quaternion") if d.get(k) is None]
            if missing:
                raise DataError(f"column map: base needs columns for {missing}")
        return BaseColumns(
            position=_names(d["position"], 3, "base.position") if has_quat else (),
            quaternion=_names(d["quaternion"], 4, "base.quaternion") if has_quat else (),
            quaternion_order=_choice(d.get("quaternion_order", "xyzw"), QUATERNION_ORDERS, "base.quaternion_order"),
            matrix=_names(d["matrix"], 16, "base.matrix") if has_matrix else (),
            twist=() if d.get("twist") is None else _names(d["twist"], 6, "base.twist"),
            twist_frame=_choice(d.get("twist_frame", "local"), TWIST_FRAMES, "base.twist_frame"),
        )

    def columns(self) -> list[str]:
        return list(self.position + self.quaternion + self.matrix + self.twist)

    def to_dict(self) -> dict:
        out: dict = {}
        if self.matrix:
            out["matrix"] = list(self.matrix)
        else:
            out.update(position=list(self.position), quaternion=list(self.quaternion),
                       quaternion_order=self.quaternion_order)
        if self.twist:
            out.update(twist=list(self.twist), twist_frame=self.twist_frame)
        return out


@dataclass(frozen=True)
class WrenchColumns:
    """One external wrench: its frame, the frame it is expressed in, force and torque columns (or 0)."""

    name: str
    frame: str
    force: tuple
    torque: tuple
    reference: str = "local"

    @staticmethod
    def from_dict(name, d) -> "WrenchColumns":
        where = f"wrenches.{name}"
        if not isinstance(d, Mapping):
            raise DataError(f"column map: {where} must be a mapping with keys {list(_WRENCH_KEYS)}, got {d!r}")
        bad = sorted(set(d) - set(_WRENCH_KEYS))
        if bad:
            raise DataError(f"column map: {where} has unknown keys {bad}; allowed: {list(_WRENCH_KEYS)}")
        missing = [k for k in ("frame", "force", "torque") if d.get(k) is None]
        if missing:
            raise DataError(f"column map: {where} needs {missing}")
        if not isinstance(d["frame"], str) or not d["frame"]:
            raise DataError(f"column map: {where}.frame: expected a frame name, got {d['frame']!r}")
        return WrenchColumns(str(name), d["frame"], _names(d["force"], 3, f"{where}.force", True),
                             _names(d["torque"], 3, f"{where}.torque", True),
                             _choice(d.get("reference", "local"), REFERENCES, f"{where}.reference"))

    def columns(self) -> list[str]:
        return [c for c in self.force + self.torque if c != 0]

    def to_dict(self) -> dict:
        return {"frame": self.frame, "reference": self.reference, "force": list(self.force), "torque": list(self.torque)}

    @property
    def spec(self) -> dict:
        """What the model needs to apply it: {name, frame, reference}."""
        return {"name": self.name, "frame": self.frame, "reference": self.reference}


def read_base(base: BaseColumns, column: Callable[[str], np.ndarray], where: str) -> tuple[np.ndarray, np.ndarray | None, dict]:
    """(q_base (T, 7) [x y z qx qy qz qw], v_base (T, 6) LOCAL or None, notes) from the logged columns."""
    from scipy.spatial.transform import Rotation  # here: scipy.spatial costs ~0.3 s to import

    if base.matrix:
        Tm = np.stack([column(c) for c in base.matrix], axis=1).reshape(-1, 4, 4)
        last = np.abs(Tm[:, 3] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=1)
        R = Tm[:, :3, :3]
        ortho = np.abs(np.einsum("tji,tjk->tik", R, R) - np.eye(3)).max(axis=(1, 2))
        for err, what in ((last, "its last row is not 0 0 0 1"), (ortho, "its rotation is not orthonormal (RᵀR ≠ I)")):
            bad = err > MATRIX_TOL
            if bad.any():
                k = int(np.argmax(bad))
                raise DataError(f"{where}: the base matrix columns at row {k}: {what} (off by {err[k]:.3g}, tolerance "
                                f"{MATRIX_TOL:g}); check that the 16 columns are world_T_base row by row")
        if np.any(np.linalg.det(R) < 0):
            k = int(np.argmax(np.linalg.det(R) < 0))
            raise DataError(f"{where}: the base matrix at row {k} is a reflection (det R < 0), not a rotation")
        p = Tm[:, :3, 3]
        quat = Rotation.from_matrix(R).as_quat()
        quat, flips = unit_quaternions(quat, where, base.matrix)
    else:
        p = np.stack([column(c) for c in base.position], axis=1)
        raw = np.stack([column(c) for c in base.quaternion], axis=1)
        if base.quaternion_order == "wxyz":
            raw = raw[:, [1, 2, 3, 0]]
        quat, flips = unit_quaternions(raw, where, base.quaternion)
    v = None
    if base.twist:
        v = np.stack([column(c) for c in base.twist], axis=1)
        if base.twist_frame == "local_world_aligned":
            Rt = Rotation.from_quat(quat).as_matrix().transpose(0, 2, 1)
            v = np.concatenate([np.einsum("tij,tj->ti", Rt, v[:, :3]), np.einsum("tij,tj->ti", Rt, v[:, 3:])], axis=1)
    notes = {"quaternion_sign_flips": flips}
    return np.concatenate([p, quat], axis=1), v, notes


def with_base(base: BaseColumns, column, where: str, t, q, v, tau, a, logged_v: bool):
    """q, v, tau of the joints with the free flyer's put first (Pinocchio's layout), and notes. The base has
    no actuator: its generalized force is 0 and forces on it come as external wrenches. Without a logged
    twist, the base velocity is a placeholder by differences on the group (``lie.gradient_on_group``)."""
    if a is not None:
        raise DataError(f"{where}: acceleration columns are not supported with a floating base (the base has none); "
                        "leave them out and differentiate")
    q_base, v_base, notes = read_base(base, column, where)
    if logged_v and base.twist and base.quaternion:
        check_quaternion_order(base, column, where, t, q_base, v_base)
    elif base.quaternion and not base.twist:  # the same text for every log: said once
        warnings.warn(f"the base quaternion columns {list(base.quaternion)} are read in {base.quaternion_order} order "
                      "(quaternion_order), which could not be checked: no base twist is logged, and a permuted "
                      "quaternion is a unit quaternion with the same angular speed; a wrong order tilts gravity in "
                      "the fit without an error", DualidWarning, stacklevel=3)
    T = t.size
    v_base = v_base if logged_v else gradient_on_group(t, q_base, 6)
    return (np.concatenate([q_base, q], axis=1), np.concatenate([v_base, v], axis=1),
            np.concatenate([np.zeros((T, 6)), tau], axis=1), notes)


QUATERNION_MISMATCH = 0.5  # relative RMS difference between the logged angular velocity and the quaternions


def check_quaternion_order(base: BaseColumns, column, where: str, t, q_base, v_base) -> None:
    """A permuted quaternion has unit norm too; the logged twist tells the orders apart. DataError when the
    logged angular velocity disagrees with the quaternions as mapped but agrees with the other order; a
    warning when it agrees with neither."""
    def mismatch(q) -> float:
        w = gradient_on_group(t, q, 6)[:, 3:]
        return float(np.sqrt(np.mean((w - v_base[:, 3:]) ** 2)) / max(np.sqrt(np.mean(v_base[:, 3:] ** 2)), 1e-12))

    err = mismatch(q_base)
    if err <= QUATERNION_MISMATCH:
        return
    other = "wxyz" if base.quaternion_order == "xyzw" else "xyzw"
    err_other = mismatch(read_base(dataclasses.replace(base, quaternion_order=other), column, where)[0])
    if err_other < QUATERNION_MISMATCH / 2:
        raise DataError(f"{where}: the logged base angular velocity matches the quaternion columns "
                        f"{list(base.quaternion)} read in {other} order ({err_other:.0%} RMS difference), not in "
                        f"{base.quaternion_order} order ({err:.0%}); set columns.base.quaternion_order: {other}")
    warnings.warn(f"{where}: the logged base angular velocity differs from that of the quaternion columns "
                  f"{list(base.quaternion)} by {err:.0%} RMS; check the quaternion columns, their order "
                  "(quaternion_order) and the twist's frame (twist_frame)", DualidWarning, stacklevel=3)


def read_wrenches(wrenches, column: Callable[[str], np.ndarray], T: int) -> np.ndarray:
    """(T, 6k) [force; torque] per wrench, zeros where the map says 0."""
    cols = [np.zeros(T) if c == 0 else column(c) for w in wrenches for c in w.force + w.torque]
    return np.stack(cols, axis=1)
