"""Figure helpers of the report leaf: figures are built as ``matplotlib.figure.Figure`` objects
(no pyplot state, no backend switch) and saved only by the report writers."""

from __future__ import annotations

from pathlib import Path

from matplotlib import colormaps
from matplotlib.figure import Figure


def new_figure(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float], **subplots):
    """(Figure, axes (nrows, ncols) array) without touching pyplot."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols, squeeze=False, **subplots)


def save_figure(fig: Figure, path: str | Path, dpi: int = 120, **kw) -> Path:
    path = Path(path)
    fig.savefig(path, dpi=dpi, **kw)
    return path


def cycle_color(k: int):
    """The k-th colour of the tab10 cycle (for curves that have no colour of their own)."""
    return colormaps["tab10"](k % 10)
