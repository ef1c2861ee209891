"""Identification over many log files on a Dask cluster (``dask.distributed``): ``DaskProblem``.

A ``DaskProblem`` is a ``ChunkedProblem`` whose samples are spread over partitions: Parquet files (the columns of
``ParquetSource``, one partition a file) or the partitions of a Dask DataFrame with those columns. Every pass the
estimators mark as a sum of per-sample terms (``dualid.problem.additive``: the sufficient statistics of the
quadratic fits, the dual-metric Newton derivatives, …) runs as one task per partition on the cluster's workers: the
worker reads its partition, builds the regressor and the metric chunk by chunk from (q, v, a, τ) with the model (the
same ``ChunkedProblem`` code as a streamed fit on one machine) and returns its sums (p×p floats); the client adds
them in the partitions' order. Y never travels, and a worker holds one partition's raw samples and one chunk's Y.
A worker lost mid-pass only loses its tasks: the scheduler runs them again on another worker, and the sums are the
same. ``subset`` (the subsamples of ``dm``'s noise levels and of the metric guard) also runs on the workers and
returns only the selected samples. A pass that is not marked (none of OLS, WLS, energy, dm-paper or dm needs one)
reads the partitions on the client (``client_passes`` counts them).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dualid.errors import DataError
from dualid.model.base import Model
from dualid.problem import IdentificationProblem, add_sums
from dualid.streaming import ArraySource, Chunk, ChunkedProblem, ParquetSource, take_rows


def frame_columns(model: Model, has_a: bool = True) -> list[str]:
    """The columns a partition needs: q_0 … q_{nq−1}, v_<coordinate>, a_<coordinate> (if has_a), tau_<coordinate>."""
    coords = tuple(model.coordinates)
    nq = getattr(model, "nq", len(coords))
    cols = [f"q_{j}" for j in range(nq)] + [f"v_{c}" for c in coords]
    return cols + ([f"a_{c}" for c in coords] if has_a else []) + [f"tau_{c}" for c in coords]


def _frame_source(frame, model: Model, chunk: int) -> ArraySource:
    """A pandas DataFrame partition (columns as ``frame_columns``) as an ArraySource."""
    coords = tuple(model.coordinates)
    nq = len(frame_columns(model, False)) - 2 * len(coords)
    take = lambda names: np.ascontiguousarray(frame[names].to_numpy(dtype=float))
    a_cols = [f"a_{c}" for c in coords]
    a = take(a_cols) if all(c in frame.columns for c in a_cols) else None
    return ArraySource(take([f"q_{j}" for j in range(nq)]), take([f"v_{c}" for c in coords]), a,
                       take([f"tau_{c}" for c in coords]), chunk=chunk)


def _on_partition(kernel, model: Model, part, chunk: int, args: tuple, kwargs: dict):
    """On a worker: ``kernel`` over one partition (a ParquetSource, or a pandas DataFrame computed by Dask)."""
    source = part if isinstance(part, ParquetSource) else _frame_source(part, model, chunk)
    return kernel(ChunkedProblem(model, source), *args, **kwargs)


@dataclass(frozen=True, eq=False)
class _Partitions:
    """The partitions read on the client, one after the other (the passes that are not spread)."""

    parts: tuple  # ParquetSource or dask Delayed (a pandas DataFrame)
    sizes: tuple[int, ...]
    model: Model
    chunk: int

    @property
    def N(self) -> int:
        return int(sum(self.sizes))

    def chunks(self) -> Iterator[Chunk]:
        for part in self.parts:
            source = part if isinstance(part, ParquetSource) else _frame_source(part.compute(), self.model, self.chunk)
            yield from source.chunks()


@dataclass(frozen=True, eq=False)
class DaskProblem(ChunkedProblem):
    """The identification problem of a model over partitions on a Dask cluster (module doc). Build it with
    ``from_files`` or ``from_dataframe``; fit it as any problem (``make_estimator(method).fit(problem)``)."""

    client: object = None  # a dask.distributed.Client
    _spread: list = field(default_factory=lambda: [0], repr=False)  # passes run on the workers

    @classmethod
    def from_files(cls, model: Model, paths: Sequence, client, chunk: int = 65536,
                   progress: Callable[[int, int, int], None] | None = None) -> "DaskProblem":
        """One partition per Parquet file (checked here: present, Parquet, the model's columns)."""
        if not paths:
            raise DataError("DaskProblem.from_files: no files given; expected Parquet files with columns "
                            + ", ".join(frame_columns(model)[:3]) + ", …")
        nq = len(frame_columns(model, False)) - 2 * len(model.coordinates)
        parts = tuple(ParquetSource(Path(p), tuple(model.coordinates), nq, chunk=chunk) for p in paths)
        return cls(model, _Partitions(parts, tuple(p.N for p in parts), model, chunk), progress, client=client)

    @classmethod
    def from_dataframe(cls, model: Model, frame, client, chunk: int = 65536,
                       progress: Callable[[int, int, int], None] | None = None) -> "DaskProblem":
        """One partition per partition of the Dask DataFrame ``frame`` (its columns as ``frame_columns``)."""
        has_a = all(c in frame.columns for c in frame_columns(model)[-2 * len(model.coordinates):])
        missing = [c for c in frame_columns(model, has_a) if c not in frame.columns]
        if missing:
            raise DataError(f"DaskProblem.from_dataframe: missing columns {missing[:6]}{' …' if len(missing) > 6 else ''}"
                            f"; expected {', '.join(frame_columns(model)[:3])}, …, v_/a_/tau_<coordinate>")
        frame = frame[frame_columns(model, has_a)]
        sizes = tuple(int(s) for s in client.compute(frame.map_partitions(len)).result())
        parts = tuple(frame.to_delayed())
        return cls(model, _Partitions(parts, sizes, model, chunk), progress, client=client)

    @property
    def client_passes(self) -> int:
        """Passes that read the partitions on the client (not spread over the workers)."""
        return self._passes[0] - self._spread[0]

    def _map(self, kernel, args: tuple | list, kwargs: dict) -> list:
        """kernel(partition, *args, **kwargs) for every partition, one task each on the workers; the values in the
        partitions' order (``args``: one tuple for all, or a list of one tuple per partition, None to skip one).
        A task whose worker dies is run again by the scheduler on another worker."""
        import dask
        from distributed import as_completed

        self._passes[0] += 1
        self._spread[0] += 1
        source = self.source
        each = args if isinstance(args, list) else [args] * len(source.parts)
        model = dask.delayed(self.model, traverse=False)  # in the graph once per pass, not once per task
        tasks = [dask.delayed(_on_partition, pure=False)(kernel, model, part, source.chunk, a, kwargs)
                 for part, a in zip(source.parts, each) if a is not None]
        sizes = [size for size, a in zip(source.sizes, each) if a is not None]
        futures = self.client.compute(tasks)
        index, done = {f.key: i for i, f in enumerate(futures)}, 0
        for future in as_completed(futures):
            if future.status == "error":
                future.result()  # raises the kernel's own exception (e.g. a metric that is not positive definite)
            done += sizes[index[future.key]]
            if self.progress is not None:
                self.progress(self._passes[0], done, self.N)
        return self.client.gather(futures)

    def map_sum(self, kernel, *args, **kwargs):
        """Σ over the partitions of an ``additive`` kernel's value."""
        total = None
        for value in self._map(kernel, args, kwargs):
            total = value if total is None else add_sums(total, value)
        return total

    def map_concat(self, kernel, *args, **kwargs) -> np.ndarray:
        """A ``stacked`` kernel's rows, concatenated in the partitions' order."""
        return np.concatenate(self._map(kernel, args, kwargs))

    def subset(self, idx: slice) -> IdentificationProblem:
        """The samples idx (a slice) in memory on the client: each worker reads its partition and returns only
        its selected samples (one pass; the subsamples of ``dm``'s noise levels and of the metric guard)."""
        if not isinstance(idx, slice):
            raise DataError(f"DaskProblem.subset: expected a slice of samples, got {type(idx).__name__}")
        wanted, starts = np.arange(self.N)[idx], np.cumsum((0,) + self.source.sizes)
        local = [wanted[(wanted >= a) & (wanted < b)] - a for a, b in zip(starts[:-1], starts[1:])]
        parts = self._map(take_rows, [(rows,) if len(rows) else None for rows in local], {})
        if not parts:
            raise DataError(f"DaskProblem.subset: the slice {idx} selects no samples of {self.N}")
        return IdentificationProblem.concatenate(parts)


def local_client(workers: int, threads: int = 1):
    """A ``distributed.Client`` on a LocalCluster of ``workers`` processes (``threads`` threads each)."""
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=workers, threads_per_worker=threads, processes=True, dashboard_address=None)
    return Client(cluster)
