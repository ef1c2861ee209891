"""On-disk data sets of Trajectories (simulated or processed): one file per run plus dataset.json.
This module reads them; ``dualid.report.dataset.save_dataset`` writes them.

Layout::

    directory/
        dataset.json            format version, splits, run files, coordinates, units, info
        <split>/<name>.parquet  (or .npz) one run: channels t, q_0.., v_<coord>, a_<coord>, tau_<coord>

Arrays are stored in SI units, as a Trajectory holds them. ``info`` (e.g. true θ, parameter names)
and each run's ``meta`` are stored as JSON (tuples come back as lists), except array-valued meta
entries (e.g. a simulator's ground truth), which go to ``<split>/<name>.meta.npz`` beside the run
and come back as arrays.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping

import numpy as np

from dualid.data.trajectory import Trajectory
from dualid.errors import DataError, MissingFileError

FORMAT = "dualid-dataset"
VERSION = 1
UNITS = {"t": "s", "q": "rad or m (quaternion unitless)", "v": "rad/s or m/s", "a": "rad/s^2 or m/s^2", "tau": "N m or N"}


def _merge_meta(meta: dict, arrays: Mapping[str, np.ndarray]) -> dict:
    for name, value in arrays.items():
        node = meta
        *parents, leaf = name.split("/")
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = value
    return meta


def _load_arrays(directory: Path, rel: str | None) -> dict[str, np.ndarray]:
    if rel is None:
        return {}
    path = directory / rel
    if not path.is_file():
        raise MissingFileError(f"dataset meta file not found: {path} (listed in {directory / 'dataset.json'})")
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def load_dataset(directory) -> tuple[dict[str, list[Trajectory]], dict]:
    """(splits -> runs, info) from a directory written by dualid.report.save_dataset."""
    directory = Path(directory)
    index = directory / "dataset.json"
    if not index.is_file():
        raise MissingFileError(f"no dataset.json in {directory}; not a dataset written by dualid.report.save_dataset")
    doc = json.loads(index.read_text())
    if doc.get("format") != FORMAT:
        raise DataError(f"{index}: format {doc.get('format')!r}, expected {FORMAT!r}")
    if doc.get("version") != VERSION:
        raise DataError(f"{index}: format version {doc.get('version')!r}; this dualid reads version {VERSION}")
    coords = tuple(doc["coordinates"])
    out: dict[str, list[Trajectory]] = {}
    for split, entries in doc["splits"].items():
        runs = []
        for e in entries:
            path = directory / e["file"]
            if not path.is_file():
                raise MissingFileError(f"dataset run file not found: {path} (listed in {index})")
            if path.suffix == ".npz":
                with np.load(path, allow_pickle=False) as z:
                    ch = {k: z[k] for k in z.files}
            else:
                import pandas as pd

                df = pd.read_parquet(path)
                ch = {c: df[c].to_numpy() for c in df.columns}

            def block(prefix, names):
                cols = [f"{prefix}_{c}" for c in names]
                missing = [c for c in cols if c not in ch]
                if missing:
                    raise DataError(f"{path}: missing channels {missing}; available: {list(ch)}")
                return np.stack([ch[c] for c in cols], axis=1)

            runs.append(
                Trajectory(
                    t=ch["t"],
                    q=block("q", range(e["nq"])),
                    v=block("v", coords),
                    tau=block("tau", coords),
                    a=block("a", coords) if e["has_a"] else None,
                    coordinates=coords,
                    name=e["name"],
                    meta=_merge_meta(e["meta"], _load_arrays(directory, e.get("meta_arrays"))),
                )
            )
        out[split] = runs
    return out, doc["info"]
