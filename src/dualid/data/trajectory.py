"""A trajectory: time-stamped states and generalized forces of one run, in a model's coordinates."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from dualid.errors import DataError


@dataclass(frozen=True, eq=False)
class Trajectory:
    """One run: T samples of configuration q, velocity v, acceleration a and generalized force tau.

    For a floating base, q holds Pinocchio's configuration (position + unit quaternion, nq = n + 1)
    and v, a the body velocity and its rate (Pinocchio's free-flyer convention).
    """

    t: np.ndarray  # (T,) time [s], strictly increasing
    q: np.ndarray  # (T, nq) configuration
    v: np.ndarray  # (T, n) generalized velocity
    tau: np.ndarray  # (T, n) generalized force
    a: np.ndarray | None = None  # (T, n) generalized acceleration (None for first-order systems)
    coordinates: tuple[str, ...] = ()  # names of the n velocity coordinates
    name: str = ""
    meta: dict = field(default_factory=dict)  # provenance: source file, processing steps, units
    wrench: np.ndarray | None = None  # (T, 6k) external wrenches [N, N m], one 6-block per meta["wrenches"] entry

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1 or t.size < 2:
            raise DataError(f"trajectory {self.name!r}: t must be a 1-D array of at least 2 times, got shape {t.shape}")
        T = t.size
        if np.any(np.diff(t) <= 0):
            k = int(np.argmax(np.diff(t) <= 0))
            raise DataError(
                f"trajectory {self.name!r}: time must be strictly increasing; t[{k}]={t[k]} then t[{k + 1}]={t[k + 1]}"
            )
        arrays = {"q": self.q, "v": self.v, "tau": self.tau, "a": self.a, "wrench": self.wrench}
        n = None
        for key, value in arrays.items():
            if value is None:
                continue
            arr = np.asarray(value, dtype=float)
            if arr.ndim != 2 or arr.shape[0] != T:
                raise DataError(f"trajectory {self.name!r}: {key} must have shape ({T}, ·), got {arr.shape}")
            if not np.all(np.isfinite(arr)):
                bad = np.argwhere(~np.isfinite(arr))[0].tolist()
                raise DataError(f"trajectory {self.name!r}: {key} has non-finite values (NaN or inf), first at {bad}")
            if key == "wrench" and arr.shape[1] % 6:
                raise DataError(f"trajectory {self.name!r}: wrench must have 6 columns per wrench, got {arr.shape[1]}")
            if key not in ("q", "wrench"):
                if n is not None and arr.shape[1] != n:
                    raise DataError(f"trajectory {self.name!r}: {key} has {arr.shape[1]} columns, expected {n}")
                n = arr.shape[1]
            arr = arr.copy()
            arr.setflags(write=False)
            object.__setattr__(self, key, arr)
        t = t.copy()
        t.setflags(write=False)
        object.__setattr__(self, "t", t)
        coords = tuple(self.coordinates) or tuple(f"v{j}" for j in range(n))
        if len(coords) != n:
            raise DataError(f"trajectory {self.name!r}: {len(coords)} coordinate names for {n} coordinates")
        object.__setattr__(self, "coordinates", coords)

    @property
    def T(self) -> int:
        return self.t.size

    @property
    def n(self) -> int:
        return self.v.shape[1]

    def take(self, idx) -> "Trajectory":
        """The samples idx (indices, slice or mask) of this run."""
        idx = np.arange(self.T)[idx]
        return replace(
            self,
            t=self.t[idx],
            q=self.q[idx],
            v=self.v[idx],
            tau=self.tau[idx],
            a=None if self.a is None else self.a[idx],
            wrench=None if self.wrench is None else self.wrench[idx],
            meta=dict(self.meta),
        )

    def with_step(self, step: dict, **changes) -> "Trajectory":
        """A copy with some arrays replaced and a processing step appended to meta['steps']."""
        meta = dict(self.meta)
        meta["steps"] = list(meta.get("steps", [])) + [step]
        return replace(self, meta=meta, **changes)
