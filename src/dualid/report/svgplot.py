"""The held-out signal figures of a report as SVG: per joint, measured and predicted signals beside their
residuals (predicted − measured) and the joint's legend (each model's RMSE on that joint and run). The markup is
self-contained (its own style), so it is both the figure file that report.md links and the figure that report.html
shows inline; there each curve's <title> is the browser's tooltip and hovering a curve thickens it.

Axes follow the measured signal (``signals.axis_limits``): a wild prediction (e.g. 1e4 rad/s² forward dynamics of
a nearly singular M̂) is clipped rather than flattening the measurement into a line, and the caption names it.
Curves are decimated to at most ``signals.MAX_POINTS`` points. Plain markup costs ~1/20 of a matplotlib figure's
drawing.
"""

from __future__ import annotations

from dataclasses import dataclass
from html import escape

import numpy as np
from matplotlib.colors import to_hex

from dualid.evaluation.validation import Validation
from dualid.estimators.methods import color as method_color
from dualid.report.signals import SIGNALS, axis_limits, color, decimate, residual_limits, unit_of

ROW, TOP, BOTTOM = 170, 36, 24  # [px] one joint's row; the title line above the first; the time axis below the last
PANELS = ((60, 470), (530, 880))  # [px] x-range of the signal and the residual panel
LEGEND = 895  # [px] x of the legend column
WIDTH = 1120
_RULES = ("polyline{fill:none;stroke-width:1}", "polyline:hover{stroke-width:3}", ".frame{fill:none;stroke:#999}",
          ".zero{stroke:#000;stroke-width:.6}", "text{font:11px sans-serif}", ".tick{font-size:10px;fill:#444}",
          ".r{text-anchor:end}", ".m{text-anchor:middle}")
STYLE = "<style>" + "".join(f"svg.signals {rule}" for rule in _RULES) + "</style>"  # scoped: it also sits in HTML


@dataclass(frozen=True)
class SignalFigure:
    svg: str  # the markup (escaped)
    run: str
    signal: str  # "tau" or "a"
    clipped: tuple[str, ...]  # "label (joint)" of the predictions that left the axes

    @property
    def caption(self) -> str:
        text = f"Held-out run {self.run}, {SIGNALS[self.signal][3]}; the legend of each joint gives its RMSE on this run."
        if self.clipped:
            text += (" The axes follow the measured signal; predictions clipped (they leave the axes): "
                     + ", ".join(self.clipped) + ".")
        return text


def _ticks(lo: float, hi: float) -> np.ndarray:
    """About four round values in [lo, hi]."""
    step = 10 ** np.floor(np.log10((hi - lo) / 4))
    step *= next(m for m in (1, 2, 5, 10) if (hi - lo) / (m * step) <= 5)
    return np.arange(np.ceil(lo / step) * step, hi, step)


class _Panel:
    """One panel's frame, ticks and clipped curves, in pixels."""

    def __init__(self, out: list, key: str, x0: float, x1: float, y0: float, t0: float, t1: float, lo: float,
                 hi: float, label: str, last_row: bool):
        self.out, self.x0, self.x1, self.y0, self.t0, self.t1, self.lo, self.hi = out, x0, x1, y0, t0, t1, lo, hi
        y1 = y0 + ROW - TOP
        out.append(f'<clipPath id="{key}"><rect x="{x0}" y="{y0}" width="{x1 - x0}" height="{y1 - y0}"/></clipPath>'
                   f'<rect class="frame" x="{x0}" y="{y0}" width="{x1 - x0}" height="{y1 - y0}"/>'
                   f'<text x="{x0}" y="{y0 - 4}">{escape(label)}</text>')
        for v in _ticks(lo, hi):
            out.append(f'<text class="tick r" x="{x0 - 4}" y="{self.y(v) + 3:.1f}">{v:.3g}</text>')
        if last_row:
            for v in _ticks(t0, t1):
                out.append(f'<text class="tick m" x="{self.x(v):.1f}" y="{y1 + 13}">{v:.3g}</text>')
            out.append(f'<text class="tick m" x="{(x0 + x1) / 2}" y="{y1 + 24}">time [s]</text>')
        out.append(f'<g clip-path="url(#{key})">')

    def x(self, t):
        return self.x0 + (t - self.t0) / max(self.t1 - self.t0, 1e-12) * (self.x1 - self.x0)

    def y(self, v):
        span = self.hi - self.lo
        return self.y0 + (self.hi - np.clip(v, self.lo - span, self.hi + span)) / span * (ROW - TOP)

    def curve(self, t, v, stroke: str, title: str, dashed: bool = False) -> None:
        t, v = decimate(np.asarray(t, float), np.asarray(v, float))
        ok = np.isfinite(v)
        points = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(self.x(t[ok]), self.y(v[ok])))
        dash = ' stroke-dasharray="4 2"' if dashed else ""
        self.out.append(f'<polyline stroke="{stroke}"{dash} points="{points}"><title>{escape(title)}</title></polyline>')


