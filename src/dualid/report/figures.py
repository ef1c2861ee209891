"""Figure helpers of the report leaf: figures are built as ``matplotlib.figure.Figure`` objects
(no pyplot state, no backend switch) and saved only by the report writers."""

from __future__ import annotations

import io
from pathlib import Path

from matplotlib import colormaps, rc_context
from matplotlib.figure import Figure


# Unhinted glyphs: text is most of a figure's drawing time (matplotlib 3.11 lays out and renders every glyph), and
# FreeType's hinting adds about 15 % to it at the report's 80 dpi; the difference is not visible at that size.
# Titles at a fixed height (read when the axes are made): an automatic one measures every axis's ticks at each draw.
DRAWING = {"text.hinting": "none", "axes.titley": 1.0}
PNG = {"compress_level": 1}  # zlib's fastest level: a quarter less encoding time than PIL's 6, files ~10 % larger


def new_figure(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float], **subplots):
    """(Figure, axes (nrows, ncols) array) without touching pyplot."""
    fig = Figure(figsize=figsize)
    with rc_context(DRAWING):
        return fig, fig.subplots(nrows, ncols, squeeze=False, **subplots)


def png(fig: Figure, dpi: int = 80) -> bytes:
    """The figure as a PNG (Agg; the figures lay themselves out, so no second 'tight' drawing pass)."""
    buf = io.BytesIO()
    with rc_context(DRAWING):
        fig.savefig(buf, format="png", dpi=dpi, pil_kwargs=PNG)
    return buf.getvalue()


def save_figure(fig: Figure, path: str | Path, dpi: int = 120, **kw) -> Path:
    path = Path(path)
    with rc_context(DRAWING):
        fig.savefig(path, dpi=dpi, **({"pil_kwargs": PNG} if path.suffix == ".png" else {}), **kw)
    return path


def cycle_color(k: int):
    """The k-th colour of the tab10 cycle (for curves that have no colour of their own)."""
    return colormaps["tab10"](k % 10)
