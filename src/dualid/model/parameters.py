"""Parameter vectors θ: names, units and the blocks that carry physical-consistency constraints.

Every block maps its slice θ_b affinely to a symmetric matrix C_b(θ_b) = Σ_k θ_bk V_k that must be
positive semidefinite for the parameters to be physically consistent:

- ``rigid_body``: the 10 inertial parameters in Pinocchio's order
  [m, mc_x, mc_y, mc_z, Ixx, Ixy, Iyy, Ixz, Iyz, Izz] (inertia about the body frame origin);
  C_b is the 4×4 pseudo-inertia [[½tr(I)·1 − I, h], [hᵀ, m]] (Wensing et al. 2018).
- ``drag_diagonal``: d non-negative drag coefficients; C_b = diag(θ_b).
- ``drag_matrix``: the upper triangle (row-major) of a symmetric d×d drag matrix; C_b = D(θ_b).
- ``nonnegative``: scalar parameters that must be ≥ 0 (viscous friction, armature); C_b = diag(θ_b).
- ``free``: no constraint (e.g. an offset).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from dualid.errors import ModelError

BlockKind = Literal["rigid_body", "drag_diagonal", "drag_matrix", "nonnegative", "free"]
BLOCK_KINDS: tuple[str, ...] = ("rigid_body", "drag_diagonal", "drag_matrix", "nonnegative", "free")

RIGID_BODY_NAMES = ("m", "mc_x", "mc_y", "mc_z", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
RIGID_BODY_UNITS = ("kg", "kg m", "kg m", "kg m", "kg m^2", "kg m^2", "kg m^2", "kg m^2", "kg m^2", "kg m^2")


def pseudo_inertia_basis() -> np.ndarray:
    """V_k (10, 4, 4) with P(θ) = Σ θ_k V_k, θ in Pinocchio's dynamic-parameter order."""
    V = np.zeros((10, 4, 4))
    V[0, 3, 3] = 1.0  # m
    for k, axis in ((1, 0), (2, 1), (3, 2)):  # h = m c
        V[k, axis, 3] = V[k, 3, axis] = 1.0
    # Σ = ½tr(I)·1 − I for I = [[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]]
    inertia_entries = {4: (0, 0), 5: (0, 1), 6: (1, 1), 7: (0, 2), 8: (1, 2), 9: (2, 2)}
    for k, (a, b) in inertia_entries.items():
        E = np.zeros((3, 3))
        E[a, b] = E[b, a] = 1.0
        V[k, :3, :3] = 0.5 * np.trace(E) * np.eye(3) - E
    return V


def symmetric_basis(d: int) -> np.ndarray:
    """(d(d+1)/2, d, d) basis of symmetric matrices, upper triangle in row-major order."""
    rows, cols = np.triu_indices(d)
    V = np.zeros((len(rows), d, d))
    for k, (a, b) in enumerate(zip(rows, cols)):
        V[k, a, b] = V[k, b, a] = 1.0
    return V


def diagonal_basis(d: int) -> np.ndarray:
    V = np.zeros((d, d, d))
    V[np.arange(d), np.arange(d), np.arange(d)] = 1.0
    return V


@dataclass(frozen=True)
class ParameterBlock:
    """A contiguous group of parameters with one physical-consistency constraint."""

    name: str  # e.g. the body name
    kind: str  # one of BLOCK_KINDS
    indices: tuple[int, ...]  # positions in θ

    def __post_init__(self) -> None:
        if self.kind not in BLOCK_KINDS:
            raise ModelError(f"block {self.name!r}: kind must be one of {BLOCK_KINDS}, got {self.kind!r}")
        k = len(self.indices)
        if self.kind == "rigid_body" and k != 10:
            raise ModelError(f"block {self.name!r}: a rigid_body block has 10 parameters, got {k}")
        if self.kind == "drag_matrix":
            d = int(round((np.sqrt(8 * k + 1) - 1) / 2))
            if d * (d + 1) // 2 != k:
                raise ModelError(
                    f"block {self.name!r}: a drag_matrix block needs d(d+1)/2 parameters, got {k}"
                )

    @property
    def constraint_basis(self) -> np.ndarray | None:
        """V (k, m, m) with C_b(θ_b) = Σ_k θ_bk V_k ⪰ 0, or None for a free block."""
        k = len(self.indices)
        if self.kind == "rigid_body":
            return pseudo_inertia_basis()
        if self.kind in ("drag_diagonal", "nonnegative"):
            return diagonal_basis(k)
        if self.kind == "drag_matrix":
            return symmetric_basis(int(round((np.sqrt(8 * k + 1) - 1) / 2)))
        return None

    def constraint_matrix(self, theta: np.ndarray) -> np.ndarray | None:
        """C_b(θ_b) (m, m) evaluated at the full parameter vector θ (p,)."""
        V = self.constraint_basis
        if V is None:
            return None
        return np.tensordot(np.asarray(theta)[list(self.indices)], V, axes=1)


