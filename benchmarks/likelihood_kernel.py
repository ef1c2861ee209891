"""dm's fit time with the (Σ, κ) likelihood's batched inverse by numpy's LAPACK calls (np.linalg.cholesky + inv, up
to session 7) and by ``covariance_model.spd_inverse`` (session 8), side by side in one run, on the statistical
benchmark's combined model-error arms (3–7 DoF, N = 3,000), and how far the two fits are apart.

    OPENBLAS_NUM_THREADS=1 python benchmarks/likelihood_kernel.py --out benchmarks/likelihood_kernel.md
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import dualid.estimators.covariance_model as cm
from dualid.bench import arms as sb
from dualid.estimators.gls import FeasibleGLS
from dualid.problem import build_problem


def lapack_nll(C, r):
    """Session 7's kernel: np.linalg.cholesky for log det, np.linalg.inv for C⁻¹."""
    try:
        L = np.linalg.cholesky(C)
    except np.linalg.LinAlgError:
        return None
    logdet = 2.0 * np.sum(np.log(np.diagonal(L, axis1=1, axis2=2)), axis=1)
    Ci = np.linalg.inv(C)
    w = np.einsum("nab,nb->na", Ci, r)
    return float(np.mean(logdet + np.einsum("na,na->n", r, w))), Ci - w[:, :, None] * w[:, None, :]


def arm_problem(seed: int, N: int = 3000):
    arm = sb.random_arm(np.random.default_rng([seed, 0]), 3 + seed % 5)
    kw = dict(case="combined", case_seed=seed * 1000 + 7)
    runs = [sb.make_run(arm, np.random.default_rng([seed, 3, h]), N / 2 / sb.FS, 0.02, payload=h == 1,
                        name=f"t{h}", **kw) for h in range(2)]
    return arm, build_problem(arm.ident, [r.measured for r in runs])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    if args.out.exists():
        raise SystemExit(f"{args.out} exists; remove it first")
    kernels = {"lapack (session 7)": lapack_nll, "spd_inverse (session 8)": cm._gaussian_nll}
    est = FeasibleGLS(allow_unidentifiable=True)
    lines = ["| arm (DoF) | " + " | ".join(f"dm, {k} [s]" for k in kernels) + " | speed-up | ‖Δθ‖/‖θ‖ | same choice |",
             "| --- | " + " | ".join("---" for _ in kernels) + " | --- | --- | --- |"]
    for seed in args.seeds:
        arm, problem = arm_problem(seed)
        times, fits = {}, {}
        for _ in range(args.repeats):  # interleaved, best of the repeats
            for name, kernel in kernels.items():
                cm._gaussian_nll = kernel
                t0 = time.perf_counter()
                fits[name] = est.fit(problem)
                times[name] = min(times.get(name, np.inf), time.perf_counter() - t0)
        a, b = (fits[k] for k in kernels)
        t = [times[k] for k in kernels]
        lines.append(f"| seed {seed} ({problem.n}) | " + " | ".join(f"{x:.2f}" for x in t) + f" | {t[0] / t[1]:.2f}× | "
                     f"{np.linalg.norm(a.theta - b.theta) / np.linalg.norm(a.theta):.1e} | "
                     f"{a.info['weight_choice'] == b.info['weight_choice']} |")
        print(lines[-1], flush=True)
    cm._gaussian_nll = kernels["spd_inverse (session 8)"]
    head = ["# dm with the likelihood's two kernels\n",
            f"`OPENBLAS_NUM_THREADS=1 python benchmarks/likelihood_kernel.py --out {args.out}` (best of {args.repeats}, "
            "interleaved; the statistical benchmark's combined model-error arms, N = 3,000)\n"]
    args.out.write_text("\n".join(head + lines) + "\n")


if __name__ == "__main__":
    main()
