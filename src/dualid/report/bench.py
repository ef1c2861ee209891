"""The benchmark's scaling plot (the only benchmark module that imports matplotlib; Agg backend).

``scaling_plot``: log-log wall time (top row) and peak memory (bottom row) against N, one column per
problem, one line per solver; runs that did not finish are listed under their panel, not drawn.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, LogLocator

from dualid.bench.runner import PROBLEMS, SOLVERS
from dualid.errors import ConfigError
from dualid.report.figures import new_figure
from dualid.report.io import write_json

LABELS = {
    "newton": "dual metric, Newton (interior point)",
    "sdp_clarabel": "dual metric, SDP (Clarabel)",
    "sdp_scs": "dual metric, SDP (SCS)",
    "ols_constrained": "constrained OLS",
}
STYLES = {
    "newton": {"color": "#d62728", "marker": "o"},
    "sdp_clarabel": {"color": "#1f77b4", "marker": "s"},
    "sdp_scs": {"color": "#9467bd", "marker": "^"},
    "ols_constrained": {"color": "#7f7f7f", "marker": "D", "linestyle": "--"},
}


def _reason(error: str) -> str:
    """The first clause of a run's error message, for a one-line note."""
    return re.split(r"[;(]", error, maxsplit=1)[0].strip()[:60]


def scaling_plot(result: dict) -> Figure:
    """Wall time and peak RSS vs N (log-log) per solver and problem from a benchmark results dict."""
    runs = result["runs"]
    problems = [p for p in PROBLEMS if any(r["problem"] == p for r in runs)]
    problems += sorted({r["problem"] for r in runs} - set(problems))
    if not problems:
        raise ConfigError("scaling_plot: the results hold no runs")
    fig, axes = new_figure(2, len(problems), figsize=(5.6 * len(problems), 7.6), sharex="col")
    for col, name in enumerate(problems):
        rows = [r for r in runs if r["problem"] == name]
        ok = [r for r in rows if "error" not in r]
        top, bottom = axes[0, col], axes[1, col]
        for solver in [s for s in SOLVERS if any(r["solver"] == s for r in ok)]:
            pts = sorted((r["N"], r["wall_time_s"], r["peak_rss_GB"]) for r in ok if r["solver"] == solver)
            N, t, mem = (np.array(x) for x in zip(*pts))
            style = {"linewidth": 1.6, "markersize": 5, **STYLES.get(solver, {})}
            top.loglog(N, t, label=LABELS.get(solver, solver), **style)
            bottom.loglog(N, mem, **style)
        dims = next(((r["n"], r["p"]) for r in ok if "n" in r), None)
        top.set_title(f"{name}" + (f" (n = {dims[0]}, p = {dims[1]})" if dims else ""))
        top.set_ylabel("wall time [s]")
        bottom.set_ylabel("peak memory (process RSS) [GB]")
        bottom.set_xlabel("samples N")
        plain = FuncFormatter(lambda y, _: f"{y:g}")
        for ax in (top, bottom):
            ax.yaxis.set_major_formatter(plain)
            ax.yaxis.set_minor_formatter(FuncFormatter(lambda y, _: ""))
            ax.grid(True, which="major", alpha=0.4)
            ax.grid(True, which="minor", alpha=0.12)
        bottom.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        failed = [r for r in rows if "error" in r]
        if failed:
            text = "not finished: " + "; ".join(
                f"{LABELS.get(r['solver'], r['solver'])} at N = {r['N']:,} ({_reason(r['error'])})"
                for r in failed
            )
            bottom.text(0.0, -0.2, text, transform=bottom.transAxes, fontsize=7.5, va="top", wrap=True)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    seen = dict(zip(labels, handles))
    for ax in axes[0, 1:]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(lab, h)
    fig.legend(list(seen.values()), list(seen), loc="lower center", ncol=len(seen), fontsize=8.5, frameon=False)
    m = result.get("machine", {})
    fig.suptitle(f"Dual-metric solvers: time and memory vs N ({m.get('cpu', 'unknown CPU')}, "
                 f"{m.get('cores', '?')} cores)", fontsize=11)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig


def to_markdown(result: dict) -> str:
    """results.md: machine, set-up, one table row per run (errors included) and any findings."""
    m = result["machine"]
    lines = [
        "# Dual-metric solver benchmark",
        "",
        f"Machine: {m['cpu']}, {m['cores']} cores, {m['memory_GB']} GB RAM; Python {m['python']}, numpy {m['numpy']}; "
        f"OPENBLAS_NUM_THREADS={m['OPENBLAS_NUM_THREADS']}; load average {m.get('load_note', 'at start')} "
        f"{tuple(round(x, 2) for x in m['load_average_at_start'])} "
        "(the machine was shared with other jobs: absolute times are pessimistic, ratios are indicative).",
        "",
        f"Random states, τ = Yθ + {int(100 * result['noise'])} % noise; up to {result['base_samples']:,} distinct samples, "
        "larger N repeat them with fresh noise. Peak memory = the run's process maximum RSS (data + solver). "
        "Objective gap: (f − f_SDP/Clarabel) / f_SDP/Clarabel (negative: lower than the SDP's).",
        "",
        "| problem | solver | N | wall time [s] | peak RSS [GB] | data [GB] | iterations | objective | gap to SDP |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in result["runs"]:
        if "error" in r:
            lines.append(f"| {r['problem']} | {r['solver']} | {r['N']:,} | error: {r['error'][:80]} | | | | | |")
            continue
        gap = r.get("objective_gap_to_sdp_clarabel")
        obj = r.get("dual_metric_objective")
        obj = float("nan") if r["solver"] == "ols_constrained" or obj is None else obj  # f of the DM solvers only
        lines.append(
            f"| {r['problem']} | {r['solver']} | {r['N']:,} | {r['wall_time_s']:.3f} | {r['peak_rss_GB']:.2f} | "
            f"{r['data_GB']:.2f} | {r['iterations'] if r['iterations'] is not None else ''} | {obj:.10g} | "
            f"{'' if gap is None else f'{gap:.2e}'} |"
        )
    if result.get("findings"):
        lines += ["", "## Findings", ""] + ([result["newton_rows_note"], ""] if result.get("newton_rows_note") else [])
        lines += [f"- {x}" for x in result["findings"]]
    return "\n".join(lines) + "\n"


def write_results(result: dict, out: Path) -> tuple[Path, Path]:
    """results.json and results.md in the directory ``out``; their paths."""
    out = Path(out)
    js, md = write_json(out / "results.json", result, indent=2), out / "results.md"
    md.write_text(to_markdown(result))
    return js, md
