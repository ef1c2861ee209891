"""Run metadata for the reports and parameters.yaml: dualid version, git commit of the dualid source
(when it is a git checkout), git commit of the data (when the input files lie in a git repository), UTC
time, command line and SHA-256 of every input file.

dualid installed with pip lives in a virtual environment, not in a checkout, so its source has no commit;
the commit that says what was fitted is the one of the repository holding the robot's logs and config."""

from __future__ import annotations

import hashlib
import shlex
import subprocess
import sys
from collections.abc import Iterable, Mapping
from datetime import datetime, timezone
from importlib import metadata as importlib_metadata
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parents[1]  # src/dualid


def dualid_version() -> str:
    try:
        return importlib_metadata.version("dualid")
    except importlib_metadata.PackageNotFoundError:
        return "unknown (dualid is not installed)"


def git_commit(where: Path = PACKAGE_DIR) -> str | None:
    """The commit of the dualid checkout that ``where`` (the package folder) is the ``src/dualid`` of, with
    "-dirty" when the package's own tracked files have uncommitted changes (files outside it, such as results, docs
    and benchmark scripts, are not looked at; untracked files are not either); None when dualid is not run from its own
    checkout (e.g. installed into a virtual environment that lies inside another project's repository,
    whose commit says nothing about dualid) or git is missing."""
    where = Path(where).resolve()
    try:
        if Path(_git(where, "rev-parse", "--show-toplevel")).resolve() / "src" / "dualid" != where:
            return None
        commit = _git(where, "rev-parse", "HEAD")
        dirty = bool(_git(where, "status", "--porcelain", "--untracked-files=no", "--", "."))
    except (OSError, subprocess.SubprocessError):
        return None
    return commit + ("-dirty" if dirty else "") if commit else None


def _git(where: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(where), *args], capture_output=True, text=True, timeout=10,
                          check=True).stdout.strip()


def data_commit(paths: Iterable[str | Path]) -> dict | None:
    """{"commit", "repository"} of the git repository holding the first existing input file, the commit with
    "-dirty" when any of the input files inside that repository is modified or untracked; None when the files
    lie in no repository or git is missing."""
    files = [Path(p).resolve() for p in paths if Path(p).is_file()]
    if not files:
        return None
    try:
        top = Path(_git(files[0].parent, "rev-parse", "--show-toplevel")).resolve()
        commit = _git(top, "rev-parse", "HEAD")
        inside = [str(f) for f in files if f.is_relative_to(top)]
        dirty = bool(_git(top, "status", "--porcelain", "--untracked-files=all", "--", *inside))
    except (OSError, subprocess.SubprocessError):
        return None
    return {"commit": commit + ("-dirty" if dirty else ""), "repository": str(top)} if commit else None


def sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def run_metadata(files: Mapping[str, Iterable[str | Path]], command: str | None = None) -> dict:
    """{dualid_version, git_commit, data_git, time_utc, command, python, inputs: [{role, path, sha256}]}.

    ``files``: role (e.g. "urdf", "train") → paths; a missing file gets sha256 None. ``command``: the
    command line (default: this process's argv)."""
    inputs = []
    for role, paths in files.items():
        for p in paths:
            inputs.append({"role": role, "path": str(p), "sha256": sha256(p) if Path(p).is_file() else None})
    return {
        "dualid_version": dualid_version(),
        "git_commit": git_commit(),
        "data_git": data_commit(p for paths in files.values() for p in paths),
        "time_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": command if command is not None else shlex.join(sys.argv),
        "python": sys.version.split()[0],
        "inputs": inputs,
    }


def metadata_items(meta: dict) -> tuple[tuple[str, str], ...]:
    """The metadata as (key, value) rows for a report (inputs listed separately)."""
    data = meta.get("data_git")
    return (
        ("dualid", meta["dualid_version"]),
        ("dualid source commit", meta["git_commit"] or "(an installed package, not a source checkout)"),
        ("data commit", f"{data['commit']} ({data['repository']})" if data else "(the input files are in no git "
                                                                                "repository)"),
        ("time (UTC)", meta["time_utc"]),
        ("command", meta["command"]),
        ("python", meta["python"]),
    )
