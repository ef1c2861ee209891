"""Every train/test split of the DFKI double-pendulum logs: how the methods rank on held-out torque.

    python benchmarks/dfki_splits.py                      # 15 splits × 4 methods, about 1–2 minutes
    python benchmarks/dfki_splits.py --methods ols,wls,dm,dm-paper,energy --out benchmarks/dfki_splits

The example (examples/dfki/fit.yaml) trains on runs 00–03 and validates on 04–05: one split, two held-out
runs, so a difference of 0.002 N m between two methods is a tenth of the run-to-run spread and cannot rank
them. Here every choice of 4 training runs out of the 6 logs (15 splits, each with the 2 others held out) is
fitted by every method with the example's model and preprocessing (joint friction and armature, Savitzky–Golay
v and a over 0.1 s, τ low-passed at 10 Hz, 100 Hz), and the held-out torque RMSE of each joint is compared
per split (paired): mean difference ± standard error, and on how many splits a method is at least as good as
WLS. Results: results.md and results.json in --out.
"""

from __future__ import annotations

import argparse
import itertools
import json
import re
import sys
import time
from pathlib import Path

import numpy as np

from dualid.report.outdir import check_output_files
import dualid

HERE = Path(__file__).resolve().parent
DATA = HERE.parent / "examples" / "dfki" / "data"
COLUMNS = {"time": "time", "joints": {
    "Joint1": {"position": "pos_meas1", "velocity": "vel_meas1", "effort": "tau_meas1"},
    "Joint2": {"position": "pos_meas2", "velocity": "vel_meas2", "effort": "tau_meas2"}}}
STEPS = [{"resample": {"rate": 500}}, {"differentiate": {"method": "savgol", "window": 0.1, "velocity": True}},
         {"filter_lowpass": {"cutoff": 10, "fields": ["tau"]}}, {"downsample": {"factor": 5}}]
RUNS = [f"trajectory_0{k}" for k in range(6)]


def make(spec: str):
    """(label, estimator): a key of dualid's method table, optionally with constructor options as JSON
    (label=key:{"option": value}), or label=module:Class[:json] for an estimator under study."""
    import importlib

    label, sep, rest = spec.partition("=")
    rest = rest if sep else spec
    key, _, tail = rest.partition(":")
    from dualid.estimators.methods import METHODS

    if key not in METHODS:  # module:Class[:json]
        cls_name, _, kw = tail.partition(":")
        est = getattr(importlib.import_module(key), cls_name)(allow_unidentifiable=True, **(json.loads(kw) if kw else {}))
        return label if sep else cls_name.lower(), est
    return label if sep else key, dualid.make_estimator(key, allow_unidentifiable=True,
                                                        options=json.loads(tail) if tail else None)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default="ols,wls,dm,dm-paper")
    ap.add_argument("--out", type=Path, default=HERE / "dfki_splits")
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args(argv)
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out / "results.json", args.out / "results.md"], args.force, ap)
    methods = [make(s) for s in re.split(r",(?![^{]*})", args.methods)]  # commas inside {…} belong to the JSON
    rigid = dualid.RigidBodyModel.from_urdf(DATA / "pendubot_model_2.1.urdf")
    model = dualid.with_joint_terms(rigid, viscous=True, coulomb=True, coulomb_velocity=0.01, armature=True)
    logs = {n: dualid.preprocess(dualid.load_log(DATA / f"{n}.csv", COLUMNS, tuple(rigid.coordinates)), STEPS)
            for n in RUNS}
    rows, t0 = [], time.perf_counter()
    for train in itertools.combinations(RUNS, 4):
        test = [n for n in RUNS if n not in train]
        problem = dualid.build_problem(model, [logs[n] for n in train])
        for label, est in methods:
            try:
                res = est.fit(problem)
            except dualid.DualidError as exc:  # counted, never dropped
                rows.append({"train": list(train), "method": label, "ok": False, "error": str(exc)[:300]})
                continue
            v = dualid.validate(model, res.theta, [logs[n] for n in test], label=label)
            nrmse = [float(np.sqrt(np.mean((r.tau_rmse / np.sqrt(np.mean(r.tau**2, axis=0))) ** 2))) for r in v.runs]
            rows.append({"train": list(train), "method": label, "ok": True, "status": str(res.status),
                         "tau_rmse": np.asarray(v.mean("tau_rmse")).tolist(), "tau_nrmse": float(np.mean(nrmse)),
                         "a_ncc": float(np.mean(v.mean("a_ncc"))),
                         "noise_choice": None if res.noise is None else res.noise.choice})
        print(f"{'+'.join(k[-2:] for k in train)} done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    result = {"command": "python benchmarks/dfki_splits.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "methods": [m for m, _ in methods], "joints": list(rigid.coordinates), "rows": rows,
              "wall_time_s": time.perf_counter() - t0}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(result, indent=1))
    (args.out / "results.md").write_text(to_markdown(result))
    print((args.out / "results.md").read_text())
    return 0


