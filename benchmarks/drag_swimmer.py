"""The generic drag model on the simulated 4-link swimmer (dualid.systems.swimmer), over data seeds.

Per seed: the logs of examples/drag/make_data.py (3 training runs of 20 s with random joint excitation,
3 held-out gaits of 15 s, 50 Hz, the TRUE system with quadratic drag and joint Coulomb friction, mocap,
encoder, velocity and torque noise) are written to a temporary folder and fitted with the example's
config (examples/drag/drag.yaml: every method; the prior of logdet/pullback is the config's deliberately
rough nominal drag) through ``robot.drag_fit.fit_drag``, the function behind ``dualid fit``.

Ablations: --linear (the true system is exactly the model) and --exact (no sensor noise).

Scores per method (held-out runs, mean over runs): velocity NCC and RMSE of v̂ = D̂⁻¹τ per coordinate,
joint effort RMSE of τ̂ = D̂v, and the parameter error ‖θ̂ − θ_true‖/‖θ_true‖. Failures are counted.

    PYTHONPATH=src python -W ignore benchmarks/drag_swimmer.py --seeds 5 --out benchmarks/drag_swimmer.json
    PYTHONPATH=src python -W ignore benchmarks/drag_swimmer.py --seeds 2 --linear --out benchmarks/drag_swimmer_linear.json
    PYTHONPATH=src python -W ignore benchmarks/drag_swimmer.py --seeds 2 --exact --out benchmarks/drag_swimmer_exact.json
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from dualid.report.outdir import check_output_files
from dualid.model.drag_spec import DragSpec
from dualid.robot.config import FitConfig
from dualid.robot.drag_fit import fit_drag
from dualid.systems import swimmer as sw

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "drag"


def _make_data():
    spec = importlib.util.spec_from_file_location("make_data", EXAMPLE / "make_data.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.make


def run_seed(seed: int, folder: Path, linear: bool = False, exact: bool = False) -> dict:
    effects = sw.TrueEffects(quadratic=0.0, joint_coulomb=0.0) if linear else sw.TrueEffects()
    _make_data()(folder, seed, effects, exact)
    base = FitConfig.from_yaml(EXAMPLE / "drag.yaml")
    config = base.with_overrides(model=base.model.__class__(folder / "swimmer.urdf", kind="drag", drag=base.model.drag),
                                 train=tuple(folder / p.name for p in base.train),
                                 test=tuple(folder / p.name for p in base.test))
    truth = DragSpec.from_dict(sw.TRUE_DRAG).nominal_theta()
    outcome = fit_drag(config)
    coords = outcome.model.coordinates
    out = {}
    for m, f in outcome.fits.items():
        if not f.ok:
            out[m] = {"error": f.error}
            continue
        v = f.validation
        out[m] = {
            "v_ncc": dict(zip(coords, v.mean("a_ncc").tolist())),
            "v_rmse": dict(zip(coords, v.mean("a_rmse").tolist())),
            "tau_rmse_joints": dict(zip(coords[3:], v.mean("tau_rmse")[3:].tolist())),
            "theta_error": float(np.linalg.norm(f.result.theta - truth) / np.linalg.norm(truth)),
            "consistent": bool(f.result.is_consistent),
            "solver": f.result.solver,
        }
    return {"seed": seed, "rank": outcome.identifiability.rank, "p": outcome.problem.p, "methods": out}


def summary(results: list[dict]) -> str:
    methods = list(results[0]["methods"])
    lines = ["| method | failed | velocity NCC (mean over coordinates) | velocity NCC, worst coordinate | "
             "v RMSE x [m/s] | v RMSE theta [rad/s] | joint τ RMSE [N m] | ‖θ̂ − θ*‖/‖θ*‖ |",
             "|---|---|---|---|---|---|---|---|"]
    for m in methods:
        ok = [r["methods"][m] for r in results if "error" not in r["methods"][m]]
        failed = len(results) - len(ok)

        def stat(values, digits=3):
            values = np.asarray(values, float)
            return f"{values.mean():.{digits}f} ± {values.std():.{digits}f}" if len(values) else "—"

        lines.append("| " + " | ".join([
            m, str(failed),
            stat([np.mean(list(e["v_ncc"].values())) for e in ok]),
            stat([min(e["v_ncc"].values()) for e in ok]),
            stat([e["v_rmse"]["x"] for e in ok], 4),
            stat([e["v_rmse"]["theta"] for e in ok]),
            stat([np.mean(list(e["tau_rmse_joints"].values())) for e in ok], 4),
            stat([e["theta_error"] for e in ok]),
        ]) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "drag_swimmer.json")
    parser.add_argument("--linear", action="store_true", help="ablation: the true system is the model (no "
                        "quadratic drag, no joint Coulomb friction)")
    parser.add_argument("--exact", action="store_true", help="ablation: no sensor noise (exact q, v, τ)")
    parser.add_argument("--force", action="store_true", help="replace existing output files")
    args = parser.parse_args(argv)
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out], args.force, parser)
    results = []
    t0 = time.time()
    for seed in range(args.seeds):
        with tempfile.TemporaryDirectory() as tmp:
            results.append(run_seed(seed, Path(tmp), args.linear, args.exact))
        print(f"seed {seed} done ({time.time() - t0:.0f} s)", file=sys.stderr)
    flags = "".join(f" --{k}" for k in ("linear", "exact") if getattr(args, k))
    record = {"command": f"PYTHONPATH=src python -W ignore benchmarks/drag_swimmer.py --seeds {args.seeds}{flags} "
                         f"--out {args.out.relative_to(ROOT) if args.out.is_relative_to(ROOT) else args.out}",
              "results": results, "summary": summary(results)}
    args.out.write_text(json.dumps(record, indent=1) + "\n")
    print(record["summary"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
