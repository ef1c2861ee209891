"""On-disk data sets of Trajectories (simulated or processed): one file per run plus dataset.json.

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
import re
from pathlib import Path
from typing import Mapping

import numpy as np

from dualid.errors import DataError
from dualid.trajectories.trajectory import Trajectory

FORMAT = "dualid-dataset"
VERSION = 1
UNITS = {"t": "s", "q": "rad or m (quaternion unitless)", "v": "rad/s or m/s", "a": "rad/s^2 or m/s^2", "tau": "N m or N"}
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


def _merge_meta(meta: dict, arrays: Mapping[str, np.ndarray]) -> dict:
    for name, value in arrays.items():
        node = meta
        *parents, leaf = name.split("/")
        for key in parents:
            node = node.setdefault(key, {})
        node[leaf] = value
    return meta


def _jsonable(x):
    """numpy values to plain Python (for json.dumps default=)."""
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, (set, frozenset)):
        return sorted(x)
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"cannot store {type(x).__name__} in dataset.json: {x!r}")


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
    """Write splits of runs (e.g. {"train": [...], "test": [...]}) and ``info`` to ``directory``.

    Refuses an existing non-empty directory unless overwrite=True; then the files of a data set
    already there (those listed in its dataset.json) are removed first and other files are left.
    """
    directory = Path(directory)
    if fmt not in ("parquet", "npz"):
        raise DataError(f"save_dataset: fmt must be 'parquet' or 'npz', got {fmt!r}")
    if directory.exists() and not directory.is_dir():
        raise FileExistsError(f"dataset path {directory} exists and is not a directory")
    if directory.is_dir() and any(directory.iterdir()):
        if not overwrite:
            raise FileExistsError(
                f"dataset directory {directory} exists and is not empty; pass overwrite=True to replace it"
            )
        _remove_dataset(directory)
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
    directory.mkdir(parents=True, exist_ok=True)
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
    (directory / "dataset.json").write_text(json.dumps(doc, indent=1, default=_jsonable))
    return directory


def _remove_dataset(directory: Path) -> None:
    index = directory / "dataset.json"
    if not index.exists():
        return
    try:
        doc = json.loads(index.read_text())
        files = [f for runs in doc.get("splits", {}).values() for e in runs for f in (e["file"], e.get("meta_arrays")) if f]
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise DataError(
            f"{index} is not a readable dualid data set index ({exc}); refusing to overwrite a directory "
            "whose files it cannot list — remove it by hand"
        ) from exc
    root = directory.resolve()
    for rel in files:
        p = (directory / rel).resolve()
        if root not in p.parents:
            continue  # never delete outside the data set directory
        if p.is_file():
            p.unlink()
        if p.parent != root and p.parent.is_dir() and not any(p.parent.iterdir()):
            p.parent.rmdir()
    index.unlink()


def _load_arrays(directory: Path, rel: str | None) -> dict[str, np.ndarray]:
    if rel is None:
        return {}
    path = directory / rel
    if not path.is_file():
        raise FileNotFoundError(f"dataset meta file not found: {path} (listed in {directory / 'dataset.json'})")
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def load_dataset(directory) -> tuple[dict[str, list[Trajectory]], dict]:
    """(splits -> runs, info) from a directory written by save_dataset."""
    directory = Path(directory)
    index = directory / "dataset.json"
    if not index.is_file():
        raise FileNotFoundError(f"no dataset.json in {directory}; not a dataset written by save_dataset")
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
                raise FileNotFoundError(f"dataset run file not found: {path} (listed in {index})")
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
