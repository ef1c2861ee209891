"""The report's figures as SVG: the held-out signal figures (per joint, measured and predicted signals beside their
residuals (predicted − measured) and the joint's legend: each model's RMSE on that joint and run), the held-out score
bars and the joint friction curves. The markup is self-contained (its own style), so it is both the figure file that
report.md links and the figure that report.html shows inline; there each curve's <title> is the browser's tooltip
and hovering a curve thickens it.

Axes follow the measured signal (``signals.axis_limits``): a wild prediction (e.g. 1e4 rad/s² forward dynamics of
a nearly singular M̂) is clipped rather than flattening the measurement into a line, and the caption names it.
Curves are decimated to at most ``signals.MAX_POINTS`` points. Plain markup costs ~1/20 of a matplotlib figure's
drawing, and a fit's report imports no plotting library.
"""

from __future__ import annotations

from dataclasses import dataclass
from html import escape

import numpy as np

from dualid.evaluation.validation import Validation
from dualid.report.signals import SIGNALS, axis_limits, decimate, residual_limits, style, unit_of

ROW, TOP, BOTTOM = 170, 36, 24  # [px] one joint's row; the title line above the first; the time axis below the last
PANELS = ((60, 470), (530, 880))  # [px] x-range of the signal and the residual panel
LEGEND = 895  # [px] x of the legend column
WIDTH = 1120
_RULES = ("polyline{fill:none;stroke-width:1}", "polyline:hover{stroke-width:3}", ".frame{fill:none;stroke:#999}",
          ".zero{stroke:#000;stroke-width:.6}", "text{font:11px sans-serif}", ".tick{font-size:10px;fill:#444}",
          ".r{text-anchor:end}", ".m{text-anchor:middle}")
STYLE = "<style>" + "".join(f"svg.plot {rule}" for rule in _RULES) + "</style>"  # scoped: it also sits in HTML


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


def _open(width: float, height: float, label: str, title: str) -> list[str]:
    """The opening markup of a figure: its size, style and title line."""
    return [f'<svg class="plot" xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {width} {height}" width="100%" '
            f'role="img" aria-label="{escape(label)}">{STYLE}<text x="{width / 2}" y="12" class="m">{escape(title)}</text>']


class _Panel:
    """One panel's frame, ticks and clipped curves, in pixels: x0…x1 × y0…y0 + height showing t0…t1 × lo…hi. The
    x axis has numeric ticks and ``xlabel`` below it, or ``categories`` at 0, 1, … (t0, t1 = −0.5, len − 0.5), or
    nothing (xlabel None)."""

    def __init__(self, out: list, key: str, x0: float, x1: float, y0: float, t0: float, t1: float, lo: float,
                 hi: float, label: str, xlabel: str | None = None, height: float = ROW - TOP,
                 categories: tuple[str, ...] = ()):
        self.out, self.x0, self.x1, self.y0, self.h = out, x0, x1, y0, height
        self.t0, self.t1, self.lo, self.hi = t0, t1, lo, hi
        y1 = y0 + height
        out.append(f'<clipPath id="{key}"><rect x="{x0}" y="{y0}" width="{x1 - x0}" height="{height}"/></clipPath>'
                   f'<rect class="frame" x="{x0}" y="{y0}" width="{x1 - x0}" height="{height}"/>'
                   f'<text x="{x0}" y="{y0 - 4}">{escape(label)}</text>')
        for v in _ticks(lo, hi):
            out.append(f'<text class="tick r" x="{x0 - 4}" y="{self.y(v) + 3:.1f}">{v:.3g}</text>')
        ticks = list(enumerate(categories)) if categories else \
            [(v, f"{v:.3g}") for v in _ticks(t0, t1)] if xlabel is not None else []
        for v, text in ticks:
            out.append(f'<text class="tick m" x="{self.x(v):.1f}" y="{y1 + 13}">{escape(text)}</text>')
        if xlabel:
            out.append(f'<text class="tick m" x="{(x0 + x1) / 2}" y="{y1 + 24}">{escape(xlabel)}</text>')
        out.append(f'<g clip-path="url(#{key})">')

    def x(self, t):
        return self.x0 + (t - self.t0) / max(self.t1 - self.t0, 1e-12) * (self.x1 - self.x0)

    def y(self, v):
        span = self.hi - self.lo
        return self.y0 + (self.hi - np.clip(v, self.lo - span, self.hi + span)) / span * self.h

    def curve(self, t, v, stroke: str, title: str, dashed: bool = False) -> None:
        t, v = decimate(np.asarray(t, float), np.asarray(v, float))
        ok = np.isfinite(v)
        points = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(self.x(t[ok]), self.y(v[ok])))
        dash = ' stroke-dasharray="4 2"' if dashed else ""
        self.out.append(f'<polyline stroke="{stroke}"{dash} points="{points}"><title>{escape(title)}</title></polyline>')

    def zero(self) -> None:
        """The line y = 0 across the panel, where it is inside."""
        if self.lo < 0 < self.hi:
            self.out.append(f'<line class="zero" x1="{self.x0}" x2="{self.x1}" y1="{self.y(0.0):.1f}" '
                            f'y2="{self.y(0.0):.1f}"/>')


