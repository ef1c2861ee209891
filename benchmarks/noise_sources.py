"""Noise-source benchmark: every method under torque noise only, regressor noise only, and both.

Data (``dualid.bench.mujoco_arms``): three public arms of the example-robot-data package (panda and xarm7,
7-DoF; ur5, 6-DoF) with their URDF inertias, simulated in MuJoCo (built through MjSpec) with joint armature,
viscous and Coulomb friction drawn per seed at a real arm's size; the identification model has the same joint
terms, so at the true θ nothing is unmodelled. Motion: sums of 5 sinusoids per joint (period 5 s) at 200 Hz;
training 8 s (N ≈ 1600), held-out test 5 s (other sinusoids). What the estimators get is what a robot logs: q through an
encoder (Gaussian noise, then 16-bit quantisation), v and a from dualid's own preprocessing
(``differentiate``: Savitzky–Golay over 0.1 s, cubic), τ with Gaussian noise of a fraction of each joint's
clean τ rms. Cases (torque noise, encoder noise): torque 2 % / 5 % (exact q); encoder 0.1 / 1 mrad (no τ
noise); both 2 % + 0.1 mrad and 5 % + 1 mrad. Every method fits the same data (paired).

Metrics of a fit θ̂ on the held-out run (joint errors divided by the joint's clean τ rms, then rms over joints):
- clean error: Y(q, v, a) θ̂ − τ_clean with the exact (commanded) states: 0 at the true θ;
- floor ratio: error of Y(q, v, a) θ̂ against the noisy held-out τ ÷ the same error of the true θ (the noise
  floor; 1.0 at the true θ); the held-out τ carries the case's torque noise, or 2 % where the case has none;
- base error: ‖D (β̂ − β)‖ / ‖D β‖, β the base parameters of the held-out regressor
  (``dualid.identifiability.base_parameters``), D their column norms (a unit-free weighting);
- forward dynamics: NCC (``dualid.evaluation.scores.score_run``, ±T/72 shift) of M̂⁻¹(τ − ĥ) from the
  measured q, v, τ against the true accelerations, mean over joints;
- CPU time of ``fit`` (process time), status, physical consistency; a fit that raises is a counted failure.
Method ``dm-true-levels`` (not in the method table): ``dm``'s objective at the simulation's noise levels instead of
estimated ones, and without its held-out check: what the noise model's fit can do when its levels are exact. They
are the mean squares per joint of the two parts of the training residual at the true θ, r_i = M_i δa_i + e_i: δa_i
the measured minus the true accelerations (encoder noise, quantisation, the filter's error), Σ_a = diag(mean δa²);
e_i the rest (torque noise, the velocities' error), Σ_τ = diag(mean e²).
Method ``iv-reference`` (not in the method table either): instrumental variables with the regressor of the commanded
trajectory as instruments (``iv_reference``; unconstrained, WLS's per-joint weight), the comparison IDIM-IV offers.
The arms follow their command exactly here, so these instruments are the regressor at the true states: the strongest
an IV fit can have, and one that needs the reference trajectory, which ``dualid fit`` does not read.
Summary ratios (per case, paired per data set, median over robots × seeds): method ÷ best of (OLS, WLS,
dm-paper), ÷ dm-paper, ÷ WLS, for the clean error, the floor ratio and the base error.

    PYTHONPATH=src python -W ignore benchmarks/noise_sources.py --method ols --method wls --method dm-paper --method dm
    PYTHONPATH=src python -W ignore benchmarks/noise_sources.py --quick --out /tmp/noise_quick.json

Methods are keys of dualid's method table (``make_estimator(key, allow_unidentifiable=True)``: a serial arm's
inertial parameters are not all identifiable, its predictions are); point PYTHONPATH at another worktree's src
to score its estimators. Writes OUT and OUT with suffix .md (default benchmarks/noise_sources.{json,md});
refuses to replace an existing file without --force.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from authors_example import fmt, header, output_paths, provenance  # noqa: E402

from dualid.bench import mujoco_arms as ma  # noqa: E402
from dualid.errors import DualidError  # noqa: E402
from dualid.estimators.methods import make_estimator  # noqa: E402
from dualid.estimators.noise_dm import NoiseModelDM  # noqa: E402
from dualid.evaluation.prediction import PredictionData  # noqa: E402
from dualid.evaluation.scores import score_run, shift_window  # noqa: E402
from dualid.identifiability import base_parameters  # noqa: E402
from dualid.problem import build_problem  # noqa: E402
from dualid.report.io import markdown_table, write_json  # noqa: E402

FS, PERIOD, WINDOW, BITS = 200.0, 5.0, 0.1, 16
TRAIN_S, TEST_S = 8.0, 5.0
FLOOR_NOISE = 0.02  # held-out τ noise of the cases without torque noise (the floor's yardstick)
# name: (regime, torque noise fraction, encoder noise [rad], encoder bits)
CASES = {
    "torque 2%": ("torque", 0.02, 0.0, 0), "torque 5%": ("torque", 0.05, 0.0, 0),
    "encoder 0.1 mrad": ("regressor", 0.0, 1e-4, BITS), "encoder 1 mrad": ("regressor", 0.0, 1e-3, BITS),
    "both 2% + 0.1 mrad": ("both", 0.02, 1e-4, BITS), "both 5% + 1 mrad": ("both", 0.05, 1e-3, BITS),
}
ROBOTS = tuple(ma.ROBOTS)
BASELINES = ("ols", "wls", "dm-paper")
DEFAULT_METHODS = ("ols", "wls", "dm-paper", "dm")
ORACLE = "dm-true-levels"
IV = "iv-reference"  # instrumental variables with the commanded trajectory's regressor (``iv_reference``)
EXTRA = (ORACLE, IV)  # methods of this benchmark, not of dualid's method table
METRICS = ("clean_error", "floor_ratio", "base_error")
HERE = Path(__file__).resolve().parent


def _nrmse(err: np.ndarray, scale: np.ndarray) -> float:
    """rms over joints of per-joint RMSE(err) / scale."""
    return float(np.sqrt(np.mean(np.mean(err**2, axis=0) / scale**2)))


class HeldOut:
    """Everything the metrics need from the held-out run, computed once per data set."""

    def __init__(self, arm: ma.SimArm, run: ma.Run, rng: np.random.Generator, torque_noise: float):
        ident = arm.ident
        self.theta_true = arm.theta_true
        self.Y = ident.regressor(run.q, run.v, run.a)
        self.tau = run.tau_clean
        self.scale = np.sqrt(np.mean(run.tau_clean**2, axis=0))
        level = torque_noise or FLOOR_NOISE
        self.tau_noisy = run.tau_clean + level * self.scale * rng.normal(size=run.tau_clean.shape)
        self.floor = _nrmse(self.Y @ self.theta_true - self.tau_noisy, self.scale)
        self.base = base_parameters(self.Y.reshape(-1, self.Y.shape[2]), ident.parameters)
        self.D = np.linalg.norm(self.base.regressor(self.Y).reshape(-1, self.base.rank), axis=0)
        m = run.measured
        self.prediction = PredictionData.of(ident, m.q, m.v, m.tau)
        self.a_true = run.a
        self.shift = shift_window(PERIOD, 1.0 / FS)

    def scores(self, theta: np.ndarray) -> dict:
        beta_true = self.base.values(self.theta_true)
        try:
            ncc = float(np.mean(score_run(self.prediction.predict(theta), self.a_true, self.shift)))
        except DualidError:  # M(q, θ̂) not positive definite somewhere: no forward dynamics
            ncc = None
        return {"clean_error": _nrmse(self.Y @ theta - self.tau, self.scale),
                "floor_ratio": _nrmse(self.Y @ theta - self.tau_noisy, self.scale) / self.floor,
                "base_error": float(np.linalg.norm(self.D * (self.base.values(theta) - beta_true))
                                    / np.linalg.norm(self.D * beta_true)),
                "ncc": ncc}


def dataset(robot: str, seed: int, case: str, train_s: float = TRAIN_S, test_s: float = TEST_S):
    """(identification problem, HeldOut, the training run's true noise levels (Σ_τ, Σ_a), the training run's regressor at
    its commanded states (``iv_reference``'s instruments)) of one robot, seed and noise case. The arm's joint terms
    depend on (robot, seed); the motion and noise on (robot, seed, case)."""
    _, torque, encoder, bits = CASES[case]
    r = ROBOTS.index(robot) if robot in ROBOTS else len(ROBOTS)
    arm = ma.sim_arm(robot, np.random.default_rng([seed, r]))
    rng = np.random.default_rng([seed, r, list(CASES).index(case)])
    train = ma.measure(arm, rng, train_s, FS, torque, encoder, bits, WINDOW, name="train")
    test = ma.measure(arm, rng, test_s, FS, torque, encoder, bits, WINDOW, name="test")
    problem = build_problem(arm.ident, train.measured)
    da = train.measured.a - train.a  # the accelerations' error; the rest of the residual at the truth is the torque's
    e = problem.residual(arm.theta_true) - np.einsum("cab,cb->ca", problem.metric.evaluate(arm.theta_true), da)
    levels = np.diag(np.mean(e**2, axis=0)), np.diag(np.mean(da**2, axis=0))
    return problem, HeldOut(arm, test, rng, torque), levels, arm.ident.regressor(train.q, train.v, train.a)


def iv_reference(problem, Z: np.ndarray) -> np.ndarray:
    """Instrumental variables with the commanded trajectory's regressor Z (N, n, p) as instruments: Σ Z_iᵀW(Y_iθ − τ_i)
    = 0 in the base parameters of Z (the other parameters 0), W = diag(1 / mean r_j²) of the OLS residual (WLS's
    weight); unconstrained, as IDIM-IV (Janot, Gautier, Vandanjon). Here the arm follows its command exactly, so Z is
    the regressor at the true states: the strongest instrument there is (IDIM-IV builds it by simulating the model in
    closed loop instead)."""
    A = problem.Y.reshape(-1, problem.p)
    r = problem.residual(np.linalg.lstsq(A, problem.tau.reshape(-1), rcond=None)[0])
    w = 1.0 / np.maximum(np.mean(r**2, axis=0), 1e-300)
    base = base_parameters(Z.reshape(-1, problem.p), problem.parameters)
    Zb, Yb = base.regressor(Z), base.regressor(problem.Y)
    beta = np.linalg.solve(np.einsum("ija,j,ijb->ab", Zb, w, Yb), np.einsum("ija,j,ij->a", Zb, w, problem.tau))
    return base.embed() @ beta


class TrueLevelsDM(NoiseModelDM):
    """``dm``'s fit at given levels without its held-out check (the check asks whether estimated levels fit)."""

    def _check(self, sensor, theta, noise):
        return None


def _estimator(key: str, levels):
    if key == ORACLE:
        return TrueLevelsDM(sigma_tau=levels[0], sigma_a=levels[1], allow_unidentifiable=True)
    return make_estimator(key, allow_unidentifiable=True)


def fit_one(key: str, problem, held: HeldOut, levels, Z=None) -> dict:
    start = time.process_time()
    if key == IV:
        theta = iv_reference(problem, Z)
        return {"method": key, "failed": False, "cpu_s": time.process_time() - start, "status": "solved",
                "consistent": bool(problem.parameters.is_consistent(theta)), **held.scores(theta)}
    estimator = _estimator(key, levels)
    try:
        result = estimator.fit(problem)
    except (DualidError, ArithmeticError, np.linalg.LinAlgError) as exc:
        return {"method": key, "failed": True, "error": f"{type(exc).__name__}: {exc}",
                "cpu_s": time.process_time() - start}
    cpu = time.process_time() - start
    extra = {"second_start": second_start(estimator, problem, result)} if key == "dm" else {}
    return {"method": key, "failed": False, "cpu_s": cpu, "status": result.status,
            "consistent": bool(result.is_consistent), **held.scores(result.theta), **extra,
            **({"choice": result.noise.choice} if result.noise is not None else {})}


def second_start(est, problem, result) -> float | None:
    """dm's objective, at its own noise levels, solved again from two other starts (the paper's optimum and the WLS
    fit, each moved inside the constraints), relative to dm's: the lower of the two, (f_2 − f_dm) / f_dm, negative
    where a second start found a lower objective. None where dm kept no noise model (its objective is then WLS's,
    convex)."""
    from dualid.estimators.noise_model import noise_model_objective

    if result.noise is None or result.noise.choice != "noise model":
        return None
    sensor = problem.in_sensor_chart()
    cons = est.closed_set(sensor)[0]  # the closed set dm's fit solves on (NoiseModelDM.fit)
    S, A = result.noise.sigma_tau, result.noise.sigma_a
    f_dm = noise_model_objective(sensor, result.theta, S, A)
    others = []
    for theta in (est._paper_optimum(sensor), make_estimator("wls", allow_unidentifiable=True).fit(sensor).theta):
        try:
            theta2 = est._solve(sensor, cons, est._inside(theta, cons), result.noise)[0]
        except DualidError:
            continue
        others.append((noise_model_objective(sensor, theta2, S, A) - f_dm) / f_dm)
    return min(others) if others else None


def run_dataset(robot: str, seed: int, case: str, methods, **sizes) -> list[dict]:
    problem, held, levels, Z = dataset(robot, seed, case, **sizes)
    tag = {"robot": robot, "seed": seed, "case": case, "N": problem.N}
    truth = {**tag, "method": "truth", "failed": False, **held.scores(held.theta_true)}
    return [truth] + [{**tag, **fit_one(key, problem, held, levels, Z)} for key in methods]


def _median(x) -> float | None:
    x = [v for v in x if v is not None and np.isfinite(v)]
    return float(np.median(x)) if x else None


def _second_starts(rs: list[dict]) -> dict:
    """How many fits were checked from second starts, how many of those found a lower objective (by > 1e-6 of it)."""
    x = [r["second_start"] for r in rs if r.get("second_start") is not None]
    return {"second_start_checked": len(x), "second_start_lower": sum(v < -1e-6 for v in x),
            "second_start_min": min(x) if x else None} if any("second_start" in r for r in rs) else {}


def summarise(rows: list[dict], methods) -> dict:
    """Per case and method: medians of every metric, counts; and the paired ratios of the done-when."""
    per_method, ratios = [], []
    for case in CASES:
        sel = [r for r in rows if r["case"] == case]
        if not sel:
            continue
        sets = {}
        for r in sel:
            sets.setdefault((r["robot"], r["seed"]), {})[r["method"]] = r
        for key in ["truth", *methods]:
            rs = [r for r in sel if r["method"] == key]
            per_method.append({"case": case, "regime": CASES[case][0], "method": key, "fits": len(rs),
                               "failures": sum(r["failed"] for r in rs),
                               "inconsistent": sum(not r.get("consistent", True) for r in rs if not r["failed"]),
                               **{f"median_{m}": _median(r.get(m) for r in rs) for m in (*METRICS, "ncc", "cpu_s")},
                               **_second_starts(rs)})
        for key in methods:
            entry = {"case": case, "regime": CASES[case][0], "method": key}
            for metric in METRICS:
                vs_best, vs_dm, vs_wls = [], [], []
                for fits in sets.values():
                    mine = fits.get(key, {}).get(metric)
                    if mine is None:
                        continue
                    base = [fits[b][metric] for b in BASELINES if b in fits and fits[b].get(metric) is not None]
                    if base:
                        vs_best.append(mine / min(base))
                    if fits.get("dm-paper", {}).get(metric) is not None:
                        vs_dm.append(mine / fits["dm-paper"][metric])
                    if fits.get("wls", {}).get(metric) is not None:
                        vs_wls.append(mine / fits["wls"][metric])
                entry[metric] = {"vs_best_of_ols_wls_dm_paper": _median(vs_best), "vs_dm_paper": _median(vs_dm),
                                 "vs_wls": _median(vs_wls), "pairs": len(vs_best)}
            ratios.append(entry)
    return {"per_method": per_method, "ratios": ratios}


def to_markdown(result: dict) -> str:
    methods, s = result["methods"], result["summary"]
    cases = [c for c in CASES if any(p["case"] == c for p in s["per_method"])]
    cell = {(p["case"], p["method"]): p for p in s["per_method"]}
    ratio = {(p["case"], p["method"]): p for p in s["ratios"]}
    out = ["# Noise-source benchmark: torque noise, regressor noise, both", "", header(result), "",
           f"Robots {', '.join(result['robots'])}; seeds {', '.join(map(str, result['seeds']))}; "
           f"N = {', '.join(map(str, result['N']))} training samples per fit. Every cell is a median over robots × seeds; lower is "
           "better except NCC.", ""]

    def table(title, metric, keys, digits=3):
        out.extend(["", f"## {title}", ""])
        out.extend(markdown_table(["case", *keys], [[c] + [fmt(cell.get((c, k), {}).get(f"median_{metric}"), digits)
                                                          for k in keys] for c in cases]))

    table("Floor ratio: held-out torque error with exact states ÷ the true parameters'", "floor_ratio", methods)
    out.extend(["", f"The held-out torque carries the case's torque noise, or {result['config']['floor_noise']:.0%} "
                "where the case has none."])
    table("Clean held-out torque error (NRMSE against the noise-free torque, exact states)", "clean_error", methods, 4)
    for metric, what in (("clean_error", "clean error"), ("floor_ratio", "floor ratio")):
        out.extend(["", f"## Paired ratios of the {what} (median over robots × seeds)", ""])
        rows = []
        for c in cases:
            for k in methods:
                r = ratio.get((c, k), {}).get(metric, {})
                rows.append([c, k, fmt(r.get("vs_best_of_ols_wls_dm_paper")), fmt(r.get("vs_dm_paper")),
                             fmt(r.get("vs_wls"))])
        out.extend(markdown_table(["case", "method", "÷ best of OLS, WLS, dm-paper", "÷ dm-paper", "÷ WLS"], rows))
    table("Base-parameter error ‖D(β̂ − β)‖ / ‖Dβ‖", "base_error", methods, 4)
    table("Forward dynamics: NCC of predicted vs true accelerations (higher is better)", "ncc", ["truth", *methods], 4)
    table("CPU time per fit [s]", "cpu_s", methods, 2)
    if "dm" in methods:
        out.extend(["", "## Second starts of dm (its noise levels fixed; from the paper's optimum and from WLS)", "",
                    "Fits where dm kept its noise model, those where a second start found an objective lower by more "
                    "than 1e-6 of dm's, and the lowest relative difference (f₂ − f_dm) / f_dm.", ""])
        out.extend(markdown_table(["case", "checked", "lower", "min (f₂ − f_dm) / f_dm"], [
            [c, cell[(c, "dm")].get("second_start_checked", 0), cell[(c, "dm")].get("second_start_lower", 0),
             "–" if cell[(c, "dm")].get("second_start_min") is None else f"{cell[(c, 'dm')]['second_start_min']:.1e}"]
            for c in cases if (c, "dm") in cell]))
    out.extend(["", "## Failures and physically inconsistent fits (counts over all fits)", ""])
    out.extend(markdown_table(["case", *methods], [[c] + [f"{cell[(c, k)]['failures']} / {cell[(c, k)]['inconsistent']}"
                                                         if (c, k) in cell else "–" for k in methods] for c in cases]))
    out.extend(["", f"Wall time {result['wall_time_s']:.0f} s, CPU time {result['cpu_time_s']:.0f} s (one process, "
                "one BLAS thread; the wall time depends on the machine's other jobs)."])
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--method", action="append", help=f"a key of dualid's method table, {ORACLE} or {IV} (repeatable; "
                    f"default {' '.join(DEFAULT_METHODS)})")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    ap.add_argument("--robots", nargs="+", choices=ROBOTS, default=list(ROBOTS))
    ap.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES), metavar="CASE",
                    help=f"noise cases (default all: {'; '.join(CASES)})".replace("%", "%%"))
    ap.add_argument("--train-seconds", type=float, default=TRAIN_S, help="training duration at 200 Hz")
    ap.add_argument("--quick", action="store_true", help="smoke run: one robot, seed 0, 3 s of training, 3 cases")
    ap.add_argument("--out", default=str(HERE / "noise_sources.json"))
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args(argv)
    methods = list(args.method or DEFAULT_METHODS)
    for key in methods:
        try:
            if key not in EXTRA:
                make_estimator(key, allow_unidentifiable=True)
        except DualidError as exc:
            print(f"error: --method {key}: {exc}", file=sys.stderr)
            return 2
    json_path, md_path = output_paths(args.out, args.force, ap)
    robots, seeds, cases, train_s = args.robots, args.seeds, args.cases, args.train_seconds
    if args.quick:
        robots, seeds, train_s = ["ur5"], [0], 3.0
        cases = ["torque 5%", "encoder 1 mrad", "both 5% + 1 mrad"]
    t0, cpu0 = time.time(), time.process_time()
    rows: list[dict] = []
    for case in cases:
        for robot in robots:
            for seed in seeds:
                rows += run_dataset(robot, seed, case, methods, train_s=train_s)
                done = rows[-len(methods):]
                print(f"[{time.time() - t0:5.0f} s] {case} {robot} seed {seed}: " + ", ".join(
                    f"{r['method']} {fmt(r.get('floor_ratio'))} ({r['cpu_s']:.1f} s)" for r in done), flush=True)
    cmd = "python benchmarks/noise_sources.py " + shlex.join(sys.argv[1:] if argv is None else argv)
    result = {"command": cmd, "methods": methods, "robots": robots, "seeds": seeds, "cases": cases,
              "config": {"fs_hz": FS, "train_s": train_s, "test_s": TEST_S, "savgol_window_s": WINDOW,
                         "encoder_bits": BITS, "floor_noise": FLOOR_NOISE, "cases": {c: CASES[c] for c in cases}},
              "N": sorted({r["N"] for r in rows}), "wall_time_s": time.time() - t0,
              "cpu_time_s": time.process_time() - cpu0, "provenance": provenance(),
              "summary": summarise(rows, methods), "rows": rows}
    write_json(json_path, result)
    md_path.write_text(to_markdown(result))
    print(f"wrote {json_path} and {md_path} ({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
