"""The description of a generic drag model (``model.kind: drag``), checked, as plain values.

YAML form (the ``drag`` key of a fit config's ``model`` section)::

    base: planar                  # root joint: fixed (default) or planar (x, y, heading in the plane z = 0)
    chain: [0.3, 0.3, 0.3]        # instead of a URDF: a planar serial chain of links of these lengths [m]
    bodies:                       # per body: drag in a named frame (a URDF link or joint, or a chain's link<i>)
      head: {frame: link1, diagonal: 3}                   # 3 coefficients (vx, vy, wz): planar
      mid:  {frame: link2, diagonal: [50, 80, 0.5]}       # with nominal values (a prior, or a simulation's truth)
      tail: {frame: link3, full: 6, rpy: [0, 0, 0.3]}     # a full PSD 6×6 matrix, frame rotated by rpy [rad]
    damping: [joint1, joint2]     # joint damping (or {joint1: 0.01, joint2: 0.02} with nominal values)

A body's drag acts on its frame's LOCAL velocity u_b = J_b(q) v: ``diagonal`` gives D_b = diag(θ_b)
over the components (vx, vy, wz) (3) or (vx, vy, vz, wx, wy, wz) (6); ``full`` gives a symmetric
D_b over the same components, parametrised by its upper triangle (row-major), physically consistent
when D_b ⪰ 0. ``xyz``/``rpy`` place the drag frame relative to the named frame (default: the frame).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from dualid.errors import ModelError

COMPONENTS = {3: ("vx", "vy", "wz"), 6: ("vx", "vy", "vz", "wx", "wy", "wz")}
MOTION_ROWS = {3: (0, 1, 5), 6: (0, 1, 2, 3, 4, 5)}  # rows of a 6-D [linear; angular] Pinocchio Jacobian
BASES = ("fixed", "planar")
_SPEC_KEYS = ("base", "chain", "bodies", "damping")
_BODY_KEYS = ("frame", "diagonal", "full", "xyz", "rpy")


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and bool(np.isfinite(x))


def _triple(x, where: str) -> tuple[float, float, float]:
    if x is None:
        return (0.0, 0.0, 0.0)
    if not isinstance(x, (list, tuple)) or len(x) != 3 or not all(_is_number(e) for e in x):
        raise ModelError(f"{where}: expected 3 finite numbers, got {x!r}")
    return tuple(float(e) for e in x)


def component_unit(component: str, other: str | None = None) -> str:
    """Unit of a drag coefficient between two velocity components (force or torque per velocity)."""
    angular = [c.startswith("w") for c in (component, other or component)]
    if all(angular):
        return "N m s/rad"
    return "N s" if any(angular) else "N s/m"


@dataclass(frozen=True)
class DragBody:
    """Drag of one body: D_b over ``size`` components of its frame's velocity (see the module docstring)."""

    name: str  # the body's label: the prefix of its parameter names
    frame: str  # a frame of the kinematic model
    form: str  # "diagonal" | "full"
    size: int  # 3 (vx, vy, wz) | 6 (vx, vy, vz, wx, wy, wz)
    nominal: tuple[tuple[float, ...], ...] | None = None  # (size, size) nominal D_b, or None
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)  # [m] drag frame in the named frame
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)  # [rad]

    @property
    def components(self) -> tuple[str, ...]:
        return COMPONENTS[self.size]

    @property
    def pairs(self) -> tuple[tuple[int, int], ...]:
        """(a, b) entries of D_b that are parameters, in θ order (diagonal, or upper triangle row-major)."""
        if self.form == "diagonal":
            return tuple((a, a) for a in range(self.size))
        rows, cols = np.triu_indices(self.size)
        return tuple((int(a), int(b)) for a, b in zip(rows, cols))

    @property
    def parameter_names(self) -> tuple[str, ...]:
        c = self.components
        return tuple(f"{self.name}.{c[a]}" if a == b else f"{self.name}.{c[a]}_{c[b]}" for a, b in self.pairs)

    @property
    def parameter_units(self) -> tuple[str, ...]:
        c = self.components
        return tuple(component_unit(c[a], c[b]) for a, b in self.pairs)

    def nominal_theta(self) -> np.ndarray | None:
        if self.nominal is None:
            return None
        D = np.asarray(self.nominal)
        return np.array([D[a, b] for a, b in self.pairs])


