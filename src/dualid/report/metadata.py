"""Run metadata for the reports and parameters.yaml: dualid version, git commit of the dualid source
(when it is a git checkout), UTC time, command line and SHA-256 of every input file."""

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
    "-dirty" when it has uncommitted changes to tracked files; None when dualid is not run from its own
    checkout (e.g. installed into a virtual environment that lies inside another project's repository,
    whose commit says nothing about dualid) or git is missing."""
    where = Path(where).resolve()
    try:
        def git(*args: str) -> str:
            return subprocess.run(["git", "-C", str(where), *args], capture_output=True, text=True, timeout=10,
                                  check=True).stdout.strip()

        if Path(git("rev-parse", "--show-toplevel")).resolve() / "src" / "dualid" != where:
            return None
        commit = git("rev-parse", "HEAD")
        dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return None
    return commit + ("-dirty" if dirty else "") if commit else None


def sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def run_metadata(files: Mapping[str, Iterable[str | Path]], command: str | None = None) -> dict:
    """{dualid_version, git_commit, time_utc, command, python, inputs: [{role, path, sha256}]}.

    ``files``: role (e.g. "urdf", "train") → paths; a missing file gets sha256 None. ``command``: the
    command line (default: this process's argv)."""
    inputs = []
    for role, paths in files.items():
        for p in paths:
            inputs.append({"role": role, "path": str(p), "sha256": sha256(p) if Path(p).is_file() else None})
    return {
        "dualid_version": dualid_version(),
        "git_commit": git_commit(),
        "time_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": command if command is not None else shlex.join(sys.argv),
        "python": sys.version.split()[0],
        "inputs": inputs,
    }


def metadata_items(meta: dict) -> tuple[tuple[str, str], ...]:
    """The metadata as (key, value) rows for a report (inputs listed separately)."""
    return (
        ("dualid", meta["dualid_version"]),
        ("git commit", meta["git_commit"] or "(not a git checkout)"),
        ("time (UTC)", meta["time_utc"]),
        ("command", meta["command"]),
        ("python", meta["python"]),
    )