def _paired(d: np.ndarray, ref: np.ndarray, better) -> str:
    """mean ± standard error of per-split differences d = method − WLS (ref: WLS's values), and on how many splits the
    method is at least as good (a difference within 1e-6 of WLS's value counts as a tie, i.e. as good)."""
    if d.size < 2:
        return "–"
    good = better(d) | (np.abs(d) <= 1e-6 * np.abs(ref))
    return f"{d.mean():+.4f} ± {d.std(ddof=1) / np.sqrt(d.size):.4f} ({int(np.sum(good))}/{d.size})"


def to_markdown(result: dict) -> str:
    methods, joints, rows = result["methods"], result["joints"], result["rows"]
    splits = sorted({tuple(r["train"]) for r in rows})
    ok = {(tuple(r["train"]), r["method"]): r for r in rows if r["ok"]}
    scores = [(f"{j} RMSE [N m]", lambda r, j=j: r["tau_rmse"][j], lambda d: d <= 0) for j in range(len(joints))]
    scores = [(f"{joints[j]} RMSE [N m]", f, b) for j, (_, f, b) in enumerate(scores)]
    scores += [("τ NRMSE, rms over joints", lambda r: r["tau_nrmse"], lambda d: d <= 0),
               ("FD acceleration NCC, mean over joints", lambda r: r["a_ncc"], lambda d: d >= 0)]
    out = ["# DFKI double pendulum: every 4-of-6 train/test split", "",
           f"Command: `{result['command']}` ({result['wall_time_s']:.0f} s). {len(splits)} splits; each trains on "
           "4 runs and validates on the other 2 (scores are means over the 2 held-out runs). NRMSE_j = RMSE_j / "
           "rms(τ_j) of the held-out run, as in the statistical benchmark. Differences are paired per split against "
           "WLS: mean ± standard error over splits, and (in brackets) the splits where the method is at least as good "
           "as WLS (lower RMSE, higher NCC).", "",
           "| method | failed | " + " | ".join(f"{name}: mean" for name, _, _ in scores) + " | "
           + " | ".join(f"{name}: − WLS" for name, _, _ in scores) + " |",
           "| --- | ---: |" + " ---: |" * (2 * len(scores))]
    for m in methods:
        fails = sum(1 for r in rows if r["method"] == m and not r["ok"])
        mine = [ok[(s, m)] for s in splits if (s, m) in ok]
        cells = [f"{np.mean([f(r) for r in mine]):.4f}" if mine else "–" for _, f, _ in scores]
        for _, f, better in scores:
            both = [s for s in splits if (s, m) in ok and (s, "wls") in ok]
            ref = np.array([f(ok[(s, "wls")]) for s in both])
            d = np.array([f(ok[(s, m)]) for s in both]) - ref
            cells.append("–" if m == "wls" else _paired(d, ref, better))
        out.append(f"| {m} | {fails} | " + " | ".join(cells) + " |")
    chosen = [r["noise_choice"] for r in rows if r["ok"] and r.get("noise_choice")]
    if chosen:
        kept = sum(c == "noise model" for c in chosen)
        rest = sorted({c.split(":")[0] for c in chosen if c != "noise model"})
        out += ["", f"`dm` kept its noise-model fit on {kept} of {len(chosen)} splits and returned "
                f"{' or '.join(rest) or 'nothing else'} (its noise check found a residual that is not the modelled "
                "noise) on the others."]
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
