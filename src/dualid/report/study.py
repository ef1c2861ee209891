"""Figures and the written report of a study (the only module that imports matplotlib; Agg backend).

- ``score_bars``: the paper's Fig. 2/4 — score per coordinate, mean with std error bars; left panel
  WLS, energy, DM; right panel log-det WLS, pullback WLS, DM.
- ``trajectory_plot``: the paper's Fig. 3/5 — predicted vs measured signal of the shape coordinate
  where the methods differ most, on one test run.
- ``study_markdown``, ``study_json``: the study's tables and record.
- ``write_report``: results.json, results.md and the PNGs in an output directory; ``reproduce``:
  simulate, run the study and write its report.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from dualid.errors import ConfigError
from dualid.estimators.methods import color as method_color
from dualid.estimators.methods import label as method_label
from dualid.paper.results import StudyResult
from dualid.paper.seeds import paired_difference, run_data_seeds
from dualid.paper.study import Case
from dualid.report.figures import new_figure, save_figure
from dualid.report.io import markdown_table, to_json
from dualid.report.outdir import check_output_dir, write_output

PANELS = (("wls", "energy", "dm-paper", "dm"), ("logdet", "pullback", "dm-paper", "dm"))
TRAJECTORY_METHODS = ("dm", "dm-paper", "wls", "energy", "logdet", "pullback")
CASE_TITLES = {"low": "low-data case", "high": "high-data case"}


def _label(method: str) -> str:
    return method_label(method)


def _coord_label(result: StudyResult, c: str) -> str:
    """a:<coordinate> for accelerations, v:<coordinate> for velocities (as in results.md)."""
    return f"{'a' if result.signal == 'acceleration' else 'v'}:{c}"


def _check_case(result: StudyResult, case: str) -> None:
    if case not in result.cases:
        raise ConfigError(f"case: expected one of {list(result.cases)} (the cases of this study), got {case!r}")


def score_bars(result: StudyResult, case: str) -> Figure:
    """Grouped bars of the score per coordinate (mean ± std), two panels as in the paper."""
    _check_case(result, case)
    coords = result.coordinates
    n = len(coords)
    panels = [[m for m in panel if m in result.methods] for panel in PANELS]
    panels = [p for p in panels if p] or [list(result.methods)]
    lows = [0.0]
    for panel in panels:
        for m in panel:
            s = result.summary(case, m)
            lows.extend((s.score_mean - s.score_std)[np.isfinite(s.score_mean)].tolist())
    ymin = min(lows)
    ymin = 0.0 if ymin >= 0 else max(-1.05, np.floor(ymin * 10) / 10 - 0.05)
    width_in = min(16.0, max(8.0, 0.8 * n * len(panels) + 2))
    fig, axes = new_figure(1, len(panels), figsize=(width_in, 4.2), sharey=True)
    x = np.arange(n)
    for ax, panel in zip(axes[0], panels):
        w = 0.8 / len(panel)
        for j, m in enumerate(panel):
            s = result.summary(case, m)
            pos = x - 0.4 + w * (j + 0.5)
            mean = np.nan_to_num(s.score_mean, nan=0.0)
            ax.bar(pos, mean, w, yerr=np.nan_to_num(s.score_std), capsize=2, color=method_color(m),
                   label=_label(m) + (f" ({s.n_failed}/{s.n_fits} failed)" if s.n_failed else ""),
                   error_kw={"elinewidth": 0.8})
            for k in np.flatnonzero(~np.isfinite(s.score_mean)):
                ax.text(pos[k], 0.02, "failed", rotation=90, ha="center", va="bottom", fontsize=7)
        ax.set_xticks(x)
        ax.set_xticklabels([_coord_label(result, c) for c in coords], fontsize=9)
        for k, c in enumerate(coords):
            if c in result.shape_coordinates:
                ax.get_xticklabels()[k].set_fontweight("bold")
                ax.axvspan(k - 0.5, k + 0.5, color="0.93", zorder=0)
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_ylim(ymin, 1.05)
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, frameon=False)
    axes[0][0].set_ylabel("max normalized cross-correlation")
    fig.suptitle(f"{result.system}: predicted vs measured {result.signal}, {CASE_TITLES.get(case, case)}\n"
                 f"mean ± std over test runs{' and seeds' if case == 'low' else ''}; shaded: shape coordinates",
                 fontsize=9)
    fig.tight_layout()
    return fig


def most_contested_coordinate(result: StudyResult, case: str, methods=TRAJECTORY_METHODS) -> str:
    """The shape coordinate (or any coordinate, if none are named) where the mean scores of the methods
    spread most (max − min)."""
    _check_case(result, case)
    candidates = [c for c in result.shape_coordinates if c in result.coordinates] or list(result.coordinates)
    methods = [m for m in methods if m in result.methods]
    spread = {}
    for c in candidates:
        k = result.coordinates.index(c)
        vals = [result.summary(case, m).score_mean[k] for m in methods]
        vals = [v for v in vals if np.isfinite(v)]
        spread[c] = (max(vals) - min(vals)) if len(vals) > 1 else 0.0
    return max(candidates, key=lambda c: spread[c])


def trajectory_plot(result: StudyResult, case: str, coordinate: str | None = None,
                    methods=TRAJECTORY_METHODS, max_duration: float = 15.0) -> Figure:
    """Predicted (each method) and measured signal of one coordinate on the study's trace run; PNG at path.

    coordinate: default the shape coordinate where the methods differ most. Only the first
    max_duration seconds of the run are drawn, for legibility.
    """
    _check_case(result, case)
    if coordinate is None:
        coordinate = most_contested_coordinate(result, case, methods)
    if coordinate not in result.coordinates:
        raise ConfigError(f"coordinate: expected one of {list(result.coordinates)}, got {coordinate!r}")
    k = result.coordinates.index(coordinate)
    traces = {tr.method: tr for tr in result.traces if tr.case == case}
    if not traces:
        raise ConfigError(f"the study kept no trajectories for case {case!r}")
    first = next(iter(traces.values()))
    t = first.t - first.t[0]
    keep = t <= max_duration
    fig, axes = new_figure(figsize=(9, 4.2))
    ax = axes[0, 0]
    measured = first.measured[keep, k]
    ax.plot(t[keep], measured, color="k", lw=2.2, alpha=0.45, label="measured")
    # the axis follows the measured signal (±100 % margin): a prediction far off scale is clipped and
    # says so in its label, instead of flattening every other curve
    lo, hi = float(measured.min()), float(measured.max())
    pad = max(hi - lo, 1e-12)
    ylim = (lo - pad, hi + pad)
    failed = []
    for m in methods:
        tr = traces.get(m)
        if tr is None:
            continue
        if tr.predicted is None:
            failed.append(_label(m))
            continue
        score = _run_score(result, tr, k)
        style = {"lw": 1.8, "ls": "-", "zorder": 2} if m == "dm" else {"lw": 1.1, "ls": "--", "zorder": 3}
        pred = tr.predicted[keep, k]
        off = " — off scale, peak {:.3g}".format(pred[np.argmax(np.abs(pred))]) if (pred.min() < ylim[0] or pred.max() > ylim[1]) else ""
        ax.plot(t[keep], pred, color=method_color(m), label=f"{_label(m)} (score {score:.3f} on this run{off})", **style)
    unit = "acceleration" if result.signal == "acceleration" else "velocity"
    ax.set_ylim(*ylim)
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{_coord_label(result, coordinate)}")
    title = f"{result.system}: {coordinate} {unit} on test run {first.run!r}, {CASE_TITLES.get(case, case)}"
    if failed:
        title += f" — failed: {', '.join(failed)}"
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.2), frameon=False)
    fig.tight_layout()
    return fig


def _run_score(result: StudyResult, trace, k: int) -> float:
    """The score of coordinate k on the trace's run, from the fit the trace came from (first seed)."""
    j = result.test_runs.index(trace.run)
    if trace.method == "truth":
        recs = []
    else:
        recs = [r for r in result.records if r.case == trace.case and r.method == trace.method and r.ok]
    if not recs:
        return float("nan")
    return float(recs[0].scores[j, k])  # records are in seed order; traces keep the first seed