@dataclass(frozen=True)
class DragSpec:
    """A drag model's description: the kinematics (URDF or a planar chain), its bodies and damped joints."""

    bodies: tuple[DragBody, ...]
    damping: tuple[tuple[str, float | None], ...] = ()  # (joint, nominal damping or None)
    base: str = "fixed"
    chain: tuple[float, ...] | None = None  # link lengths [m] of a planar chain (None: from a URDF)

    @staticmethod
    def from_dict(d: Any, where: str = "model.drag") -> "DragSpec":
        if not isinstance(d, Mapping):
            raise ModelError(f"{where}: expected a mapping with keys {list(_SPEC_KEYS)}, got {d!r}")
        unknown = [k for k in d if k not in _SPEC_KEYS]
        if unknown:
            raise ModelError(f"{where}: unknown keys {unknown}; known keys: {list(_SPEC_KEYS)}")
        base = d.get("base", "fixed")
        if base not in BASES:
            raise ModelError(f"{where}.base: expected one of {list(BASES)}, got {base!r}")
        chain = d.get("chain")
        if chain is not None:
            if (not isinstance(chain, (list, tuple)) or not chain
                    or not all(_is_number(x) and x > 0 for x in chain)):
                raise ModelError(f"{where}.chain: expected a list of link lengths > 0 [m], got {chain!r}")
            chain = tuple(float(x) for x in chain)
        bodies_in = d.get("bodies")
        if not isinstance(bodies_in, Mapping) or not bodies_in:
            raise ModelError(f"{where}.bodies: expected a mapping {{body: {{frame, diagonal | full}}}} with at "
                             f"least one body, got {bodies_in!r}")
        bodies = tuple(_body(str(name), b, f"{where}.bodies.{name}") for name, b in bodies_in.items())
        return DragSpec(bodies, _damping(d.get("damping"), f"{where}.damping"), base, chain)

    def nominal_theta(self) -> np.ndarray | None:
        """θ₀ from the nominal values, or None when any body or joint has none."""
        parts = [b.nominal_theta() for b in self.bodies]
        if any(p is None for p in parts) or any(c is None for _, c in self.damping):
            return None
        return np.concatenate(parts + [np.array([c for _, c in self.damping], dtype=float)])

    def as_dict(self) -> dict:
        """The YAML form (inverse of from_dict)."""
        bodies = {}
        for b in self.bodies:
            value: Any = b.size
            if b.nominal is not None:
                value = [list(r) for r in b.nominal] if b.form == "full" else [b.nominal[a][a] for a in range(b.size)]
            entry = {"frame": b.frame, b.form: value}
            if any(b.xyz):
                entry["xyz"] = list(b.xyz)
            if any(b.rpy):
                entry["rpy"] = list(b.rpy)
            bodies[b.name] = entry
        damping: Any = [j for j, _ in self.damping]
        if self.damping and all(c is not None for _, c in self.damping):
            damping = {j: c for j, c in self.damping}
        out = {"base": self.base, "bodies": bodies, "damping": damping}
        if self.chain is not None:
            out["chain"] = list(self.chain)
        return out


def _body(name: str, b: Any, where: str) -> DragBody:
    if not isinstance(b, Mapping):
        raise ModelError(f"{where}: expected a mapping with keys {list(_BODY_KEYS)}, got {b!r}")
    unknown = [k for k in b if k not in _BODY_KEYS]
    if unknown:
        raise ModelError(f"{where}: unknown keys {unknown}; known keys: {list(_BODY_KEYS)}")
    frame = b.get("frame", name)
    if not isinstance(frame, str) or not frame:
        raise ModelError(f"{where}.frame: expected a frame name, got {frame!r}")
    forms = [f for f in ("diagonal", "full") if f in b]
    if len(forms) != 1:
        raise ModelError(f"{where}: give exactly one of 'diagonal' or 'full', got {forms or 'neither'}")
    form = forms[0]
    value = b[form]
    sizes = "3 (vx, vy, wz) or 6 (vx, vy, vz, wx, wy, wz)"
    nominal = None
    if isinstance(value, int) and not isinstance(value, bool):
        size = value
        if size not in COMPONENTS:
            raise ModelError(f"{where}.{form}: expected {sizes}, got {value!r}")
    elif form == "diagonal" and isinstance(value, (list, tuple)):
        if len(value) not in COMPONENTS:
            raise ModelError(f"{where}.diagonal: expected {sizes} coefficients, got {len(value)}: {list(value)!r}")
        if not all(_is_number(x) and x >= 0 for x in value):
            raise ModelError(f"{where}.diagonal: expected finite coefficients ≥ 0, got {list(value)!r}")
        size = len(value)
        nominal = tuple(tuple(float(value[a]) if a == c else 0.0 for c in range(size)) for a in range(size))
    elif form == "full" and isinstance(value, (list, tuple)):
        D = _matrix(value, f"{where}.full", sizes)
        size = D.shape[0]
        nominal = tuple(tuple(float(x) for x in row) for row in D)
    else:
        raise ModelError(f"{where}.{form}: expected {sizes}, or nominal values, got {value!r}")
    return DragBody(name, frame, form, size, nominal, _triple(b.get("xyz"), f"{where}.xyz"),
                    _triple(b.get("rpy"), f"{where}.rpy"))


def _matrix(value, where: str, sizes: str) -> np.ndarray:
    try:
        D = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ModelError(f"{where}: expected a square matrix of numbers, got {value!r}") from None
    if D.ndim != 2 or D.shape[0] != D.shape[1] or D.shape[0] not in COMPONENTS:
        raise ModelError(f"{where}: expected a {sizes} square matrix, got shape {D.shape}")
    if not np.all(np.isfinite(D)) or not np.allclose(D, D.T, rtol=0, atol=1e-12 * max(1.0, np.abs(D).max())):
        raise ModelError(f"{where}: expected a finite symmetric matrix, got {value!r}")
    lam = float(np.linalg.eigvalsh(D)[0])
    if lam < -1e-12 * max(1.0, np.abs(D).max()):
        raise ModelError(f"{where}: a drag matrix must be positive semidefinite; smallest eigenvalue {lam:.3g}")
    return D


def _damping(d: Any, where: str) -> tuple[tuple[str, float | None], ...]:
    if d is None:
        return ()
    if isinstance(d, str):
        d = [d]
    if isinstance(d, (list, tuple)):
        if not all(isinstance(j, str) and j for j in d):
            raise ModelError(f"{where}: expected joint names, got {d!r}")
        items = [(j, None) for j in d]
    elif isinstance(d, Mapping):
        items = []
        for j, c in d.items():
            if c is not None and not (_is_number(c) and c >= 0):
                raise ModelError(f"{where}.{j}: expected a damping ≥ 0 [N m s/rad] or null, got {c!r}")
            items.append((str(j), None if c is None else float(c)))
    else:
        raise ModelError(f"{where}: expected a list of joint names or {{joint: nominal damping}}, got {d!r}")
    names = [j for j, _ in items]
    dup = sorted({j for j in names if names.count(j) > 1})
    if dup:
        raise ModelError(f"{where}: joints named more than once: {dup}")
    return tuple(items)
