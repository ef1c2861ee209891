"""dm's covariance structure (sigma_structure = full / diagonal / auto) on the paper's simulated systems.

    python benchmarks/dm_structure.py --system crazyflie --out benchmarks/dm_structure_crazyflie.json
    python benchmarks/dm_structure.py --system landsalp --out benchmarks/dm_structure_landsalp.json

The study of ``dualid reproduce`` (dualid.paper: 5 data-set seeds, 5 low-data subsets each, realistic noise),
restricted to WLS and the dm variants; per case and method the mean score per coordinate, the paired
difference against WLS (mean over the pooled (data seed, subset, test run) triples) and, for the auto
variant, how often each structure was chosen. Writes JSON and prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from pathlib import Path

import numpy as np

from dualid.estimators.gls import FeasibleGLS
from dualid.estimators.methods import make_estimator
from dualid.paper.seeds import run_data_seeds

STRUCTURES = ("full", "diagonal", "auto")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--system", choices=("crazyflie", "landsalp"), required=True)
    ap.add_argument("--data-seeds", type=int, default=5)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--case", default="both")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    methods = {"wls": make_estimator("wls", allow_unidentifiable=True)}
    methods.update({f"dm-{s}": FeasibleGLS(sigma_structure=s, allow_unidentifiable=True) for s in STRUCTURES})
    t0 = time.time()
    study = run_data_seeds(a.system, a.data_seeds, case=a.case, seeds=a.seeds, methods=methods)
    coords = list(study.coordinates)
    out = {"command": f"python benchmarks/dm_structure.py --system {a.system} --data-seeds {a.data_seeds} "
                      f"--seeds {a.seeds} --case {a.case} --out {a.out}",
           "coordinates": coords, "elapsed_s": time.time() - t0, "cases": {}}
    lines = [f"| case | method | fits (failed) | {' | '.join(coords)} | mean − WLS over coordinates |",
             "| --- | --- | --- |" + " ---: |" * (len(coords) + 1)]
    for case in study.cases:
        recs = {m: {(r.data_seed, r.seed): r for r in study.records if r.case == case and r.method == m} for m in methods}
        out["cases"][case] = {}
        for m in methods:
            ok = [r for r in recs[m].values() if r.ok]
            S = np.concatenate([r.scores for r in ok]) if ok else np.full((1, len(coords)), np.nan)
            common = [k for k in recs[m] if recs[m][k].ok and recs["wls"].get(k) is not None and recs["wls"][k].ok]
            D = (np.concatenate([recs[m][k].scores - recs["wls"][k].scores for k in common])
                 if common else np.full((1, len(coords)), np.nan))
            chosen = Counter(str(r.info.get("sigma_structure")) for r in ok) if m == "dm-auto" else {}
            out["cases"][case][m] = {"n_fits": len(recs[m]), "n_failed": len(recs[m]) - len(ok),
                                     "score_mean": S.mean(0).tolist(), "diff_vs_wls_mean": D.mean(0).tolist(),
                                     "chosen": dict(chosen)}
            lines.append(f"| {case} | {m} | {len(recs[m])} ({len(recs[m]) - len(ok)}) | "
                         + " | ".join(f"{x:.3f}" for x in S.mean(0)) + f" | {np.nanmean(D):+.4f} |")
            if chosen:
                lines.append(f"| | chosen | {dict(chosen)} |" + " |" * (len(coords) + 1))
    out["table"] = "\n".join(lines)
    Path(a.out).write_text(json.dumps(out, indent=1))
    print(out["table"])
    print(f"{out['elapsed_s']:.0f} s")


if __name__ == "__main__":
    main()
