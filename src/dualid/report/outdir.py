"""The one output-directory policy of every command and writer.

- Without ``force`` an existing non-empty directory is never touched.
- With ``force`` only the files that dualid itself wrote there before (listed in the directory's
  manifest, ``.dualid-manifest.json``) are removed; foreign files are kept, and a new output whose
  name collides with a foreign file is refused.
- Everything is first written into a temporary sibling directory and moved into place at the end,
  so a failed run never leaves a complete-looking output (the temporary directory is removed).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from dualid.errors import DataError, OutputError

MANIFEST = ".dualid-manifest.json"


def _manifest(directory: Path) -> list[str]:
    """The relative paths dualid wrote into ``directory`` before (empty if it has no manifest)."""
    path = directory / MANIFEST
    if not path.is_file():
        return []
    try:
        files = json.loads(path.read_text())["files"]
        if not isinstance(files, list) or not all(isinstance(f, str) for f in files):
            raise DataError("'files' is not a list of strings")
    except (ValueError, KeyError, TypeError) as exc:
        raise OutputError(
            f"{path}: unreadable dualid manifest ({exc}); refusing to overwrite a directory whose "
            "files dualid cannot list — remove them by hand"
        ) from exc
    return files


def check_output_files(paths, force: bool, parser=None) -> list[Path]:
    """Files a script is about to write, checked before its work: OutputError naming those that exist unless
    ``force`` (with an argparse ``parser``: its ``error``, exit status 2 after the usage line); their directories are
    made. The paths, as Paths."""
    paths = [Path(p) for p in paths]
    existing = [str(p) for p in paths if p.exists()]
    if existing and not force:
        message = (f"{', '.join(existing)}: {'exists' if len(existing) == 1 else 'exist'}; pass --force to replace "
                   + ("it" if len(existing) == 1 else "them"))
        if parser is not None:
            parser.error(message)
        raise OutputError(message)
    for p in paths:
        p.parent.mkdir(parents=True, exist_ok=True)
    return paths


def check_output_dir(out: str | Path, force: bool) -> Path:
    """Fail early (before a long computation) if ``out`` cannot be written under the policy."""
    out = Path(out)
    above = next((p for p in out.parents if p.exists()), None)
    if above is not None and not above.is_dir():
        raise OutputError(f"output directory {out}: {above} is a file, so no directory can be made below it")
    if out.exists() and not out.is_dir():
        raise OutputError(f"output directory {out}: exists and is a file, expected a directory")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise OutputError(f"output directory {out}: exists and is not empty; choose another or pass --force")
    if out.is_dir():
        _manifest(out)  # an unreadable manifest is an error now, not after the work
    parent = out.resolve().parent
    if parent.exists() and not os.access(parent, os.W_OK):
        raise OutputError(f"output directory {out}: cannot write in {parent} (permission denied)")
    return out


def _files_below(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file())


def _install(tmp: Path, out: Path) -> None:
    """Move the files of ``tmp`` into ``out`` after removing what dualid wrote there before."""
    new = _files_below(tmp)
    if not out.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp, out)
        return
    old = set(_manifest(out))
    root = out.resolve()
    clashes = [f for f in new if f != MANIFEST and f not in old and (out / f).exists()]
    if clashes:
        raise OutputError(
            f"output directory {out}: would overwrite files that dualid did not write: {clashes[:5]}"
            + (f" and {len(clashes) - 5} more" if len(clashes) > 5 else "") + "; move them away first"
        )
    for rel in old:
        p = (out / rel).resolve()
        if root in p.parents and p.is_file():
            p.unlink()
    for rel in new:
        dest = out / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp / rel, dest)
    for d in sorted((p for p in root.rglob("*") if p.is_dir()), key=lambda p: len(p.parts), reverse=True):
        if not any(d.iterdir()):
            d.rmdir()
    shutil.rmtree(tmp, ignore_errors=True)


@contextmanager
def output_dir(out: str | Path, force: bool = False) -> Iterator[Path]:
    """Yield a fresh temporary directory to write into; on success its files replace ``out``'s
    (under the policy above) together with a manifest; on any error ``out`` is left as it was."""
    out = check_output_dir(out, force)
    parent = out.resolve().parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=parent))
    except OSError as exc:
        raise OutputError(f"output directory {out}: cannot create it ({exc.strerror or exc})") from exc
    try:
        yield tmp
        (tmp / MANIFEST).write_text(json.dumps({"files": _files_below(tmp)}, indent=1) + "\n")
        _install(tmp, out)
    except OSError as exc:
        raise OutputError(f"output directory {out}: cannot write ({exc.strerror or exc}: {exc.filename})") from exc
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def write_output(out: str | Path, force: bool, write: Callable[[Path], dict[str, Path]]) -> dict[str, Path]:
    """Run ``write(directory) -> {name: path}`` under the policy; return the paths as installed in ``out``."""
    with output_dir(out, force) as tmp:
        written = write(tmp)
    return {k: Path(out) / Path(p).relative_to(tmp) for k, p in written.items()}
