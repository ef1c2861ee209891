"""Identification from data that need not fit in memory: chunked sources and ``ChunkedProblem``.

A *source* yields the raw samples (q, v, a, τ) in chunks, once per pass, from arrays (also memory-mapped
``.npy`` files) or a Parquet file (pyarrow, read in record batches). A ``ChunkedProblem`` builds each
chunk's regressor and metric with the model on the fly and hands the estimators one in-memory block at
a time (``blocks()``, read by ``dualid.problem.sample_blocks``), so at no time are more than one chunk's
Y_i (chunk·n·p floats) in memory. Every estimator that works from passes over the data (the quadratic
ones through their sufficient statistics, the dual-metric Newton method through its chunked
derivatives, the feasible-GLS ``dm``) accepts it in place of an ``IdentificationProblem``; the price is
the regressor being rebuilt on every pass. ``progress(pass, done, N)`` is called after every chunk
(core code reports; the CLI draws the bars).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dualid.errors import DataError, MissingFileError
from dualid.model.base import Model
from dualid.problem import IdentificationProblem, additive, identifiability_of, owned, stacked

Chunk = tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]  # q (c, nq), v (c, n), a (c, n) or None, τ (c, n)


@dataclass(frozen=True, eq=False)
class ArraySource:
    """Samples from arrays (in memory, or memory-mapped with ``from_npy``), ``chunk`` rows at a time."""

    q: np.ndarray  # (N, nq)
    v: np.ndarray  # (N, n)
    a: np.ndarray | None  # (N, n) or None
    tau: np.ndarray  # (N, n)
    chunk: int = 65536

    def __post_init__(self) -> None:
        N = len(self.q)
        for name in ("v", "a", "tau"):
            x = getattr(self, name)
            if x is not None and len(x) != N:
                raise DataError(f"ArraySource: {name} has {len(x)} rows, q has {N}")
        if not (isinstance(self.chunk, int) and self.chunk >= 1):
            raise DataError(f"ArraySource: chunk must be a positive integer, got {self.chunk!r}")

    @property
    def N(self) -> int:
        return len(self.q)

    def chunks(self) -> Iterator[Chunk]:
        for s in range(0, self.N, self.chunk):
            rows = slice(s, s + self.chunk)
            yield (np.asarray(self.q[rows], dtype=float), np.asarray(self.v[rows], dtype=float),
                   None if self.a is None else np.asarray(self.a[rows], dtype=float),
                   np.asarray(self.tau[rows], dtype=float))

    @classmethod
    def from_npy(cls, directory, chunk: int = 65536) -> "ArraySource":
        """q.npy, v.npy, tau.npy (and a.npy if present) in ``directory``, memory-mapped (read as needed)."""
        directory = Path(directory)
        arrays = {}
        for name in ("q", "v", "a", "tau"):
            path = directory / f"{name}.npy"
            if not path.is_file():
                if name == "a":
                    arrays[name] = None
                    continue
                raise MissingFileError(f"ArraySource.from_npy: {path} not found (expected q.npy, v.npy, tau.npy, a.npy)")
            arrays[name] = np.load(path, mmap_mode="r")
        return cls(**arrays, chunk=chunk)


@dataclass(frozen=True, eq=False)
class ParquetSource:
    """Samples from a Parquet file with columns q_0 … q_{nq−1}, v_<coord>, a_<coord>, tau_<coord> (the run
    files of ``dualid.data.dataset``), read ``chunk`` rows at a time with pyarrow."""

    path: Path
    coordinates: tuple[str, ...]
    nq: int
    chunk: int = 65536
    has_a: bool = True

    def __post_init__(self) -> None:
        import pyarrow.parquet as pq

        object.__setattr__(self, "path", Path(self.path))
        if not self.path.is_file():
            raise MissingFileError(f"ParquetSource: {self.path} not found")
        try:
            file = pq.ParquetFile(self.path)
        except (OSError, ValueError) as exc:  # pyarrow's ArrowInvalid (a ValueError): empty, CSV, truncated, …
            raise DataError(f"{self.path}: not a Parquet file ({exc}); expected Parquet with columns q_0..q_{self.nq - 1}, "
                            "v_/a_/tau_<coordinate> (or a directory of q.npy, v.npy, a.npy, tau.npy)") from None
        if file.metadata.num_rows == 0:
            raise DataError(f"{self.path}: the Parquet file has no rows")
        names = set(file.schema_arrow.names)
        missing = [c for c in self._columns() if c not in names]
        if missing:
            raise DataError(f"{self.path}: missing columns {missing[:6]}{' …' if len(missing) > 6 else ''}; "
                            f"expected q_0..q_{self.nq - 1}, v_/a_/tau_<coordinate>")

    def _columns(self) -> list[str]:
        cols = [f"q_{j}" for j in range(self.nq)] + [f"v_{c}" for c in self.coordinates]
        cols += [f"a_{c}" for c in self.coordinates] if self.has_a else []
        return cols + [f"tau_{c}" for c in self.coordinates]

    @property
    def N(self) -> int:
        import pyarrow.parquet as pq

        return pq.ParquetFile(self.path).metadata.num_rows

    def chunks(self) -> Iterator[Chunk]:
        import pyarrow.parquet as pq

        n, nq = len(self.coordinates), self.nq
        # pre_buffer=False: with it, pyarrow coalesces the reads of every row group the iterator will visit, i.e.
        # holds the whole (compressed) file in memory (peak RSS 2.5 GB for a 1.7 GB file at N = 10⁷)
        for batch in pq.ParquetFile(self.path, pre_buffer=False).iter_batches(batch_size=self.chunk,
                                                                               columns=self._columns()):
            X = np.column_stack([batch.column(k).to_numpy(zero_copy_only=False) for k in range(batch.num_columns)])
            a = X[:, nq + n : nq + 2 * n] if self.has_a else None
            yield X[:, :nq], X[:, nq : nq + n], a, X[:, -n:]


@dataclass(frozen=True, eq=False)
class ChunkedProblem:
    """The identification problem of a model over a chunked source (module doc); the same interface as
    ``IdentificationProblem`` for everything that passes over the data, without Y in memory."""

    model: Model
    source: ArraySource | ParquetSource
    progress: Callable[[int, int, int], None] | None = None  # (pass 1, 2, …, samples done, N) after each chunk
    _passes: list = field(default_factory=lambda: [0], repr=False)  # passes made so far (a counter)

    sensor_chart = None  # the forces are measured in the model's chart

    def __post_init__(self) -> None:
        if self.source.N == 0:
            raise DataError("the problem has no samples (N = 0)")

    @property
    def N(self) -> int:
        return self.source.N

    @property
    def n(self) -> int:
        return len(self.model.coordinates)

    @property
    def p(self) -> int:
        return self.model.parameters.p

    @property
    def parameters(self):
        return self.model.parameters

    @property
    def kind(self):
        return self.model.kind

    @property
    def coordinates(self) -> tuple[str, ...]:
        return tuple(self.model.coordinates)

    @property
    def passes(self) -> int:
        """Passes over the source so far."""
        return self._passes[0]

    def blocks(self) -> Iterator[IdentificationProblem]:
        """One in-memory problem per chunk of the source (one pass)."""
        self._passes[0] += 1
        done = 0
        for q, v, a, tau in self.source.chunks():
            if self.kind == "inertia" and a is None:
                raise DataError("the source has no accelerations; an inertia-dominated model needs them")
            block = IdentificationProblem(owned(self.model.regressor(q, v, a)), tau, self.model.metric(q), v,
                                          self.parameters, self.kind, self.coordinates)
            yield block
            done += block.N
            if self.progress is not None:
                self.progress(self._passes[0], done, self.N)

    def in_sensor_chart(self) -> "ChunkedProblem":
        return self

    def column_norms(self) -> np.ndarray:
        return np.sqrt(_column_squares(self))

    def identifiability(self):
        return identifiability_of(self)

    def residual(self, theta: np.ndarray) -> np.ndarray:
        """r_i (N, n): N·n floats (not N·n·p), for callers that need every residual."""
        return _residuals(self, theta)

    def dual_metric_objective(self, theta: np.ndarray) -> float:
        return float(_dual_metric_sum(self, theta))

    def explained(self, theta: np.ndarray) -> float:
        """R² = 1 − Σ‖r_i‖² / Σ‖τ_i − τ̄‖² (one pass): the share of the effort's variance the model with θ explains."""
        rss, s1, s2, N = _explained_sums(self, theta)
        tss = float(np.sum(s2 - s1 ** 2 / max(N, 1)))
        return 1.0 - rss / tss if tss > 0 else float("nan")

    def subset(self, idx: slice) -> IdentificationProblem:
        """The samples idx (a slice, e.g. every k-th) collected into an in-memory problem (one pass)."""
        if not isinstance(idx, slice):
            raise DataError(f"ChunkedProblem.subset: expected a slice of samples, got {type(idx).__name__}")
        taken = take_rows(self, np.arange(self.N)[idx])
        if taken is None:
            raise DataError(f"ChunkedProblem.subset: the slice {idx} selects no samples of {self.N}")
        return taken

    def materialise(self) -> IdentificationProblem:
        """All samples in memory (for the solvers that need them at once, e.g. the SDP)."""
        return self.subset(slice(None))