def signal_svg(validations: dict[str, Validation], run: int, signal: str = "tau") -> SignalFigure:
    """Measured vs predicted effort ("tau") or acceleration ("a") on held-out run ``run`` (module docstring)."""
    first = next(iter(validations.values()))
    r0 = first.runs[run]
    stem, _, measured_label, what = SIGNALS[signal]
    measured = r0.tau if signal == "tau" else r0.a
    t0, t1 = float(r0.t[0]), float(r0.t[-1])
    n = len(first.coordinates)
    out = [f'<svg class="signals" xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {WIDTH} {ROW * n + BOTTOM + 8}" '
           f'width="100%" role="img" aria-label="{escape(r0.run)} {signal}">{STYLE}'
           f'<text x="{WIDTH / 2}" y="12" class="m">held-out run {escape(r0.run)}: {escape(what)}</text>']
    clipped: list[str] = []
    for j, joint in enumerate(first.coordinates):
        unit = unit_of(signal, joint)
        curves = []  # (legend text, colour, dashed, t, prediction)
        for k, (label, val) in enumerate(validations.items()):
            r = val.runs[run]
            pred = r.tau_pred if signal == "tau" else r.a_pred
            if pred is not None:
                score = (r.tau_rmse if signal == "tau" else r.a_rmse)[j]
                curves.append((f"{label}: RMSE {score:.3g} {unit}", to_hex(color(label, k)),
                               not method_color(label), r.t, np.asarray(pred[:, j], float), label))
        lo, hi = axis_limits(measured[:, j], [c[4] for c in curves])
        clipped += [f"{c[5]} ({joint})" for c in curves
                    if np.nanmin(c[4]) < lo or np.nanmax(c[4]) > hi or not np.isfinite(c[4]).all()]
        residuals = [c[4] - measured[:, j] for c in curves]
        y0 = TOP + ROW * j
        top = j == 0
        panel = _Panel(out, f"s{run}{signal}{j}", *PANELS[0], y0, t0, t1, lo, hi,
                       f"{joint} [{unit}]" + (f" — {stem}: measured (black) and predicted" if top else ""), j == n - 1)
        panel.curve(r0.t, measured[:, j], "#000000", measured_label)
        for title, hexcolor, dashed, t, y, _ in curves:
            panel.curve(t, y, hexcolor, title, dashed)
        out.append("</g>")
        rlo, rhi = residual_limits(residuals, hi - lo)
        panel = _Panel(out, f"r{run}{signal}{j}", *PANELS[1], y0, t0, t1, rlo, rhi,
                       "residual: predicted − measured" if top else "", j == n - 1)
        out.append(f'<line class="zero" x1="{PANELS[1][0]}" x2="{PANELS[1][1]}" y1="{panel.y(0.0):.1f}" '
                   f'y2="{panel.y(0.0):.1f}"/>')
        for (title, hexcolor, dashed, t, _, _), res in zip(curves, residuals):
            panel.curve(t, res, hexcolor, title, dashed)
        out.append(f'</g><text x="{LEGEND}" y="{y0 + 10}">{escape(joint)}</text>')
        for i, (title, hexcolor, dashed, *_) in enumerate(curves):
            y = y0 + 24 + 13 * i
            dash = ' stroke-dasharray="4 2"' if dashed else ""
            out.append(f'<line x1="{LEGEND}" x2="{LEGEND + 16}" y1="{y - 4}" y2="{y - 4}" stroke="{hexcolor}"{dash}/>'
                       f'<text class="tick" x="{LEGEND + 20}" y="{y}">{escape(title)}</text>')
    out.append("</svg>")
    return SignalFigure("".join(out), r0.run, signal, tuple(clipped))
