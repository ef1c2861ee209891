"""What the figures of a validation share: the signals' names and units, the curves' colours and styles, the axes
of a signal panel and of its residuals.

Axes follow the measured signal: each panel's y-range is the measured range, widened to show predictions that stay
near it (at most one measured span on either side) and clipped beyond, so a wild prediction (e.g. 1e4 rad/s²
forward dynamics of a nearly singular M̂) does not flatten the measurement into a line. The signal figures
themselves are ``report.svgplot``'s.
"""

from __future__ import annotations

import numpy as np

from dualid.estimators.methods import color as method_color

SIGNALS = {
    "tau": ("effort", "N m", "measured", "effort: inverse dynamics Y(q,v,a)θ̂"),
    "a": ("acceleration", "rad/s²", "differentiated (measured q)", "acceleration: forward dynamics M̂⁻¹(τ−ĥ)"),
}
LINEAR_BASE = ("vx", "vy", "vz")  # a free-flyer's translational coordinates (data.lie.BASE_COORDINATES[:3])
WIDEN = 1.0  # predictions may widen the axes by this fraction of the measured span on either side
MARGIN = 0.05  # blank margin, fraction of the axis span
MAX_POINTS = 600  # points per drawn curve
REFERENCE_COLORS = ("#555555", "#bcbd22", "#393b79", "#8c6d31")  # labels outside the method table (dashed); no method's


def unit_of(signal: str, coordinate: str) -> str:
    """The unit of ``signal`` on ``coordinate``: force and linear acceleration on a floating base's
    translational coordinates, torque and angular acceleration elsewhere."""
    if coordinate in LINEAR_BASE:
        return "N" if signal == "tau" else "m/s²"
    return SIGNALS[signal][1]


def color(label: str, k: int):
    """The method's colour from the method table; a reference (any other label) one of REFERENCE_COLORS."""
    return method_color(label) or REFERENCE_COLORS[k % len(REFERENCE_COLORS)]


def style(label: str, k: int) -> tuple[str, bool]:
    """(colour, dashed) of a curve: its colour, dashed for references."""
    return color(label, k), not method_color(label)


def decimate(t: np.ndarray, *ys: np.ndarray) -> tuple[np.ndarray, ...]:
    """Every k-th sample so that at most MAX_POINTS remain (enough for a ~900 px wide panel)."""
    step = max(1, int(np.ceil(len(t) / MAX_POINTS)))
    return (t[::step], *(y[::step] for y in ys))


def axis_limits(measured: np.ndarray, predicted: list[np.ndarray]) -> tuple[float, float]:
    """The y-range of one panel: the measured range, widened by the predictions up to WIDEN × its span
    on either side, plus a MARGIN (see the module docstring)."""
    m = np.asarray(measured, dtype=float)
    m = m[np.isfinite(m)]
    lo, hi = (float(m.min()), float(m.max())) if m.size else (-1.0, 1.0)
    span = hi - lo if hi > lo else max(abs(hi), 1.0) * 0.2
    p = np.concatenate([np.asarray(x, dtype=float).ravel() for x in predicted]) if predicted else np.empty(0)
    p = p[np.isfinite(p)]
    if p.size:
        lo = max(min(lo, float(p.min())), lo - WIDEN * span)
        hi = min(max(hi, float(p.max())), hi + WIDEN * span)
    if hi <= lo:
        lo, hi = lo - 0.1 * span, hi + 0.1 * span
    pad = MARGIN * (hi - lo)
    return lo - pad, hi + pad


def residual_limits(residuals: list[np.ndarray], span: float) -> tuple[float, float]:
    """Symmetric about 0, wide enough for 99.5 % of every residual sample, at most half the signal panel's span
    (a residual beyond it belongs to a prediction the signal panel clips too)."""
    r = np.abs(np.concatenate(residuals)) if residuals else np.empty(0)
    r = r[np.isfinite(r)]
    half = min(1.1 * float(np.percentile(r, 99.5)), 0.5 * span) if r.size else 0.5 * span
    half = half if half > 0 else 0.5 * span if span > 0 else 1.0
    return -half, half