def study_markdown(self: StudyResult, reference: str = "wls") -> str:
    """The study's tables (scores, RMSEs, paired differences against ``reference``, the truth row,
    failed fits) as Markdown."""
    c = self.coordinates
    data_seeds = self.config.get("data_seeds", [self.config.get("system_seed", 0)])
    sym = "a" if self.signal == "acceleration" else "v"
    lines = [
        f"# {self.system}: identification study",
        "",
        f"Predicted forward dynamics ({self.signal}s, {self.kind}-dominated) on {len(self.test_runs)} test runs. "
        f"Score: max normalized cross-correlation within ±{self.config.get('max_shift')} samples "
        f"(±T/72 of the slowest period {self.config.get('slowest_period')} s); mean ± std over test runs"
        + (" and low-data subsets" if "low" in self.cases else "")
        + (f" and {len(data_seeds)} simulated data sets (seeds {data_seeds})" if len(data_seeds) > 1 else "")
        + ", over the successful fits (the 'failed' column counts the others). Shape coordinates: "
        + ", ".join(self.shape_coordinates) + ".",
    ]
    for d in self.config.get("descriptions", [])[:1] or [self.config.get("description", "")]:
        lines += ["", f"System: {d}."] if d else []
    if self.config.get("ablation") is not None:
        lines += ["", f"Ablation: fitted in a re-charted problem, B = diag({self.config['ablation_B_diag']})."]
    for case in self.cases:
        title = {"low": f"Low-data case ({self.config.get('low_data_samples')} samples, "
                        f"{len(self.config.get('seeds') or [])} seeds)", "high": "High-data case (all samples)"}[case]
        lines += ["", f"## {title}", "", "### Score (higher is better, max 1)", ""]
        lines += markdown_table(["method"] + [f"{sym}:{x}" for x in c] + ["failed", "degenerate metric"],
                        [[method_label(s.method)] + [_pm(m, d, 3) for m, d in zip(s.score_mean, s.score_std)]
                         + [f"{s.n_failed}/{s.n_fits}", _degenerate(self, case, s.method)]
                         for s in self.summaries if s.case == case])
        lines += ["", "### RMSE per coordinate (signal units) and chart-invariant RMSE √(mean eᵀMe)", ""]
        lines += markdown_table(["method"] + [f"{sym}:{x}" for x in c] + ["√(eᵀMe)"],
                        [[method_label(s.method)] + [_pm(m, d, 3, "g") for m, d in zip(s.rmse_mean, s.rmse_std)]
                         + [_pm(s.metric_rmse_mean, s.metric_rmse_std, 3, "g")] for s in self.summaries if s.case == case])
        if reference in self.methods:
            lines += _paired_section(self, case, reference, sym)
    t = self.truth
    lines += ["", "## Reference: the true parameters", ""]
    lines += markdown_table(["", *[f"{sym}:{x}" for x in c], "√(eᵀMe)"],
                    [["score"] + [_pm(m, d, 3) for m, d in zip(t.score_mean, t.score_std)] + [""],
                     ["RMSE"] + [_pm(m, d, 3, "g") for m, d in zip(t.rmse_mean, t.rmse_std)]
                     + [_pm(t.metric_rmse_mean, t.metric_rmse_std, 3, "g")]])
    failed = self.failures()
    if failed:
        lines += ["", "## Failed fits", ""]
        for r in failed:
            seed = f", subset seed {r.seed}" if r.seed is not None else ""
            lines.append(f"- {r.case}, {method_label(r.method)}, data set {r.data_seed}{seed}: {r.error}")
    return "\n".join(lines) + "\n"




