"""Figures of a validation: measured vs predicted signals per run and joint beside their residuals, and
per-joint score bars.

Axes follow the measured signal: each panel's y-range is the measured range, widened to show
predictions that stay near it (at most one measured span on either side) and clipped beyond,
so a wild prediction (e.g. 1e4 rad/s² forward dynamics of a nearly singular M̂) does not flatten the
measurement into a line; ``clipped`` names the curves that left the axes, for the caption.
Every joint has its own legend with the RMSE of that joint on that run. Curves are decimated to at most
MAX_POINTS points (the PNGs are ~900 px wide) and the figures are small, so drawing stays cheap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

from dualid.estimators.methods import color as method_color
from dualid.evaluation.validation import Validation
from dualid.report.figures import new_figure

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


def style(label: str, k: int) -> dict:
    """Line style of a curve: its colour, dashed for references."""
    return {"color": color(label, k), "ls": "-" if method_color(label) else "--"}


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


def _pred(val: Validation, run: int, signal: str):
    r = val.runs[run]
    return r.tau_pred if signal == "tau" else r.a_pred


@dataclass(frozen=True, eq=False)
class SignalFigure:
    figure: Figure
    run: str
    signal: str  # "tau" or "a"
    clipped: tuple[str, ...]  # "label (joint)" of the predictions that left the axes

    @property
    def caption(self) -> str:
        stem, _, _, what = SIGNALS[self.signal]
        text = f"Held-out run {self.run}, {what}; the legend of each joint gives its RMSE on this run."
        if self.clipped:
            text += (" The axes follow the measured signal; predictions clipped (they leave the axes): "
                     + ", ".join(self.clipped) + ".")
        return text


def signal_plot(validations: dict[str, Validation], run: int, signal: str = "tau") -> SignalFigure:
    """Measured vs predicted effort ("tau") or acceleration ("a") on held-out run ``run``: one row per joint,
    left the signals, right the residuals (predicted − measured) in the same colours, with the joint's legend
    (label and that joint's RMSE on this run)."""
    first = next(iter(validations.values()))
    coords = first.coordinates
    meas_run = first.runs[run]
    stem, _, measured_label, what = SIGNALS[signal]
    fig, axes = new_figure(len(coords), 2, figsize=(11, 1.9 * len(coords) + 0.5), sharex=True,
                           gridspec_kw={"width_ratios": (1, 1)})
    measured = meas_run.tau if signal == "tau" else meas_run.a
    t, meas = decimate(np.asarray(meas_run.t), measured)
    clipped: list[str] = []
    for j, (ax, res) in enumerate(axes):
        unit = unit_of(signal, coords[j])
        ax.plot(t, meas[:, j], color="black", lw=1.0, label=measured_label)
        preds, lines, residuals = [], [], []
        for k, (label, val) in enumerate(validations.items()):
            pred = _pred(val, run, signal)
            if pred is None:
                continue
            r = val.runs[run]
            score = (r.tau_rmse if signal == "tau" else r.a_rmse)[j]
            _, p = decimate(np.asarray(r.t), pred[:, j])
            ax.plot(t, p, lw=0.8, alpha=0.9, **style(label, k))
            line, = res.plot(t, p - meas[:, j], lw=0.8, alpha=0.9, **style(label, k))
            residuals.append(p - meas[:, j])
            lines.append((line, f"{label}: RMSE {score:.3g} {unit}"))
            preds.append((label, pred[:, j]))
        lo, hi = axis_limits(measured[:, j], [p for _, p in preds])
        ax.set_ylim(lo, hi)
        res.set_ylim(*_residual_limits(residuals, hi - lo))
        clipped += [f"{label} ({coords[j]})" for label, p in preds
                    if np.nanmin(p) < lo or np.nanmax(p) > hi or not np.isfinite(p).all()]
        ax.set_ylabel(f"{coords[j]} [{unit}]", fontsize=8)
        res.axhline(0.0, color="black", lw=0.6)
        for a in (ax, res):
            a.grid(alpha=0.3)
            a.tick_params(labelsize=7)
            a.locator_params(nbins=4)  # fewer tick labels: text is most of a figure's drawing time
        res.legend([ln for ln, _ in lines], [text for _, text in lines], fontsize=7, loc="upper left",
                   bbox_to_anchor=(1.01, 1.0), frameon=False, title=coords[j], title_fontsize=7)
    axes[0, 0].set_title(f"{SIGNALS[signal][0]}: measured (black) and predicted", fontsize=8)
    axes[0, 1].set_title("residual: predicted − measured", fontsize=8)
    for a in axes[-1]:
        a.set_xlabel("time [s]", fontsize=8)
    fig.suptitle(f"held-out run {meas_run.run}: {what}", fontsize=9)
    fig.subplots_adjust(left=0.07, right=0.8, top=0.9 if len(coords) > 1 else 0.82, bottom=0.12, wspace=0.25,
                        hspace=0.25)
    return SignalFigure(fig, meas_run.run, signal, tuple(clipped))


def _residual_limits(residuals: list[np.ndarray], span: float) -> tuple[float, float]:
    """Symmetric about 0, wide enough for 99.5 % of every residual sample, at most half the signal panel's span
    (a residual beyond it belongs to a prediction the signal panel clips too)."""
    r = np.abs(np.concatenate(residuals)) if residuals else np.empty(0)
    r = r[np.isfinite(r)]
    half = min(1.1 * float(np.percentile(r, 99.5)), 0.5 * span) if r.size else 0.5 * span
    half = half if half > 0 else 0.5 * span if span > 0 else 1.0
    return -half, half


def score_bars(validations: dict[str, Validation]) -> Figure:
    """Grouped bars per joint of held-out effort RMSE and NCC, and acceleration NCC (mean ± std over runs)."""
    first = next(iter(validations.values()))
    coords = first.coordinates
    panels = (("tau_rmse", "effort RMSE [N m] (lower is better)"), ("tau_ncc", "effort NCC (higher is better)"),
              ("a_ncc", "forward-dynamics acceleration NCC"))
    fig, axes = new_figure(1, 3, figsize=(12, 3.6))
    x = np.arange(len(coords))
    w = 0.8 / len(validations)
    for ax, (key, title) in zip(axes[0], panels):
        for k, (label, val) in enumerate(validations.items()):
            yerr = np.nan_to_num(val.std(key)) if len(val.runs) > 1 else None
            ax.bar(x - 0.4 + w * (k + 0.5), np.nan_to_num(val.mean(key)), w, yerr=yerr, capsize=2,
                   color=color(label, k), label=label, error_kw={"elinewidth": 0.8},
                   hatch=None if method_color(label) else "//")
        ax.set_xticks(x)
        ax.set_xticklabels(coords)
        ax.set_title(title, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
        if key != "tau_rmse":
            lo = min([0.0] + [float(np.nanmin(v.mean(key))) for v in validations.values()
                              if np.isfinite(v.mean(key)).any()])
            ax.set_ylim(min(lo - 0.05, 0.0) if lo < 0 else 0.0, 1.0)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 8), fontsize=8, frameon=False,
               bbox_to_anchor=(0.5, 0.0))
    fig.subplots_adjust(left=0.05, right=0.99, top=0.92, bottom=0.16, wspace=0.2)
    return fig
