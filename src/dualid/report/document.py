"""A report as one value: titled sections of text, tables, preformatted text and figures.

The fit and validation reports are built once as a ``Report`` (``report.fit_report``) and rendered
by both writers (``report.render``: Markdown and self-contained HTML), so the two cannot disagree.
A new section is one more ``Section`` in ``Report.sections``; its blocks render generically.

Figures carry their PNG bytes (rendered once): the Markdown links the PNG file written beside it,
the HTML embeds the same bytes as base64.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Union

import numpy as np


@dataclass(frozen=True)
class Text:
    """A paragraph (plain text; the writers escape it as needed)."""

    kind: ClassVar[str] = "text"
    text: str


@dataclass(frozen=True)
class Bullets:
    kind: ClassVar[str] = "bullets"
    items: tuple[str, ...]


@dataclass(frozen=True)
class Pre:
    """Preformatted text (e.g. the identifiability report)."""

    kind: ClassVar[str] = "pre"
    text: str


@dataclass(frozen=True)
class Table:
    """A table of already formatted cells; ``title`` is shown above it, ``note`` below."""

    kind: ClassVar[str] = "table"
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    title: str = ""
    note: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "header", tuple(str(h) for h in self.header))
        object.__setattr__(self, "rows", tuple(tuple(str(c) for c in r) for r in self.rows))


@dataclass(frozen=True, eq=False)
class Image:
    """A figure: ``name`` is the file the Markdown links (written beside it), holding ``png`` (a PNG) or, when that
    is empty, ``svg`` (self-contained SVG markup, escaped), which the HTML then shows inline."""

    kind: ClassVar[str] = "image"
    name: str
    png: bytes
    caption: str = ""
    svg: str = ""


Block = Union[Text, Bullets, Pre, Table, Image]


@dataclass(frozen=True, eq=False)
class Section:
    title: str
    blocks: tuple[Block, ...] = ()
    anchor: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "blocks", tuple(self.blocks))
        if not self.anchor:
            object.__setattr__(self, "anchor", "".join(c if c.isalnum() else "-" for c in self.title.lower()))


@dataclass(frozen=True, eq=False)
class Report:
    """title, an optional banner (e.g. "incomplete: …"), run metadata (key → value) and sections."""

    title: str
    sections: tuple[Section, ...] = ()
    banner: str = ""
    metadata: tuple[tuple[str, str], ...] = ()
    images: tuple[Image, ...] = field(init=False, default=())

    def __post_init__(self) -> None:
        object.__setattr__(self, "sections", tuple(s for s in self.sections if s.blocks))
        object.__setattr__(self, "images", tuple(b for s in self.sections for b in s.blocks if isinstance(b, Image)))


# --- formatting of numbers in cells -------------------------------------------------------------
def fmt(x: Any, digits: int = 4) -> str:
    """A number with ``digits`` significant digits ('—' for None/NaN); other values as str."""
    if x is None:
        return "—"
    if isinstance(x, (bool, np.bool_)):
        return str(bool(x))
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, (float, np.floating)):
        return "—" if not np.isfinite(x) else f"{float(x):.{digits}g}"
    return str(x)


def fmt_value(x: Any) -> str:
    """A configuration value for a table: numbers rounded to 4 significant digits (no float noise),
    lists and mappings element-wise."""
    if isinstance(x, dict):
        return ", ".join(f"{k} = {fmt_value(v)}" for k, v in x.items())
    if isinstance(x, (list, tuple)):
        return "[" + ", ".join(fmt_value(v) for v in x) + "]"
    return fmt(x)


def mean_cell(values: Sequence[float] | np.ndarray, digits: int = 3) -> str:
    """Mean ± std over runs of one score; a single run shows its value alone (its spread is not a
    measurement: no "± 0.000"), a spread below the last digit one significant digit (0.961 ± 0.0003).
    NaN values are left out; all NaN gives '—'."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return "—"
    m = f"{float(np.mean(x)):.{digits}f}"
    if x.size == 1:
        return m
    s = float(np.std(x))
    sd = f"{s:.{digits}f}"
    return f"{m} ± {sd if float(sd) != 0 or s == 0 else f'{s:.1g}'}"


def runs_phrase(n: int) -> str:
    return "1 run" if n == 1 else f"mean ± std over {n} runs"


def chunks(items: Sequence, size: int) -> list[Sequence]:
    """``items`` in consecutive groups of at most ``size`` (tables of many joints are split)."""
    return [items[i:i + size] for i in range(0, len(items), size)] or [items]
