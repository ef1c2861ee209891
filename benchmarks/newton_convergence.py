"""Convergence corpus for dualid's interior-point solvers: DM Newton vs the SDP, and the quadratic fits.

    PYTHONPATH=src python benchmarks/newton_convergence.py [--sdp-max-n 1000] [--out benchmarks/newton_convergence.md]

Part 1, the dual-metric objective: for each problem, Newton's status, iterations, time and objective, and
the SDP's (Clarabel) status and objective with the relative difference (Newton − SDP)/SDP. Problems: the
DFKI pendubot log with the default preprocessing (its DM infimum is not attained: Joint1.m → ∞; with
masses ≤ 5 kg it is), the same tiled ×100, the bench arm7 (rank deficient) and Crazyflie (6-dim null
space) at N = 100 … 10,000, and arm7 in units scaled over 1e-6 … 1.
Part 2, constrained OLS/WLS and the log-det / pullback priors (CAD-like ×1.3, and a prior on the cone
boundary from constrained OLS) on a thin-rod 3-DoF arm and arm7: status, solver, and the fallback chain.
Failures are rows, not omissions.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from dualid.report.outdir import check_output_files
from dualid.robot.defaults import FIXED_PREPROCESSING_0_1

DFKI = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data"


def dfki(mass_bound=None):
    from dualid.robot.config import FitConfig
    from dualid.robot.fit import build_model, build_problem, column_map, load_runs

    cfg = FitConfig.from_dict({"model": {"urdf": str(DFKI / "pendubot_model_2.1.urdf")},
                               "train": [str(DFKI / "trajectory_00.csv")],
                               "preprocessing": [dict(x) for x in FIXED_PREPROCESSING_0_1]})
    rigid, model = build_model(cfg)
    joints = tuple(rigid.coordinates)
    problem = build_problem(model, load_runs(cfg.train, column_map(cfg.columns, joints, cfg.train[0]), joints,
                                             cfg.preprocessing))
    if mass_bound is not None:
        upper = {n: mass_bound for n in problem.parameters.names if n.endswith(".m")}
        problem = dataclasses.replace(problem, parameters=problem.parameters.with_bounds({}, upper))
    return problem


def dm_corpus(cache: Path):
    from dualid.bench.runner import base_samples, build_problem

    if DFKI.is_dir():
        d = dfki()
        yield "dfki (default preprocessing)", d
        yield "dfki tiled x100", d.subset(np.tile(np.arange(d.N), 100))
        yield "dfki, masses <= 5 kg", dfki(5.0)
    for name in ("arm7", "crazyflie"):
        for N in (100, 1000, 10_000):
            yield f"{name} N={N}", build_problem(base_samples(name, cache, 2000), N)
    arm = build_problem(base_samples("arm7", cache, 2000), 300)
    B = np.diag(np.geomspace(1.0, 1e-6, arm.n))
    yield "arm7 N=300, units 1e-6..1", arm.in_coordinates(np.broadcast_to(B, (arm.N,) + B.shape).copy())


def run_dm(cache: Path, sdp_max_n: int) -> list[str]:
    from dualid.estimators.dual_metric import fit_dual_metric_sdp
    from dualid.estimators.newton import fit_dual_metric_newton

    rows = ["| problem | N | Newton | iterations | time [s] | f | SDP | SDP time [s] | (f − f_SDP)/f_SDP |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for label, problem in dm_corpus(cache):
        t0 = time.perf_counter()
        try:
            r = fit_dual_metric_newton(problem)
            newton = ("optimal", r.iterations, time.perf_counter() - t0, r.objective)
        except Exception as exc:  # a row, not an omission
            newton = (f"{type(exc).__name__}: {exc}"[:80], "", time.perf_counter() - t0, np.nan)
        sdp, sdp_t, gap = "not run", np.nan, ""
        if problem.N <= sdp_max_n:
            t0 = time.perf_counter()
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    s = fit_dual_metric_sdp(problem)
                sdp, gap = s.status, f"{(newton[3] - s.objective) / s.objective:+.1e}"
            except Exception as exc:
                sdp = f"{type(exc).__name__}"
            sdp_t = time.perf_counter() - t0
        rows.append(f"| {label} | {problem.N} | {newton[0]} | {newton[1]} | {newton[2]:.2f} | {newton[3]:.10g} | "
                    f"{sdp} | {sdp_t:.2f} | {gap} |")
        print(rows[-1], flush=True)
    return rows


def arm_problem(model, seed, T=300):
    from dualid.data import Trajectory
    from dualid.problem import build_problem

    rng = np.random.default_rng(seed)
    nj = len(model.coordinates)
    q = rng.uniform(-np.pi, np.pi, (T, nj))
    v, a = rng.standard_normal((T, nj)), 3 * rng.standard_normal((T, nj))
    tau = model.regressor(q, v, a) @ model.nominal
    tau += 0.05 * np.abs(tau).mean(0) * rng.standard_normal(tau.shape)
    return build_problem(model, Trajectory(np.arange(T) * 0.01, q, v, tau, a, model.coordinates, "random"))


def run_quadratic(seeds=3) -> list[str]:
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from dualid import OLS, WLS, RegularizedWLS
    from dualid.bench.runner import pinocchio_model
    from dualid.model import RigidBodyModel
    from tests.factories import arm

    rows = ["| arm | seed | fit | status | solver | chain |", "| --- | --- | --- | --- | --- | --- |"]
    for label, pin_model in (("3-DoF thin rods", arm(3)), ("arm7", pinocchio_model("arm7"))):
        model = RigidBodyModel(pin_model)
        for seed in range(seeds):
            problem = arm_problem(model, seed)
            fits = {"constrained OLS": OLS(allow_unidentifiable=True), "WLS": WLS(allow_unidentifiable=True)}
            theta_ols = None
            for kind in ("logdet", "pullback"):
                fits[f"{kind}, CAD x1.3"] = RegularizedWLS(theta0=model.nominal * 1.3, regularizer=kind,
                                                            allow_unidentifiable=True)
            for name, est in list(fits.items()) + [("logdet, prior = constrained OLS", "logdet"),
                                                   ("pullback, prior = constrained OLS", "pullback")]:
                if isinstance(est, str):
                    est = RegularizedWLS(theta0=theta_ols, regularizer=est, allow_unidentifiable=True)
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("error")  # a raw warning reaching the caller is a failure here
                        r = est.fit(problem)
                    if name == "constrained OLS":
                        theta_ols = r.theta
                    row = (r.status, r.solver, r.info.get("solver_chain", ""))
                except Exception as exc:
                    row = ("FAILED", "", f"{type(exc).__name__}: {exc}"[:140].replace("|", "/"))
                rows.append(f"| {label} | {seed} | {name} | {row[0]} | {row[1]} | {row[2][:140]} |")
                print(rows[-1], flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sdp-max-n", type=int, default=1000)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args()
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out] if args.out else [], args.force, ap)
    with tempfile.TemporaryDirectory() as tmp:
        dm = run_dm(Path(tmp), args.sdp_max_n)
    quad = run_quadratic()
    if args.out:
        args.out.write_text("# Interior-point convergence corpus\n\n## Dual metric\n\n" + "\n".join(dm)
                            + "\n\n## Quadratic and regularized fits\n\n" + "\n".join(quad) + "\n")


if __name__ == "__main__":
    main()