def take_rows(problem: "ChunkedProblem", wanted: np.ndarray) -> IdentificationProblem | None:
    """The samples ``wanted`` (ascending indices into the problem) in memory, in one pass; None if there are none."""
    parts, offset = [], 0
    for block in problem.blocks():
        local = wanted[(wanted >= offset) & (wanted < offset + block.N)] - offset
        if len(local):
            parts.append(block.subset(local))
        offset += block.N
    return IdentificationProblem.concatenate(parts) if parts else None


# The passes above as sums (or rows) per sample, so that a problem spread over partitions (``dualid.distributed``)
# runs them where the data live (``dualid.problem.additive``).
@additive
def _column_squares(problem) -> np.ndarray:
    return sum(block.column_norms() ** 2 for block in problem.blocks())


@stacked
def _residuals(problem, theta: np.ndarray) -> np.ndarray:
    return np.concatenate([b.residual(theta) for b in problem.blocks()])


@additive
def _dual_metric_sum(problem, theta: np.ndarray) -> float:
    return float(sum(b.dual_metric_objective(theta) for b in problem.blocks()))


@additive
def _explained_sums(problem, theta: np.ndarray) -> tuple:
    """(Σ‖r_i‖², Σ τ_i, Σ τ_i², N)."""
    rss, s1, s2, N = 0.0, 0.0, 0.0, 0
    for b in problem.blocks():
        rss += float(np.sum(b.residual(theta) ** 2))
        s1, s2, N = s1 + b.tau.sum(axis=0), s2 + np.sum(b.tau ** 2, axis=0), N + b.tau.shape[0]
    return rss, s1, s2, N
