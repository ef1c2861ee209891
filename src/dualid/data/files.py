"""Reading the YAML/JSON files dualid is given (fit and excite configs, reference and prior parameters) with
errors that name the file and the line."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from dualid.errors import ConfigError, MissingFileError


def read_mapping(path: str | Path, what: str) -> dict[str, Any]:
    """The mapping in a YAML (or .json) file; ConfigError naming the file and line on a syntax error
    or when the top level is not a mapping; an empty file is {}. ``what`` names the file's role."""
    import yaml

    path = Path(path)
    if not path.exists():
        raise MissingFileError(f"{what} not found: {path}")
    if path.is_dir():
        raise ConfigError(f"{what} {path}: is a directory, expected a file")
    text = path.read_text()  # an unreadable file raises OSError (PermissionError): reported as such
    if path.suffix.lower() == ".json":
        try:
            d = json.loads(text) if text.strip() else {}
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{what} {path}: JSON syntax error at line {exc.lineno}, column {exc.colno}: {exc.msg}") from None
    else:
        try:
            d = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
            problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
            raise ConfigError(f"{what} {path}: YAML syntax error{where}: {problem}") from None
    if d is None:
        return {}
    if not isinstance(d, dict):
        raise ConfigError(f"{what} {path}: expected a mapping of keys to values at the top level, got {type(d).__name__}")
    return d
