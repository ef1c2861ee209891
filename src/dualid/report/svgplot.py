"""Interactive signal plots for the HTML report without JavaScript: inline SVG, one panel per joint,
each curve a polyline whose <title> (the browser's tooltip) names the model and its RMSE on that
joint and run; hovering a curve thickens it (CSS). Curves are decimated to at most MAX_POINTS points
and drawn in the y-range of ``signals.axis_limits`` (the measured signal's), clipped beyond it.
"""

from __future__ import annotations

from html import escape

import numpy as np
from matplotlib.colors import to_hex

from dualid.evaluation.validation import Validation
from dualid.report.signals import SIGNALS, axis_limits, color

MAX_POINTS = 400
W, H, LEFT, RIGHT, TOP, BOTTOM = 900, 170, 60, 10, 18, 22  # one panel, [px]


def _decimate(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    step = max(1, int(np.ceil(len(t) / MAX_POINTS)))
    return t[::step], y[::step]


def _points(t, y, t0, t1, lo, hi) -> str:
    t, y = _decimate(np.asarray(t, float), np.asarray(y, float))
    ok = np.isfinite(y)
    x = LEFT + (t[ok] - t0) / max(t1 - t0, 1e-12) * (W - LEFT - RIGHT)
    yy = TOP + (hi - np.clip(y[ok], lo - (hi - lo), hi + (hi - lo))) / (hi - lo) * (H - TOP - BOTTOM)
    return " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(x, yy))


def _ticks(lo: float, hi: float) -> list[float]:
    step = 10 ** np.floor(np.log10((hi - lo) / 4))
    for m in (1, 2, 5, 10):
        if (hi - lo) / (m * step) <= 5:
            step *= m
            break
    return list(np.arange(np.ceil(lo / step) * step, hi, step))


def signal_svg(validations: dict[str, Validation], run: int, signal: str = "tau") -> str:
    """The SVG markup (escaped) of one held-out run's measured and predicted ``signal`` per joint."""
    first = next(iter(validations.values()))
    r0 = first.runs[run]
    _, unit, measured_label, _ = SIGNALS[signal]
    measured = r0.tau if signal == "tau" else r0.a
    t0, t1 = float(r0.t[0]), float(r0.t[-1])
    n = len(first.coordinates)
    out = [f'<svg class="signals" xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {W} {H * n}" '
           f'width="100%" role="img" aria-label="{escape(r0.run)} {signal}">']
    for j, joint in enumerate(first.coordinates):
        curves = []
        for k, (label, val) in enumerate(validations.items()):
            r = val.runs[run]
            pred = r.tau_pred if signal == "tau" else r.a_pred
            if pred is not None:
                score = (r.tau_rmse if signal == "tau" else r.a_rmse)[j]
                curves.append((f"{label}: RMSE {score:.3g} {unit}", to_hex(color(label, k)), r.t, pred[:, j]))
        lo, hi = axis_limits(measured[:, j], [c[3] for c in curves])
        out.append(f'<g transform="translate(0 {H * j})"><clipPath id="c{run}{signal}{j}">'
                   f'<rect x="{LEFT}" y="{TOP}" width="{W - LEFT - RIGHT}" height="{H - TOP - BOTTOM}"/></clipPath>'
                   f'<rect class="frame" x="{LEFT}" y="{TOP}" width="{W - LEFT - RIGHT}" height="{H - TOP - BOTTOM}"/>'
                   f'<text x="{LEFT}" y="12">{escape(joint)} [{escape(unit)}] '
                   '(hover a curve for its model and RMSE)</text>')
        for v in _ticks(lo, hi):
            y = TOP + (hi - v) / (hi - lo) * (H - TOP - BOTTOM)
            out.append(f'<text class="tick" x="{LEFT - 4}" y="{y + 3:.1f}">{v:.3g}</text>')
        out.append(f'<g clip-path="url(#c{run}{signal}{j})">')
        for title, hexcolor, t, y in [(measured_label, "#000000", r0.t, measured[:, j])] + curves:
            out.append(f'<polyline stroke="{hexcolor}" points="{_points(t, y, t0, t1, lo, hi)}">'
                       f'<title>{escape(title)}</title></polyline>')
        out.append("</g></g>")
    out.append(f'<text x="{W - RIGHT}" y="{H * n - 4}" class="tick">time {t0:.3g}–{t1:.3g} s</text></svg>')
    return "".join(out)