def _legend(out: list, x0: float, y: float, entries, dy: float = 13, columns: int = 1, dx: float = 0) -> None:
    """Legend entries (text, colour, dashed) from (x, y), each with a short line swatch: row by row in ``columns``
    columns ``dx`` apart."""
    for i, (text, stroke, dashed) in enumerate(entries):
        x, yi = x0 + dx * (i % columns), y + dy * (i // columns)
        dash = ' stroke-dasharray="4 2"' if dashed else ""
        out.append(f'<line x1="{x}" x2="{x + 16}" y1="{yi - 4}" y2="{yi - 4}" stroke="{stroke}" stroke-width="2"{dash}/>'
                   f'<text class="tick" x="{x + 20}" y="{yi}">{escape(text)}</text>')


def signal_svg(validations: dict[str, Validation], run: int, signal: str = "tau") -> SignalFigure:
    """Measured vs predicted effort ("tau") or acceleration ("a") on held-out run ``run`` (module docstring)."""
    first = next(iter(validations.values()))
    r0 = first.runs[run]
    stem, _, measured_label, what = SIGNALS[signal]
    measured = r0.tau if signal == "tau" else r0.a
    t0, t1 = float(r0.t[0]), float(r0.t[-1])
    n = len(first.coordinates)
    out = _open(WIDTH, ROW * n + BOTTOM + 8, f"{r0.run} {signal}", f"held-out run {r0.run}: {what}")
    clipped: list[str] = []
    for j, joint in enumerate(first.coordinates):
        unit = unit_of(signal, joint)
        curves = []  # (legend text, colour, dashed, t, prediction)
        for k, (label, val) in enumerate(validations.items()):
            r = val.runs[run]
            pred = r.tau_pred if signal == "tau" else r.a_pred
            if pred is not None:
                score = (r.tau_rmse if signal == "tau" else r.a_rmse)[j]
                curves.append((f"{label}: RMSE {score:.3g} {unit}", *style(label, k), r.t,
                               np.asarray(pred[:, j], float), label))
        lo, hi = axis_limits(measured[:, j], [c[4] for c in curves])
        clipped += [f"{c[5]} ({joint})" for c in curves
                    if np.nanmin(c[4]) < lo or np.nanmax(c[4]) > hi or not np.isfinite(c[4]).all()]
        residuals = [c[4] - measured[:, j] for c in curves]
        y0 = TOP + ROW * j
        top = j == 0
        xlabel = "time [s]" if j == n - 1 else None
        panel = _Panel(out, f"s{run}{signal}{j}", *PANELS[0], y0, t0, t1, lo, hi,
                       f"{joint} [{unit}]" + (f" — {stem}: measured (black) and predicted" if top else ""), xlabel)
        panel.curve(r0.t, measured[:, j], "#000000", measured_label)
        for title, hexcolor, dashed, t, y, _ in curves:
            panel.curve(t, y, hexcolor, title, dashed)
        out.append("</g>")
        rlo, rhi = residual_limits(residuals, hi - lo)
        panel = _Panel(out, f"r{run}{signal}{j}", *PANELS[1], y0, t0, t1, rlo, rhi,
                       "residual: predicted − measured" if top else "", xlabel)
        panel.zero()
        for (title, hexcolor, dashed, t, _, _), res in zip(curves, residuals):
            panel.curve(t, res, hexcolor, title, dashed)
        out.append(f'</g><text x="{LEGEND}" y="{y0 + 10}">{escape(joint)}</text>')
        _legend(out, LEGEND, y0 + 24, [(title, hexcolor, dashed) for title, hexcolor, dashed, *_ in curves])
    out.append("</svg>")
    return SignalFigure("".join(out), r0.run, signal, tuple(clipped))


def curves_svg(title: str, panels, xlabel: str, ylabel: str, styles: dict[str, tuple[str, bool]]) -> str:
    """Panels side by side, each (panel title, x (m,), {label: y (m,)}), with one legend on the right; styles:
    label → (colour, dashed). The axes span every curve; zero lines where 0 is inside."""
    width, height, top = 300, 160, 36
    labels = list(dict.fromkeys(label for _, _, ys in panels for label in ys))
    legend_x = 60 + width * len(panels)
    out = _open(legend_x + 20 + 8 * max((len(label) for label in labels), default=0), top + height + 36, title, title)
    for k, (name, x, ys) in enumerate(panels):
        values = np.concatenate([np.asarray(y, float) for y in ys.values()] + [np.zeros(1)])
        lo, hi = axis_limits(values, [])
        x0 = 60 + width * k
        panel = _Panel(out, f"c{k}", x0, x0 + width - 50, top, float(x[0]), float(x[-1]), lo, hi,
                       f"{name}" + (f" [{ylabel}]" if k == 0 else ""), xlabel, height)
        panel.zero()
        if x[0] < 0 < x[-1]:
            out.append(f'<line class="zero" x1="{panel.x(0.0):.1f}" x2="{panel.x(0.0):.1f}" y1="{top}" '
                       f'y2="{top + height}"/>')
        for label, y in ys.items():
            panel.curve(x, y, styles[label][0], label, styles[label][1])
        out.append("</g>")
    _legend(out, legend_x, top + 10, [(label, *styles[label]) for label in labels])
    out.append("</svg>")
    return "".join(out)


def bars_svg(title: str, panels, categories: tuple[str, ...], styles: dict[str, tuple[str, bool]]) -> str:
    """Grouped bars, one panel per (panel title, lo, hi, {label: (mean (k,), std (k,) or None)}), one group per
    category, whiskers ± std; styles: label → (colour, dashed: drawn pale with a dashed outline). Legend below."""
    width, height, top = 1120 // len(panels), 200, 36
    labels = list(dict.fromkeys(label for *_, bars in panels for label in bars))
    columns = min(len(labels), 6)
    rows = -(-len(labels) // columns)
    out = _open(width * len(panels), top + height + 40 + 14 * rows, title, title)
    w = 0.8 / max(len(labels), 1)
    for k, (name, lo, hi, bars) in enumerate(panels):
        x0 = 50 + width * k
        panel = _Panel(out, f"b{k}", x0, x0 + width - 60, top, -0.5, len(categories) - 0.5, lo, hi, name,
                       categories=categories, height=height)
        panel.zero()
        for i, label in enumerate(labels):
            if label not in bars:
                continue
            mean, std = (np.nan_to_num(np.asarray(v, float)) if v is not None else None for v in bars[label])
            stroke, pale = styles[label]
            look = f'fill="{stroke}"' + (f' fill-opacity=".45" stroke="{stroke}" stroke-dasharray="3 2"' if pale else "")
            for j, joint in enumerate(categories):
                xa, xb = panel.x(j - 0.4 + w * i), panel.x(j - 0.4 + w * (i + 1))
                ya, yb = sorted((float(panel.y(mean[j])), float(panel.y(0.0))))
                tip = f"{label}, {joint}: {mean[j]:.4g}" + ("" if std is None else f" ± {std[j]:.2g}")
                out.append(f'<rect {look} x="{xa:.1f}" y="{ya:.1f}" width="{xb - xa:.1f}" height="{yb - ya:.1f}">'
                           f'<title>{escape(tip)}</title></rect>')
                if std is not None and std[j] > 0:
                    xm, lo_y, hi_y = (xa + xb) / 2, panel.y(mean[j] - std[j]), panel.y(mean[j] + std[j])
                    out.append(f'<path stroke="#000" stroke-width=".8" d="M{xm:.1f},{lo_y:.1f}V{hi_y:.1f}'
                               f'M{xm - 2:.1f},{lo_y:.1f}h4M{xm - 2:.1f},{hi_y:.1f}h4"/>')
        out.append("</g>")
    _legend(out, 50, top + height + 34, [(label, *styles[label]) for label in labels], dy=14, columns=columns,
            dx=width * len(panels) // columns)
    out.append("</svg>")
    return "".join(out)


def score_svg(validations: dict[str, Validation]) -> str:
    """SVG: grouped bars per joint of held-out effort RMSE and NCC, and acceleration NCC (mean ± std over runs)."""
    first = next(iter(validations.values()))
    panels = []
    for key, title in (("tau_rmse", "effort RMSE [N m] (lower is better)"), ("tau_ncc", "effort NCC (higher is better)"),
                       ("a_ncc", "forward-dynamics acceleration NCC")):
        bars = {label: (val.mean(key), val.std(key) if len(val.runs) > 1 else None)
                for label, val in validations.items()}
        means = [m for m, _ in bars.values() if np.isfinite(m).any()]
        if key == "tau_rmse":
            top = max([float(np.nanmax(m + np.nan_to_num(s if s is not None else 0)))
                       for m, s in bars.values() if np.isfinite(m).any()] + [0.0])
            lo, hi = 0.0, 1.1 * top if top > 0 else 1.0
        else:
            low = min([0.0] + [float(np.nanmin(m)) for m in means])
            lo, hi = (low - 0.05 if low < 0 else 0.0), 1.0
        panels.append((title, lo, hi, bars))
    styles = {label: style(label, k) for k, label in enumerate(validations)}
    return bars_svg("held-out scores per joint", panels, tuple(first.coordinates), styles)