@dataclass(frozen=True)
class ParameterSpace:
    """Names, units and constraint blocks of θ ∈ R^p, plus optional per-parameter bounds."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    blocks: tuple[ParameterBlock, ...] = ()
    lower: tuple[float, ...] | None = None  # per-parameter lower bounds (−inf for none)
    upper: tuple[float, ...] | None = None
    # the margin C_b(θ) ⪰ ε·C_b(θ_ref) on every constrained block (None: off); see ``with_margin``
    margin_reference: tuple[float, ...] | None = None  # θ_ref (p,)
    margin_epsilon: float = 0.0  # ε ∈ [0, 1)
    margin_label: str = ""  # where θ_ref came from ("prior", "wls pilot", …), for reports
    _index: dict = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        p = len(self.names)
        if len(self.units) != p:
            raise ModelError(f"ParameterSpace: {p} names but {len(self.units)} units")
        if len(set(self.names)) != p:
            dup = sorted({n for n in self.names if self.names.count(n) > 1})
            raise ModelError(f"ParameterSpace: duplicate parameter names {dup}")
        seen: set[int] = set()
        for b in self.blocks:
            bad = [i for i in b.indices if not 0 <= i < p]
            if bad:
                raise ModelError(f"block {b.name!r}: indices {bad} outside 0..{p - 1}")
            overlap = seen.intersection(b.indices)
            if overlap:
                raise ModelError(f"block {b.name!r}: parameters {sorted(overlap)} already in another block")
            seen.update(b.indices)
        for label, bound in (("lower", self.lower), ("upper", self.upper)):
            if bound is not None and len(bound) != p:
                raise ModelError(f"ParameterSpace: {label} bounds have {len(bound)} entries, expected {p}")
        if self.margin_reference is not None and len(self.margin_reference) != p:
            raise ModelError(f"ParameterSpace: margin reference has {len(self.margin_reference)} entries, expected {p}")
        object.__setattr__(self, "_index", {n: i for i, n in enumerate(self.names)})

    @property
    def p(self) -> int:
        return len(self.names)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper) as new (p,) arrays, −inf / +inf where there are no bounds."""
        return (np.array(self.lower if self.lower is not None else [-np.inf] * self.p),
                np.array(self.upper if self.upper is not None else [np.inf] * self.p))

    def index(self, name: str) -> int:
        try:
            return self._index[name]
        except KeyError:
            raise ModelError(f"no parameter named {name!r}; parameters are {list(self.names)}") from None

    def with_bounds(self, lower=None, upper=None) -> "ParameterSpace":
        """A copy with bounds; each of lower/upper is an array (p,) or a {name: value} dict."""

        def as_tuple(bound, fill):
            if bound is None:
                return None
            if isinstance(bound, dict):
                arr = np.full(self.p, fill)
                for name, value in bound.items():
                    arr[self.index(name)] = value
                return tuple(float(x) for x in arr)
            arr = np.asarray(bound, dtype=float)
            if arr.shape != (self.p,):
                raise ModelError(f"bounds: expected shape ({self.p},), got {arr.shape}")
            return tuple(float(x) for x in arr)

        return ParameterSpace(
            self.names,
            self.units,
            self.blocks,
            as_tuple(lower, -np.inf) if lower is not None else self.lower,
            as_tuple(upper, np.inf) if upper is not None else self.upper,
            self.margin_reference,
            self.margin_epsilon,
            self.margin_label,
        )

    def with_margin(self, theta_ref, epsilon: float, label: str = "") -> "ParameterSpace":
        """A copy whose feasible set is C_b(θ) ⪰ ε·C_b(θ_ref) for every constrained block b (θ_k ≥ ε θ_ref,k
        on non-negative rows): θ − εθ_ref is physically consistent, so M_i(θ) ⪰ ε·M_i(θ_ref) at every
        configuration, seen or not (dualid.model.margin checks the arguments; ε = 0 is plain consistency)."""
        from dualid.model.margin import check_margin

        ref, eps = check_margin(self, theta_ref, epsilon)
        return dataclasses.replace(self, margin_reference=ref, margin_epsilon=eps, margin_label=str(label))

    def without_margin(self) -> "ParameterSpace":
        return dataclasses.replace(self, margin_reference=None, margin_epsilon=0.0, margin_label="")

    def margin_shift(self, block: "ParameterBlock") -> np.ndarray | None:
        """ε·C_b(θ_ref) (m, m) of one block, or None when there is no margin (or the block is free)."""
        if self.margin_reference is None or self.margin_epsilon == 0.0:
            return None
        C = block.constraint_matrix(np.asarray(self.margin_reference))
        return None if C is None else self.margin_epsilon * C

    def concatenate(self, other: "ParameterSpace") -> "ParameterSpace":
        """θ = [θ_self, θ_other]: the other space's blocks are shifted by self.p."""
        shift = self.p
        blocks = self.blocks + tuple(
            ParameterBlock(b.name, b.kind, tuple(i + shift for i in b.indices)) for b in other.blocks
        )

        def join(a, b, pa, pb, fill):
            if a is None and b is None:
                return None
            a = a if a is not None else (fill,) * pa
            b = b if b is not None else (fill,) * pb
            return tuple(a) + tuple(b)

        if self.margin_reference is not None or other.margin_reference is not None:
            raise ModelError("concatenate: add the margin (with_margin) after concatenating the parameter spaces")
        return ParameterSpace(
            self.names + other.names,
            self.units + other.units,
            blocks,
            join(self.lower, other.lower, self.p, other.p, -np.inf),
            join(self.upper, other.upper, self.p, other.p, np.inf),
        )

    def consistency_margins(self, theta: np.ndarray) -> dict[str, float]:
        """Smallest eigenvalue of each block's constraint matrix C_b(θ_b) (≥ 0 when consistent)."""
        out = {}
        for b in self.blocks:
            C = b.constraint_matrix(theta)
            if C is not None:
                out[b.name] = float(np.linalg.eigvalsh(C)[0])
        return out

    def violated_block(self, theta: np.ndarray, tol: float = 1e-9) -> tuple[str, float] | None:
        """(name, smallest eigenvalue) of the first block whose C_b(θ_b) is not ⪰ −tol·max(1, ‖C_b‖), else None."""
        theta = np.asarray(theta, dtype=float)
        for b in self.blocks:
            C = b.constraint_matrix(theta)
            if C is not None:
                lam = float(np.linalg.eigvalsh(C)[0])
                if lam < -tol * max(1.0, float(np.abs(C).max())):
                    return b.name, lam
        return None

    def is_consistent(self, theta: np.ndarray, tol: float = 1e-9) -> bool:
        """True when every block's C_b(θ_b) ⪰ −tol·max(1, ‖C_b‖) and θ is within the bounds."""
        theta = np.asarray(theta, dtype=float)
        if self.violated_block(theta, tol) is not None:
            return False
        if self.lower is not None and np.any(theta < np.asarray(self.lower) - tol):
            return False
        if self.upper is not None and np.any(theta > np.asarray(self.upper) + tol):
            return False
        return True


def rigid_body_space(body_names: list[str] | tuple[str, ...]) -> ParameterSpace:
    """10 inertial parameters per body, named '<body>.<m|mc_x|...>'."""
    names, units, blocks = [], [], []
    for j, body in enumerate(body_names):
        names += [f"{body}.{n}" for n in RIGID_BODY_NAMES]
        units += list(RIGID_BODY_UNITS)
        blocks.append(ParameterBlock(body, "rigid_body", tuple(range(10 * j, 10 * j + 10))))
    return ParameterSpace(tuple(names), tuple(units), tuple(blocks))
