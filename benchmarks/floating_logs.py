"""Floating base from CSV logs over several data seeds: the two demos of examples/floating (a free-flying
box pushed by a measured wrench; the Crazyflie–pendulum with its thrust wrench) regenerated per seed by
examples/floating/make_logs.py and fitted with their own configs (fit_robot, what `dualid fit` runs).

Per seed and method: the box's mass and inertia errors against the truth (all 10 parameters are
identifiable) and the held-out scores (acceleration NCC: forward dynamics from measured state and
wrench; τ RMSE). Failed fits are counted, not dropped. Prints a markdown table and writes JSON.

    PYTHONPATH=src python -W ignore benchmarks/floating_logs.py --seeds 0 1 2 3 4 --out benchmarks/floating_logs.json
"""

from __future__ import annotations

import argparse
import json
import runpy
import tempfile
import time
from pathlib import Path

import numpy as np
import pinocchio as pin

from dualid.report.outdir import check_output_files
from dualid.robot.config import FitConfig
from dualid.robot.fit import fit_robot

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "examples" / "floating"
make_logs = runpy.run_path(str(DEMO / "make_logs.py"))


def box_truth() -> np.ndarray:
    return make_logs["_box_inertia"](make_logs["BOX_MASS"], make_logs["BOX_SIZE"], make_logs["BOX_COM"]).toDynamicParameters()


def box_errors(theta: np.ndarray) -> dict:
    """Relative errors of the mass and of the principal moments about the CoM (sorted), and the CoM error [mm]."""
    truth = box_truth()
    est, ref = pin.Inertia.FromDynamicParameters(theta), pin.Inertia.FromDynamicParameters(truth)
    moments = np.sort(np.linalg.eigvalsh(est.inertia)) / np.sort(np.linalg.eigvalsh(ref.inertia)) - 1
    return {"mass": float(est.mass / ref.mass - 1), "com_mm": float(1e3 * np.linalg.norm(est.lever - ref.lever)),
            "moments": [float(x) for x in moments]}


def fit_demo(name: str, folder: Path) -> dict:
    cfg = FitConfig.from_yaml(DEMO / name / "fit.yaml")
    cfg = cfg.with_overrides(model=type(cfg.model)(folder / name / cfg.model.urdf.name, cfg.model.floating_base,
                                                   cfg.model.gravity),
                             train=tuple(folder / name / p.name for p in cfg.train),
                             test=tuple(folder / name / p.name for p in cfg.test), out=None)
    outcome = fit_robot(cfg)
    out = {}
    for method, fit in outcome.fits.items():
        if not fit.ok:
            out[method] = {"error": fit.error}
            continue
        v = fit.validation
        entry = {"a_ncc": dict(zip(v.coordinates, map(float, v.mean("a_ncc")))),
                 "tau_rmse": dict(zip(v.coordinates, map(float, v.mean("tau_rmse"))))}
        if name == "box":
            entry["errors"] = box_errors(fit.result.theta)
        out[method] = entry
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args()
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out] if args.out else [], args.force, ap)
    results = {"command": "PYTHONPATH=src python -W ignore benchmarks/floating_logs.py --seeds "
                          + " ".join(map(str, args.seeds)), "seeds": {}}
    t0 = time.time()
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as tmp:
            make_logs["main"](Path(tmp), seed)
            results["seeds"][seed] = {name: fit_demo(name, Path(tmp)) for name in ("box", "crazyflie")}
        print(f"seed {seed} done ({time.time() - t0:.0f} s)", flush=True)
    results["seconds"] = time.time() - t0
    print(table(results))
    if args.out:
        args.out.write_text(json.dumps(results, indent=1))


def _ms(xs) -> str:
    xs = np.asarray([x for x in xs if x is not None and np.isfinite(x)], dtype=float)
    return "—" if xs.size == 0 else f"{xs.mean():.3f} ± {xs.std():.3f}"


def table(results: dict) -> str:
    seeds = list(results["seeds"].values())
    lines = ["| demo | method | fits ok | a NCC base (mean of 6) | a NCC joints | mass error | CoM error [mm] | "
             "principal moments error (worst) |", "|---|---|---|---|---|---|---|---|"]
    for demo in ("box", "crazyflie"):
        methods = list(seeds[0][demo])
        for m in methods:
            ok = [s[demo][m] for s in seeds if "error" not in s[demo][m]]
            base = [np.mean([e["a_ncc"][c] for c in ("vx", "vy", "vz", "wx", "wy", "wz")]) for e in ok]
            joints = [np.mean([v for c, v in e["a_ncc"].items() if c not in ("vx", "vy", "vz", "wx", "wy", "wz")])
                      for e in ok] if demo == "crazyflie" else []
            err = [e["errors"] for e in ok if "errors" in e]
            lines.append(
                f"| {demo} | {m} | {len(ok)}/{len(seeds)} | {_ms(base)} | {_ms(joints)} | "
                f"{_ms([100 * e['mass'] for e in err]) + ' %' if err else '—'} | {_ms([e['com_mm'] for e in err])} | "
                f"{_ms([100 * max(e['moments'], key=abs) for e in err]) + ' %' if err else '—'} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
