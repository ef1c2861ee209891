"""Write data sets of Trajectories (the layout is described in ``dualid.data.dataset``)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Mapping

import numpy as np

from dualid.data.dataset import FORMAT, UNITS, VERSION
from dualid.data.trajectory import Trajectory
from dualid.errors import DataError
from dualid.report.io import write_json
from dualid.report.outdir import output_dir

_SAFE = re.compile(r"^[A-Za-z0-9_.-]+$")


def _split_meta(meta: Mapping, prefix: str = "") -> tuple[dict, dict[str, np.ndarray]]:
    """(meta without numpy arrays, {"key/sub": array}) — arrays nested in dicts are flattened."""
    plain, arrays = {}, {}
    for key, value in meta.items():
        name = f"{prefix}{key}"
        if isinstance(value, np.ndarray) and value.ndim > 0:
            arrays[name] = value
        elif isinstance(value, Mapping):
            sub_plain, sub_arrays = _split_meta(value, f"{name}/")
            arrays.update(sub_arrays)
            if sub_plain or not sub_arrays:
                plain[key] = sub_plain
        else:
            plain[key] = value
    return plain, arrays


def _channels(traj: Trajectory) -> dict[str, np.ndarray]:
    ch = {"t": traj.t}
    ch.update({f"q_{k}": traj.q[:, k] for k in range(traj.q.shape[1])})
    for key in ("v", "a", "tau"):
        arr = getattr(traj, key)
        if arr is not None:
            ch.update({f"{key}_{c}": arr[:, j] for j, c in enumerate(traj.coordinates)})
    return ch


def save_dataset(
    directory,
    trajectories: Mapping[str, list[Trajectory]],
    info: dict | None = None,
    fmt: str = "parquet",
    overwrite: bool = False,
) -> Path:
    """Write splits of runs (e.g. {"train": [...], "test": [...]}) and ``info`` to ``directory``,
    under the output-directory policy (``dualid.report.outdir``; overwrite = --force)."""
    out = Path(directory)
    if fmt not in ("parquet", "npz"):
        raise DataError(f"save_dataset: fmt must be 'parquet' or 'npz', got {fmt!r}")
    coords = None
    for split, runs in trajectories.items():
        if not _SAFE.match(str(split)):
            raise DataError(f"save_dataset: split name {split!r} must match {_SAFE.pattern}")
        for traj in runs:
            if not isinstance(traj, Trajectory):
                raise DataError(f"save_dataset: split {split!r} holds a {type(traj).__name__}, expected Trajectory")
            coords = traj.coordinates if coords is None else coords
            if traj.coordinates != coords:
                raise DataError(
                    f"save_dataset: all runs must share coordinates; {list(coords)} vs {list(traj.coordinates)} "
                    f"in run {traj.name!r} of split {split!r}"
                )
    with output_dir(out, overwrite) as directory:
        _write(directory, trajectories, info, fmt, coords)
    return out


def _write(directory: Path, trajectories: Mapping[str, list[Trajectory]], info: dict | None, fmt: str, coords) -> None:
    splits = {}
    for split, runs in trajectories.items():
        (directory / split).mkdir(exist_ok=True)
        entries = []
        for k, traj in enumerate(runs):
            stem = f"run_{k:03d}"
            rel = f"{split}/{stem}.{fmt}"
            ch = _channels(traj)
            if fmt == "npz":
                np.savez(directory / rel, **ch)
            else:
                import pandas as pd

                pd.DataFrame(ch).to_parquet(directory / rel, index=False)
            meta, meta_arrays = _split_meta(traj.meta)
            entry = {"file": rel, "name": traj.name, "nq": traj.q.shape[1], "has_a": traj.a is not None, "meta": meta}
            if meta_arrays:
                entry["meta_arrays"] = f"{split}/{stem}.meta.npz"
                np.savez(directory / entry["meta_arrays"], **meta_arrays)
            entries.append(entry)
        splits[split] = entries
    doc = {
        "format": FORMAT,
        "version": VERSION,
        "fmt": fmt,
        "coordinates": list(coords or ()),
        "units": UNITS,
        "splits": splits,
        "info": info or {},
    }
    write_json(directory / "dataset.json", doc)