def _pm(m: float, d: float, digits: int, fmt: str = "f") -> str:
    if not np.isfinite(m):
        return "failed"
    return f"{m:.{digits}{fmt}} ± {d:.{digits}{fmt}}" if fmt == "f" else f"{m:.{digits}g} ± {d:.{digits - 1}g}"


def _degenerate(result: StudyResult, case: str, method: str) -> str:
    """'k/n' successful fits whose identified metric left [1/c, c] of the prior's (the metric guard)."""
    recs = [r for r in result.records if r.case == case and r.method == method and r.ok]
    flagged = sum(bool(r.info.get("degenerate", False)) for r in recs)
    worst = min((r.info.get("metric_ratio_min", float("nan")) for r in recs), default=float("nan"))
    return f"{flagged}/{len(recs)}" + (f" (min λ {worst:.1e})" if flagged else "")


def _paired_section(result: StudyResult, case: str, reference: str, sym: str) -> list[str]:
    rows = []
    for m in result.methods:
        if m == reference:
            continue
        d = paired_difference(result, case, m, reference)
        if d.n_pairs == 0:
            rows.append([method_label(m)] + ["—"] * len(result.coordinates) + ["0"])
            continue
        rows.append([method_label(m)] + [f"{mu:+.3f} ± {sd:.3f} ({w}/{d.n_pairs})" for mu, sd, w in
                                         zip(d.mean, d.std, d.wins)] + [str(d.n_pairs)])
    return ["", f"### Paired score difference against {method_label(reference)} (method − {method_label(reference)}; "
                "mean ± std over the same data set, subset and test run; in brackets: how often the method is ahead)",
            ""] + markdown_table(["method"] + [f"{sym}:{x}" for x in result.coordinates] + ["pairs"], rows)


