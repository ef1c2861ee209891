"""Does the default ``dualid fit`` finish on a real-arm-like case, and do the model files it writes make physical sense?

The simulated Franka Panda of ``dualid.bench.urdf_arm`` (example-robot-data's URDF as the truth, friction, near-zero
armature, 2 % torque noise, 16-bit encoders; the URDF given to the fit is a CAD-like prior 0.7–1.3× the truth per
link), two training runs and one held-out run per seed, fitted exactly as ``dualid fit --model panda.urdf --data
run0.npz --data run1.npz --test run2.npz --out DIR`` does (default config: ols and dm, sandwich uncertainty,
plausible parameters in the 0.95 region). Per seed and method: exit status, total moving mass / the prior's, the
worst link mass ratio among those the prior determines, held-out τ RMSE of the written model / the raw fit's, and
the plausible step's share of the command's wall time (stages timed through fit_robot's progress callback, the
files written by ``write_fit``).

    PYTHONPATH=src python benchmarks/real_arm.py --seeds 3 --seconds 10 --out benchmarks/real_arm.json
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from dualid.report.outdir import check_output_files
from dualid.bench.urdf_arm import arm_runs, arm_urdf, example_robot_urdf, log_arrays, prior_urdf, urdf_arm
from dualid.model.rigid_body import RigidBodyModel
from dualid.report.robot import write_fit
from dualid.robot.config import FitConfig
from dualid.robot.fit import fit_robot


def one_seed(seed: int, seconds: float, folder: Path) -> dict:
    rng = np.random.default_rng(seed)
    truth = arm_urdf(example_robot_urdf())
    prior = prior_urdf(truth, rng)
    (folder / "panda.urdf").write_text(prior)
    arm = urdf_arm(truth, prior, rng)
    logs = []
    for k, run in enumerate(arm_runs(arm, truth, rng, 3, seconds)):
        np.savez(folder / f"run{k}.npz", **log_arrays(run))
        logs.append(str(folder / f"run{k}.npz"))
    cfg = FitConfig.from_dict({"model": {"urdf": str(folder / "panda.urdf")}, "train": logs[:2], "test": logs[2:],
                               "out": str(folder / "out")})
    stages: list[tuple[str, float]] = []
    t0 = time.perf_counter()

    def progress(message: str) -> None:
        stages.append((message, time.perf_counter()))

    outcome = fit_robot(cfg, progress)
    progress("writing")
    write_fit(outcome, folder / "out")
    total = time.perf_counter() - t0
    stages.append(("end", time.perf_counter()))
    plausible_time = sum(b[1] - a[1] for a, b in zip(stages[:-1], stages[1:]) if "plausible parameters" in a[0])
    prior_masses = RigidBodyModel.from_urdf(folder / "panda.urdf").nominal[::10]
    masses_idx = np.arange(0, prior_masses.size * 10, 10)
    out = {"seed": seed, "seconds_per_run": seconds, "samples": outcome.problem.N, "command_s": total,
           "plausible_s": plausible_time, "plausible_share": plausible_time / total,
           "warnings": list(outcome.warnings), "methods": {}}
    for m, f in outcome.fits.items():
        entry: dict = {"ok": f.ok, "error": f.error, "plausible_error": f.plausible_error}
        if f.ok and f.plausible is not None:
            p = f.plausible
            masses = p.theta[masses_idx]
            by_prior = [k for k, i in enumerate(masses_idx) if p.determined_by[i] == "prior"]
            ratios = masses / prior_masses
            raw = float(np.mean(f.validation.mean("tau_rmse")))
            written = float(np.mean(f.plausible_validation.mean("tau_rmse")))
            entry.update(total_mass_ratio=float(masses.sum() / prior_masses.sum()),
                         raw_total_mass_ratio=float(f.result.theta[masses_idx].sum() / prior_masses.sum()),
                         raw_max_mass_ratio=float(np.max(f.result.theta[masses_idx] / prior_masses)),
                         mass_ratios=ratios.tolist(), masses_by_prior=by_prior,
                         by_prior_ratio_range=[float(ratios[by_prior].min()), float(ratios[by_prior].max())]
                         if by_prior else None,
                         held_out_ratio=written / raw, statistic=p.statistic, radius2=p.radius2,
                         chain=p.solver_chain)
        out["methods"][m] = entry
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--out", type=Path, default=Path(__file__).with_suffix(".json"))
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args()
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out], args.force, ap)
    results = []
    for seed in range(args.seeds):
        with tempfile.TemporaryDirectory() as d:
            results.append(one_seed(seed, args.seconds, Path(d)))
        print(json.dumps(results[-1], indent=1)[:2000], flush=True)
    args.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
