"""dm's cross-validation scores on the statistical benchmark's model-error training sets (what its choice saw).

    python benchmarks/weight_cv_scores.py --cases sensor,payload --out benchmarks/weight_cv_scores.md

For each case and seed (the same arms and training data as benchmarks/statistical_quality.py's model-error family),
fits the default ``dm`` and records its choice and the cross-validated held-out torque NRMSE of its pilot and of its
GLS fit (estimators/weight_cv.py). The clean-torque error of each choice is in that benchmark's results.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import statistical_quality as sq  # noqa: E402

from dualid.estimators.gls import FeasibleGLS  # noqa: E402
from dualid.problem import build_problem  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="sensor,payload")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    sb = sq.sb
    out = ["# dm's cross-validation on the model-error training sets", "",
           f"Command: `python benchmarks/weight_cv_scores.py {' '.join(argv if argv is not None else sys.argv[1:])}`", "",
           "| case | seed | DoF | choice | CV NRMSE pilot (WLS) | CV NRMSE GLS fit | pilot / GLS − 1 |",
           "| --- | ---: | ---: | --- | ---: | ---: | ---: |"]
    for case in args.cases.split(","):
        for seed in range(args.seeds):
            arm = sb.random_arm(np.random.default_rng([seed, 0]), 3 + seed % 5)
            kw = dict(case=case, case_seed=seed * 1000 + 7)
            runs = [sb.make_run(arm, np.random.default_rng([seed, 3, h]), sq.ME_N / 2 / sb.FS, sq.ME_NOISE,
                                payload=h == 1, name=f"train{h}", **kw) for h in range(2)]
            res = FeasibleGLS(allow_unidentifiable=True).fit(build_problem(arm.ident, [r.measured for r in runs]))
            sc = res.info["cv_score"]
            out.append(f"| {case} | {seed} | {arm.n} | {res.info['weight_choice']} | {sc['pilot']:.4f} | {sc['gls']:.4f} "
                       f"| {sc['pilot'] / sc['gls'] - 1:+.4f} |")
            print(out[-1], flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(out) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