def study_json(result: StudyResult) -> str:
    return to_json(result.as_dict(), indent=2)


def _write_study(result: StudyResult, out: Path) -> dict[str, Path]:
    written = {"json": out / "results.json", "markdown": out / "results.md"}
    written["json"].write_text(study_json(result) + "\n")
    figures = []
    for case in result.cases:
        bars = save_figure(score_bars(result, case), out / f"score_bars_{case}.png", dpi=150)
        traj = save_figure(trajectory_plot(result, case), out / f"trajectory_{case}.png", dpi=150)
        written[f"score_bars_{case}"], written[f"trajectory_{case}"] = bars, traj
        figures += [f"![scores, {case}]({bars.name})", f"![trajectory, {case}]({traj.name})"]
    written["markdown"].write_text(study_markdown(result) + "\n## Figures\n\n" + "\n\n".join(figures) + "\n")
    return written


def write_report(result: StudyResult, out_dir: str | Path, overwrite: bool = False) -> dict[str, Path]:
    """results.json, results.md, score_bars_<case>.png and trajectory_<case>.png in out_dir
    (under the output-directory policy of dualid.report.outdir; overwrite = --force)."""
    return write_output(out_dir, overwrite, lambda d: _write_study(result, d))


def reproduce(system_name: str, out_dir: str | Path, case: Case = "both", seeds: int = 5, noise: str = "realistic",
              size: str = "default", ablation: None | str | np.ndarray = None, overwrite: bool = False,
              progress=None, data_seeds: int = 5, workers: int = 1, **system_options) -> StudyResult:
    """Simulate the named system on ``data_seeds`` data sets (``workers`` processes at once), run the study on
    each, pool them and write the report to out_dir."""
    check_output_dir(out_dir, overwrite)  # fail before the (long) study, not after
    result = run_data_seeds(system_name, data_seeds, case, seeds, noise, size, ablation, progress=progress,
                            workers=workers, **system_options)
    write_report(result, out_dir, overwrite=overwrite)
    return result
