"""Reading a log file into named float channels: CSV and Parquet (pyarrow; its CSV parser gives each decimal its
nearest double, as Python's float() does) and NPZ.

(T, n) arrays (NPZ arrays, Parquet columns holding one list per row) become channels "name[k]".
Unreadable files are DataErrors naming the file; duplicated CSV header names are refused.
"""

from __future__ import annotations

import warnings
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path

import numpy as np

from dualid.data.checks import csv_header
from dualid.errors import DataError

FORMATS = (".csv", ".parquet", ".npz")


_READ: ContextVar[dict | None] = ContextVar("dualid_tables_read", default=None)


@contextmanager
def reading_once() -> Iterator[None]:
    """Inside this block read_table parses each file once (keyed by its resolved path, size and modification
    time) and hands out read-only arrays; a workflow that checks, samples and then loads the same log reads it once."""
    token = _READ.set({})
    try:
        yield
    finally:
        _READ.reset(token)


def read_once(path: Path, how: tuple, read):
    """read() -> (data: name -> array, ...) once per file (resolved path, sizes and modification times of the file or
    of the files in the folder) and ``how`` inside ``reading_once``, its arrays made read-only; always read outside."""
    cache = _READ.get()
    if cache is None:
        return read()
    files = sorted(path.iterdir()) if path.is_dir() else [path]
    key = (str(path.resolve()), how, tuple((f.name, f.stat().st_size, f.stat().st_mtime_ns) for f in files))
    if key not in cache:
        out = read()
        for x in out[0].values():
            x.flags.writeable = False
        cache[key] = out
    data, *rest = cache[key]
    return (dict(data), *(r.copy() for r in rest))


def read_table(path: Path) -> tuple[dict[str, np.ndarray], list[str]]:
    """All columns of the file as float arrays (name -> (T,)) and the column order."""
    return read_once(path, (), lambda: _read_table(path))


def _read_table(path: Path) -> tuple[dict[str, np.ndarray], list[str]]:
    ext = path.suffix.lower()
    if ext not in FORMATS:
        raise DataError(f"{path}: unknown log format {path.suffix!r}; expected one of {', '.join(FORMATS)}")
    if ext == ".npz":
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: np.asarray(z[k]) for k in z.files}
        except (ValueError, EOFError, zipfile.BadZipFile) as exc:  # not an npz, truncated, pickled objects
            raise DataError(f"{path}: cannot read it as .npz ({type(exc).__name__}: {exc})") from None
        if not data:
            raise DataError(f"{path}: log is empty (no rows)")
        data = _split_arrays(path, data)
        lengths = {k: v.shape[0] for k, v in data.items()}
        if len(set(lengths.values())) > 1:
            raise DataError(f"{path}: npz channels have different lengths {lengths}")
        return data, list(data)
    if ext == ".csv":
        import pyarrow.csv as pcsv

        try:
            csv_header(path)
        except UnicodeDecodeError as exc:
            raise DataError(f"{path}: cannot read it as CSV text ({exc})") from None  # duplicated names: refused there
        try:
            table = pcsv.read_csv(path)
        except ValueError as exc:  # pyarrow's ArrowInvalid, e.g. a row with more fields than the header
            if "Empty CSV file" in str(exc):
                raise DataError(f"{path}: log is empty (no rows)") from None
            raise DataError(f"{path}: cannot read it as CSV ({type(exc).__name__}: {exc})") from None
    else:
        import pyarrow.parquet as pq

        try:
            table = pq.read_table(path)
        except (ValueError, OSError) as exc:  # pyarrow's ArrowInvalid is a ValueError
            if isinstance(exc, (PermissionError, IsADirectoryError)):
                raise
            raise DataError(f"{path}: cannot read it as Parquet ({type(exc).__name__}: {exc})") from None
        table = table.select([c for c in table.column_names if not c.startswith("__index_level_")])  # pandas' index
    data = {str(c): _column(table, c) for c in table.column_names}
    for c, x in list(data.items()):  # Parquet list columns (one array per row) -> (T, n)
        if x.dtype == object and len(x) and isinstance(x[0], (list, tuple, np.ndarray)):
            try:
                data[c] = np.stack([np.asarray(r, dtype=float) for r in x])
            except (ValueError, TypeError):
                raise DataError(f"{path}: list column {c!r} has rows of different lengths or non-numbers") from None
    data = _split_arrays(path, data)
    return data, list(data)


def _column(table, name: str) -> np.ndarray:
    """A pyarrow column as a numpy array: numbers without gaps through DLPack (pyarrow's own conversion imports
    pandas, 0.3 s), anything else (missing cells, text, lists) by that conversion."""
    column = table.column(name).combine_chunks()
    try:
        with warnings.catch_warnings():  # numpy asks for a versioned capsule, which pyarrow ≤ 26 does not make yet
            warnings.simplefilter("ignore", DeprecationWarning)
            return np.from_dlpack(column)
    except (TypeError, ValueError, BufferError):  # pyarrow's ArrowTypeError is a TypeError
        return column.to_numpy(zero_copy_only=False)


def _split_arrays(path: Path, data: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """2-D arrays (T, n) become channels 'name[0]' … 'name[n-1]' (addressed so in a column map)."""
    out: dict[str, np.ndarray] = {}
    for k, x in data.items():
        if x.ndim == 1:
            out[k] = x
        elif x.ndim == 2:
            out.update({f"{k}[{i}]": x[:, i] for i in range(x.shape[1])})
        else:
            raise DataError(f"{path}: array {k!r} has shape {x.shape}; expected (T,) channels or (T, n) arrays")
    return out
