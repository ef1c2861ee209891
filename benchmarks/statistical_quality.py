"""Statistical-quality benchmark of dualid's estimators.

    python benchmarks/statistical_quality.py --quick          # smoke run, ~2 minutes
    python benchmarks/statistical_quality.py                  # full run (≤ ~20 minutes on 2 cores)
    python benchmarks/statistical_quality.py --methods ols,wls,dm-paper,dm

Writes benchmarks/statistical_quality/results.json and results.md (or --out DIR). Data and metrics are
defined in dualid.bench.arms (random 3–7-DoF arms simulated with Pinocchio). Two families:

- noise: torque noise 0/2/5/10 % of each joint's τ rms, N = 1e3/3e3/1e4 training samples, seeds 0..S-1
  (seed s is a random arm of 3 + s mod 5 joints); every model term is in the identification model.
- model error: 2 % noise, N = 3e3, six cases of effects the model lacks (Stribeck friction, position-
  dependent friction, cogging, torque-sensor gain and offset, a 1.5 kg payload carried in half of the
  training data, all combined); the ratio rms(unexplained torque)/rms(inertial torque) per joint is reported.

Per method and run: clean held-out torque error (NRMSE against the noise-free physical τ at the commanded
states; aggregated as rms over joints) divided by the FLOOR, and by the best of OLS/WLS on the same run;
forward-dynamics NCC on held-out runs from measured q, v, τ; the same fit after a configuration-
dependent re-chart (IdentificationProblem.in_coordinates, unit scalings 10^±2) with the relative change
of the clean torque error; solver status, time and failures (counted, never dropped).

FLOOR: the clean held-out torque error of an oracle WLS, fitted on the same training data with the
weight diag(1 / var_j), var_j the variance of the training residual at the TRUE θ (noise + differentiation
error + unmodelled torque; only the simulator knows it). It is what a perfectly informed per-joint
weighting achieves; a method may beat it (ratio < 1), it is a yardstick, not a bound.

Methods: built-ins ols, wls, dm-paper (the paper's objective, Newton solver, max_iter 300), or
[label=]module:Class[:kwargs-json] for any estimator with .fit(problem) -> IdentificationResult; when
the class accepts allow_unidentifiable it is set True unless given (serial arms' inertial parameters are
not all identifiable; predictions are). Point PYTHONPATH at another worktree's src to run its estimators.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import json
import multiprocessing as mp
import os
import platform
import sys
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

NOISE_LEVELS = (0.0, 0.02, 0.05, 0.10)
SIZES = (1000, 3000, 10000)
ME_NOISE = 0.02
ME_N = 3000
DEFAULT_METHODS = "ols,wls,dm-paper,dm"


from dualid.report.outdir import check_output_files  # noqa: E402
from dualid.bench import arms as sb  # noqa: E402


# --- methods --------------------------------------------------------------------------------------
def make_method(spec: str):
    """(label, estimator) from a key of dualid's method table ('ols', 'wls', 'dm', 'dm-paper', …) or
    '[label=]module:Class[:kwargs-json]'."""
    from dualid.estimators.methods import METHODS, make_estimator

    # the paper's objective gets 300 Newton iterations (the default stops short on some model-error fits)
    options = {"dm-paper": {"max_iter": 300}}
    if spec in METHODS:
        return spec, make_estimator(spec, allow_unidentifiable=True, options=options.get(spec))
    builtin = METHODS
    label, sep, rest = spec.partition("=")
    if not sep or ":" in label:
        label, rest = "", spec
    parts = rest.split(":", 2)
    if len(parts) < 2:
        raise ValueError(f"method {spec!r}: expected one of {sorted(builtin)} or [label=]module:Class[:kwargs-json]")
    module, cls_name = parts[0], parts[1]
    kwargs = json.loads(parts[2]) if len(parts) == 3 else {}
    if not isinstance(kwargs, dict):
        raise ValueError(f"method {spec!r}: kwargs must be a JSON object, got {parts[2]!r}")
    cls = getattr(importlib.import_module(module), cls_name)
    accepted = inspect.signature(cls).parameters
    if "allow_unidentifiable" in accepted and "allow_unidentifiable" not in kwargs:
        kwargs["allow_unidentifiable"] = True
    return label or cls_name.lower(), cls(**kwargs)


# --- one task -------------------------------------------------------------------------------------
def _fit(estimator, problem):
    """(result or None, record dict): failures are recorded with their message, never dropped."""
    t0 = time.perf_counter()
    try:
        res = estimator.fit(problem)
    except Exception as exc:  # counted as a failure of this method on this run
        return None, {"ok": False, "error": f"{type(exc).__name__}: {str(exc)[:300]}",
                      "wall_time_s": time.perf_counter() - t0}
    return res, {"ok": True, "status": str(res.status), "solver": str(res.solver), "iterations": res.iterations,
                 "wall_time_s": time.perf_counter() - t0, "objective": float(res.objective),
                 "info": {k: v for k, v in res.info.items() if isinstance(v, (int, float, str, bool))}
                 | {f"cv_score_{k}": v for k, v in res.info.get("cv_score", {}).items()}
                 | {f"cv_motion_score_{k}": v for k, v in res.info.get("cv_motion_score", {}).items()}}


class _Tests:
    """Held-out runs of one arm: θ-independent parts built once, scored per θ̂."""

    def __init__(self, arm, runs):
        from dualid.evaluation.prediction import PredictionData
        from dualid.evaluation.scores import shift_window
        self.arm = arm
        self.Y = np.concatenate([arm.ident.regressor(r.q, r.v, r.a) for r in runs])  # commanded states
        self.tau_phys = np.concatenate([r.tau_phys for r in runs])
        self.tau_model = self.Y @ arm.theta_true
        self.pred = [PredictionData.of(arm.ident, r.measured.q, r.measured.v, r.measured.tau) for r in runs]
        self.a_meas = [r.measured.a for r in runs]
        self.shift = shift_window(sb.PERIOD, 1.0 / sb.FS)
        idx = np.linspace(0, runs[0].q.shape[0] - 1, 100).astype(int)
        self.metric = arm.ident.metric(runs[0].q[idx])
        self.M_true = self.metric.evaluate(arm.theta_true)
        self.approx_floor = sb.aggregate(sb.torque_nrmse(
            self.Y, np.linalg.lstsq(self.Y.reshape(-1, self.Y.shape[2]), self.tau_phys.reshape(-1), rcond=None)[0],
            self.tau_phys))

    def score(self, theta) -> dict:
        from dualid.evaluation.scores import score_run
        per_joint = sb.torque_nrmse(self.Y, theta, self.tau_phys)
        out = {"torque_nrmse": sb.aggregate(per_joint), "torque_nrmse_joints": per_joint.tolist(),
               "param_nrmse": sb.aggregate(sb.torque_nrmse(self.Y, theta, self.tau_model))}
        try:
            ncc = [score_run(p.predict(theta), a, self.shift) for p, a in zip(self.pred, self.a_meas)]
            out["fd_ncc"] = float(np.mean(ncc))
            out["fd_ncc_joints"] = np.mean(ncc, axis=0).tolist()
        except Exception as exc:  # M̂ not positive definite somewhere: no forward dynamics
            out["fd_ncc"] = None
            out["fd_error"] = f"{type(exc).__name__}: {str(exc)[:200]}"
        try:
            lo, hi = sb.metric_eigen_range(self.metric.evaluate(theta), self.M_true)
            out["metric_eig_min"], out["metric_eig_max"] = lo, hi
        except np.linalg.LinAlgError:
            out["metric_eig_min"], out["metric_eig_max"] = None, None
        return out


def _evaluate(methods, train, tests, B, oracle) -> list[dict]:
    """Fit every method in the sensor chart and re-charted; scores against held-out runs."""
    rows = []
    other = train.in_coordinates(B)
    for label, est in [("oracle", oracle)] + methods:
        res, rec = _fit(est, train)
        row = {"method": label, **rec}
        if res is not None:
            row.update(tests.score(res.theta))
        if label != "oracle":
            res2, rec2 = _fit(est, other)
            row["rechart"] = rec2
            if res2 is not None:
                s2 = tests.score(res2.theta)
                row["rechart"].update({k: s2[k] for k in ("torque_nrmse", "fd_ncc")})
                if res is not None:
                    row["rechart"]["torque_rel_change"] = s2["torque_nrmse"] / row["torque_nrmse"] - 1
                    row["rechart"]["theta_rel_change"] = float(
                        np.linalg.norm(res2.theta - res.theta) / np.linalg.norm(res.theta))
        rows.append(row)
    return rows


def _oracle(train, arm):
    from dualid import WLS

    r = train.residual(arm.theta_true)
    return WLS(allow_unidentifiable=True, covariance=np.diag(np.maximum(r.var(axis=0), 1e-12)))


def run_task(task: dict) -> list[dict]:
    """One (seed, N) of the noise family (all noise levels) or one (seed, case) of the model-error family."""
    from dualid.problem import build_problem
    warnings.filterwarnings("ignore", message="Solution may be inaccurate")  # the status is recorded instead
    try:
        methods = [make_method(m) for m in task["methods"]]
        seed = task["seed"]
        arm = sb.random_arm(np.random.default_rng([seed, 0]), task["dof"])
        B_rng = np.random.default_rng([seed, 9])
        rows = []
        test_seconds = task["test_seconds"]
        if task["family"] == "noise":
            N = task["N"]
            for noise in task["noise_levels"]:
                runs = [sb.make_run(arm, np.random.default_rng([seed, 1, k]), test_seconds, noise, name=f"test{k}")
                        for k in range(sb.TEST_RUNS)]
                tests = _Tests(arm, runs)
                run = sb.make_run(arm, np.random.default_rng([seed, 2, N]), N / sb.FS, noise, name="train")
                train = build_problem(arm.ident, run.measured)
                B = sb.rechart(np.random.default_rng([seed, 9]), run.measured.q)
                head = {"family": "noise", "seed": seed, "dof": arm.n, "p": train.p, "N": train.N, "noise": noise,
                        "approx_floor": tests.approx_floor}
                for row in _evaluate(methods, train, tests, B, _oracle(train, arm)):
                    rows.append({**head, **row})
        else:
            case = task["case"]
            N = task["N"]
            kw = dict(case=case, case_seed=seed * 1000 + 7)
            runs = [sb.make_run(arm, np.random.default_rng([seed, 1, k]), test_seconds, ME_NOISE, name=f"test{k}", **kw)
                    for k in range(sb.TEST_RUNS)]
            tests = _Tests(arm, runs)
            train_runs = [sb.make_run(arm, np.random.default_rng([seed, 3, h]), N / 2 / sb.FS, ME_NOISE, payload=h == 1,
                                      name=f"train{h}", **kw) for h in range(2)]
            train = build_problem(arm.ident, [r.measured for r in train_runs])
            B = sb.rechart(B_rng, np.concatenate([r.measured.q for r in train_runs]))
            unexpl = np.concatenate([r.unmodelled for r in train_runs])
            inert = np.concatenate([r.inertial for r in train_runs])
            ratio = np.sqrt(np.mean(unexpl**2, axis=0) / np.mean(inert**2, axis=0))
            head = {"family": "model_error", "case": case, "seed": seed, "dof": arm.n, "p": train.p, "N": train.N,
                    "noise": ME_NOISE, "unexplained_over_inertial": ratio.tolist(), "approx_floor": tests.approx_floor}
            for row in _evaluate(methods, train, tests, B, _oracle(train, arm)):
                rows.append({**head, **row})
        return rows
    except Exception as exc:  # the whole task failed: recorded as such
        return [{**{k: v for k, v in task.items() if k != "methods"}, "method": "(task)", "ok": False,
                 "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()[-2000:]}]


# --- planning and aggregation -------------------------------------------------------------------
def plan(quick: bool, seeds: int, methods: list[str], family: str = "both") -> tuple[list[dict], dict]:
    if quick:
        cfg = {"seeds": min(seeds, 2), "sizes": [1000], "noise_levels": [0.0, 0.05], "me_cases": ["sensor", "combined"],
               "me_N": 1000, "test_seconds": 4.0}
    else:
        cfg = {"seeds": seeds, "sizes": list(SIZES), "noise_levels": list(NOISE_LEVELS),
               "me_cases": list(sb.MODEL_ERROR_CASES), "me_N": ME_N, "test_seconds": sb.TEST_SECONDS}
    tasks = []
    for seed in range(cfg["seeds"]):
        dof = 3 + seed % 5
        for N in cfg["sizes"] if family in ("both", "noise") else []:
            tasks.append({"family": "noise", "seed": seed, "dof": dof, "N": N, "noise_levels": cfg["noise_levels"],
                          "methods": methods, "test_seconds": cfg["test_seconds"]})
        for case in cfg["me_cases"] if family in ("both", "model_error") else []:
            tasks.append({"family": "model_error", "seed": seed, "dof": dof, "case": case, "N": cfg["me_N"],
                          "methods": methods, "test_seconds": cfg["test_seconds"]})
    tasks.sort(key=lambda t: -(t["N"] * (t["dof"] ** 2) * (len(t.get("noise_levels", [1])))))  # big first
    return tasks, cfg


def _ratios(rows: list[dict]) -> None:
    """Add ratio_to_floor and ratio_to_best_ls (best of ols/wls on the same run) to every fitted row."""
    groups: dict = {}
    for r in rows:
        key = (r["family"], r.get("case"), r["seed"], r["N"], r["noise"])
        groups.setdefault(key, {})[r["method"]] = r
    for g in groups.values():
        floor = g.get("oracle", {}).get("torque_nrmse")
        ls = [g[m]["torque_nrmse"] for m in ("ols", "wls") if m in g and g[m].get("ok")]
        best = min(ls) if len(ls) == 2 else None
        for r in g.values():
            if not r.get("ok") or "torque_nrmse" not in r:
                continue
            if floor:
                r["ratio_to_floor"] = r["torque_nrmse"] / floor
            if best:
                r["ratio_to_best_ls"] = r["torque_nrmse"] / best


def _fmt(xs, f="{:.3g}"):
    xs = [x for x in xs if x is not None and np.isfinite(x)]
    if not xs:
        return "–"
    return f"{f.format(float(np.median(xs)))} ({f.format(float(np.max(xs)))})"


def _fmt_min(xs):
    xs = [x for x in xs if x is not None and np.isfinite(x)]
    return "–" if not xs else f"{np.mean(xs):.3f} ({np.min(xs):.3f})"


def to_markdown(result: dict) -> str:
    rows = result["rows"]
    methods = result["methods"]
    cfg = result["config"]
    m = result["machine"]
    out = [
        "# Statistical-quality benchmark",
        "",
        f"Command: `{result['command']}`  ",
        f"Wall time {result['wall_time_s'] / 60:.1f} min with {result['workers']} worker(s) on {m['cpu']} "
        f"({m['cores']} cores, shared), numpy {m['numpy']}, Python {m['python']}.  ",
        f"dualid package: {result['provenance']['dualid_package']} at commit {result['provenance']['commit']}"
        + f"; data module {result['provenance']['data_module']}."
        + (f" Note: {result['provenance']['note']}." if result["provenance"].get("note") else ""),
        "",
        "Data: random serial arms of 3 + (seed mod 5) revolute joints (Pinocchio), true friction and armature; "
        "sum-of-sinusoids excitation (period 5 s, 5 harmonics) sampled at 200 Hz; q quantised (16-bit), v and a by "
        "Savitzky–Golay differentiation (0.1 s window); τ with Gaussian noise as a fraction of each joint's τ rms. "
        "Identification model: RigidBodyModel + viscous/Coulomb friction + armature, from CAD-like wrong inertias. "
        f"Held-out: {2} runs of {cfg['test_seconds']:g} s per arm. Every method is fitted with physical-consistency "
        "constraints and allow_unidentifiable (serial-arm inertial parameters are not all identifiable).",
        "",
        "**Clean torque error** = rms over joints of NRMSE_j = RMSE(Y θ̂ − τ_phys)_j / rms(τ_phys)_j on held-out runs, "
        "Y and τ_phys at the commanded (exact) states, τ_phys noise-free (actuator torque, without sensor "
        "offset/gain). **Floor** = the same error of an *oracle WLS* fitted on the same training data with "
        "weights 1/var_j of the residual at the true θ (known only to the simulator). "
        "**vs best LS** = error / min(OLS, WLS) on the same run (paired). **FD NCC** = forward-dynamics "
        "a = M̂⁻¹(τ − ĥ) from measured q, v, τ against measured a, max normalised cross-correlation within "
        "±T/72, mean over joints and held-out runs. **Re-chart** = the same fit on "
        "problem.in_coordinates(B(q)), B configuration-dependent with unit scalings 10^±2; reported: the relative "
        "change of the clean torque error (error evaluated in the original chart; θ is chart-free).",
        "",
        "Cells: median over seeds (max over seeds) unless said; FD NCC cells: mean (min). Failed fits are counted "
        "in the failure table; statistics are over the successful fits, and a cell missing some seeds says "
        "[successful/all] — compare such cells with care (the failed seed is often the hardest one).",
    ]

    def table(title, family_rows, key_cols, key_fn, metric, fmt=_fmt, sub=None):
        out.extend(["", f"### {title}", "", "| " + " | ".join(key_cols + methods) + " |",
                    "|" + " --- |" * len(key_cols) + " ---: |" * len(methods)])
        keys = sorted({key_fn(r) for r in family_rows}, key=lambda k: tuple(str(x).zfill(8) for x in k))
        for k in keys:
            cells = []
            for meth in methods:
                vals, total = [], 0
                for r in family_rows:
                    if key_fn(r) == k and r["method"] == meth:
                        total += 1
                        d = r.get(sub, {}) if sub else r
                        if r.get("ok") and d.get("ok", True) and d.get(metric) is not None:
                            vals.append(d.get(metric))
                cells.append(fmt(vals) + ("" if len(vals) == total else f" [{len(vals)}/{total}]"))
            out.append("| " + " | ".join([str(x) for x in k] + cells) + " |")

    def paired(title, family_rows, key_cols, key_fn, metric, base="wls"):
        """Per run: metric(method) − metric(base) on the same data set; mean ± standard error over runs, and
        how many runs the method is at least as high (k/n; within 1e-6 relative counts as a tie, i.e. as high). Failed
        fits make the pair missing (n says so)."""
        others = [m for m in methods if m != base]
        out.extend(["", f"### {title}", "", "| " + " | ".join(key_cols + [f"{m} − {base}" for m in others]) + " |",
                    "|" + " --- |" * len(key_cols) + " ---: |" * len(others)])
        runs: dict = {}
        for r in family_rows:
            if r.get("ok") and r.get(metric) is not None:
                runs.setdefault((key_fn(r), r["seed"]), {})[r["method"]] = r[metric]
        keys = sorted({k for k, _ in runs}, key=lambda k: tuple(str(x).zfill(8) for x in k))
        for k in keys:
            cells = []
            for meth in others:
                pairs = [(v[meth], v[base]) for (kk, _), v in runs.items() if kk == k and meth in v and base in v]
                d = np.array([a - b for a, b in pairs])
                if d.size == 0:
                    cells.append("–")
                    continue
                se = d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else float("nan")
                tie = 1e-6 * np.array([abs(b) for _, b in pairs])  # equal to 1e-6 (relative) counts as at least as high
                cells.append(f"{d.mean():+.4f} ± {se:.4f} ({int(np.sum(d >= -tie))}/{d.size})")
            out.append("| " + " | ".join([str(x) for x in k] + cells) + " |")

    noise = [r for r in rows if r["family"] == "noise"]
    me = [r for r in rows if r["family"] == "model_error"]
    nkey = lambda r: (f"{100 * r['noise']:g} %", r["N"])
    ckey = lambda r: (r["case"],)
    if noise:
        out += ["", "## Family 'noise' (every effect is in the model)"]
        table("Clean torque error / floor", noise, ["noise", "N"], nkey, "ratio_to_floor")
        table("Clean torque error / best of OLS, WLS (paired per run)", noise, ["noise", "N"], nkey, "ratio_to_best_ls")
        table("Clean torque error (absolute NRMSE)", noise, ["noise", "N"], nkey, "torque_nrmse")
        table("Forward-dynamics NCC, mean (min) over seeds", noise, ["noise", "N"], nkey, "fd_ncc", _fmt_min)
        paired("Forward-dynamics NCC minus WLS's, paired per run: mean ± s.e. over seeds (runs ≥ WLS / runs)", noise,
               ["noise", "N"], nkey, "fd_ncc")
        table("Re-chart: relative change of the clean torque error, median (max)", noise, ["noise", "N"], nkey,
              "torque_rel_change", lambda xs: _fmt([abs(x) for x in xs if x is not None], "{:.1e}"), sub="rechart")
        table("Metric guard: generalised eigenvalues of M(θ̂) vs M(θ_true), median of min (min of min)", noise,
              ["noise", "N"], nkey, "metric_eig_min",
              lambda xs: "–" if not [x for x in xs if x is not None] else
              f"{np.median([x for x in xs if x is not None]):.2g} ({np.min([x for x in xs if x is not None]):.2g})")
        table("Metric guard: max generalised eigenvalue, median (max)", noise, ["noise", "N"], nkey, "metric_eig_max",
              lambda xs: _fmt(xs, "{:.2g}"))
    if me:
        out += ["", f"## Family 'model error' ({100 * ME_NOISE:g} % noise, N = {cfg['me_N']})", "",
                "Unexplained torque (τ_clean − Y θ_true, incl. sensor error) over inertial torque (M(q) a incl. armature), "
                "rms per joint on the training data: largest joint, median over seeds (max over seeds); and the joints "
                "with ratio ≥ 0.5.", "", "| case | max-joint ratio | joints ≥ 0.5 (of all, summed over seeds) |",
                "| --- | ---: | ---: |"]
        for case in sorted({r["case"] for r in me}):
            rs = {r["seed"]: r["unexplained_over_inertial"] for r in me if r["case"] == case and "unexplained_over_inertial" in r}
            mx = [max(v) for v in rs.values()]
            big = sum(sum(x >= 0.5 for x in v) for v in rs.values())
            tot = sum(len(v) for v in rs.values())
            out.append(f"| {case} | {_fmt(mx, '{:.2f}')} | {big} / {tot} |")
        table("Clean torque error / floor", me, ["case"], ckey, "ratio_to_floor")
        table("Clean torque error / best of OLS, WLS (paired per run)", me, ["case"], ckey, "ratio_to_best_ls")
        table("Clean torque error (absolute NRMSE)", me, ["case"], ckey, "torque_nrmse")
        table("Forward-dynamics NCC, mean (min) over seeds", me, ["case"], ckey, "fd_ncc", _fmt_min)
        paired("Forward-dynamics NCC minus WLS's, paired per run: mean ± s.e. over seeds (runs ≥ WLS / runs)", me,
               ["case"], ckey, "fd_ncc")
        table("Re-chart: relative change of the clean torque error, median (max)", me, ["case"], ckey,
              "torque_rel_change", lambda xs: _fmt([abs(x) for x in xs if x is not None], "{:.1e}"), sub="rechart")
        table("Metric guard: min generalised eigenvalue of M(θ̂) vs M(θ_true), median (min)", me, ["case"], ckey,
              "metric_eig_min", lambda xs: "–" if not [x for x in xs if x is not None] else
              f"{np.median([x for x in xs if x is not None]):.2g} ({np.min([x for x in xs if x is not None]):.2g})")
        table("Metric guard: max generalised eigenvalue, median (max)", me, ["case"], ckey, "metric_eig_max",
              lambda xs: _fmt(xs, "{:.2g}"))
    out += ["", "## Failures and time", "", "| method | fits | failed (sensor chart) | failed (re-chart) | "
            "FD not computable | median / max fit time [s] |", "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for meth in ["oracle"] + methods:
        rs = [r for r in rows if r["method"] == meth]
        fails = sum(not r.get("ok") for r in rs)
        refails = sum(not r.get("rechart", {}).get("ok", True) for r in rs)
        fd = sum(r.get("ok") and r.get("fd_ncc") is None for r in rs)
        t = [r["wall_time_s"] for r in rs if r.get("ok")]
        out.append(f"| {meth} | {len(rs)} | {fails} | {refails if meth != 'oracle' else '–'} | {fd} | "
                   f"{np.median(t) if t else float('nan'):.2f} / {np.max(t) if t else float('nan'):.2f} |")
    errs = [r for r in rows if not r.get("ok") or not r.get("rechart", {}).get("ok", True)]
    if errs:
        out += ["", "Failure messages (first 10):", ""]
        for r in errs[:10]:
            msg = r.get("error") or r.get("rechart", {}).get("error")
            out.append(f"- {r['method']} {r['family']} seed {r['seed']} N {r.get('N')} "
                       f"{r.get('case') or ('noise ' + str(r.get('noise')))}: {msg}")
    task_fail = [r for r in rows if r["method"] == "(task)"]
    if task_fail:
        out += ["", f"**{len(task_fail)} task(s) failed as a whole** (see results.json)."]
    return "\n".join(out) + "\n"


def _provenance() -> dict:
    """Which dualid tree and commit run (taken at the start, before any fit)."""
    import dualid
    from dualid.report.metadata import git_commit

    package = Path(dualid.__file__).resolve().parent
    return {"dualid_package": str(package), "commit": git_commit(package) or "unknown",
            "data_module": str(Path(sb.__file__).resolve())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="smoke run: 2 seeds, N = 1000, 2 noise levels, 2 cases")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--family", choices=("both", "noise", "model_error"), default="both")
    ap.add_argument("--methods", default=DEFAULT_METHODS,
                    help="comma-separated: keys of the method table (ols, wls, dm, dm-paper, …) or [label=]module:Class[:kwargs-json]")
    ap.add_argument("--workers", type=int, default=2, help="processes (at most 2)")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "statistical_quality"))
    ap.add_argument("--render", metavar="RESULTS_JSON", help="only rewrite results.md next to an existing results.json")
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args(argv)
    # before the work: an existing result is not replaced without --force
    targets = ([Path(args.render).parent / "results.md"] if args.render else
               [Path(args.out) / "results.json", Path(args.out) / "results.md"])
    check_output_files(targets, args.force, ap)
    if args.render:
        path = Path(args.render)
        (path.parent / "results.md").write_text(to_markdown(json.loads(path.read_text())))
        return 0
    provenance = _provenance()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    methods = _split_methods(args.methods)
    labels = [make_method(m)[0] for m in methods]  # fail early on a bad spec
    if len(set(labels)) != len(labels) or "oracle" in labels:
        raise SystemExit(f"method labels must be distinct and not 'oracle', got {labels}")
    tasks, cfg = plan(args.quick, args.seeds, methods, args.family)
    cfg["family"] = args.family
    workers = max(1, min(2, args.workers))
    t0 = time.time()
    rows: list[dict] = []
    with mp.get_context("fork").Pool(workers) as pool:
        for k, part in enumerate(pool.imap_unordered(run_task, tasks), 1):
            rows.extend(part)
            print(f"[{time.time() - t0:6.0f} s] task {k}/{len(tasks)}: {part[0].get('family')} seed {part[0].get('seed')} "
                  f"{part[0].get('case') or ('N ' + str(part[0].get('N')))}", flush=True)
    _ratios(rows)
    from dualid.bench.runner import machine


    result = {"command": "python benchmarks/statistical_quality.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "methods": labels, "method_specs": methods, "config": cfg, "workers": workers,
              "wall_time_s": time.time() - t0, "machine": machine(), "provenance": provenance, "python": platform.python_version(), "rows": rows}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(result, indent=1, default=float))
    (out / "results.md").write_text(to_markdown(result))
    print(f"wrote {out / 'results.json'} and {out / 'results.md'} in {(time.time() - t0) / 60:.1f} min")
    return 0


def _split_methods(text: str) -> list[str]:
    """Split on commas outside JSON braces."""
    items, depth, cur = [], 0, ""
    for ch in text:
        depth += ch in "{[" and 1 or 0
        depth -= ch in "}]" and 1 or 0
        if ch == "," and depth == 0:
            items.append(cur.strip())
            cur = ""
        else:
            cur += ch
    if cur.strip():
        items.append(cur.strip())
    return items


if __name__ == "__main__":
    raise SystemExit(main())
