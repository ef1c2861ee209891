"""Online identification of a payload picked up mid-log by a simulated 7-DoF arm (``dualid.online``).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/online_payload.py \
        --out benchmarks/online_payload

The arm: the Franka Panda of ``example-robot-data`` (gripper welded into the last link, ``bench.urdf_arm``), 70
inertial parameters. Motion: a sum of four sinusoids per joint (fundamental 4 s) about the middle of each joint's
range, sampled at 1 kHz. Logged: the exact q and v, the acceleration with white noise (σ_a rad/s², as differentiated
encoders give) and the joint torque τ = rnea(q, v, a) of the true arm with white noise (σ_τ N m): the noise model of
``dm``. At ``--pickup`` seconds a payload (a 2 kg, 8 cm cube centred at the hand's tool point) is added to the last
link.

The tracker: ``RecursiveFit`` in the last link's 10 parameters (the arm's others held at their values before the
pick-up: the arm was identified before), forgetting with a 2 s time constant, batches of 10 samples, the consistent
projection every 100 samples (10 Hz), the χ² detector (50-sample windows, α = 1e-6 per window, i.e. 0.07 false alarms
per hour stated; Ŝ learnt from the first 2 s) cutting the memory to 100 samples at an alarm, then pausing 2 s and
re-learning Ŝ over 2 s. Measured: the last link's mass estimate over time, the
time from the pick-up until it stays within 10 % of the true 2 kg change, the detection delay, alarms on a log without
a change, the update cost per sample (regressor, statistics, solve, detector and the projection at its rate; one
thread), and the online ``dm`` (weights frozen per batch) against the batch ``dm`` fit of the same window.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.stats import chi2

from dualid.report.outdir import check_output_files
from dualid.report.metadata import git_commit
from dualid.bench.runner import machine
from dualid.bench.urdf_arm import arm_urdf, example_robot_urdf, joint_ranges
from dualid.estimators.noise_dm import NoiseModelDM
from dualid.estimators.noise_model import noise_model_objective
from dualid.model.rigid_body import RigidBodyModel
from dualid.online import ChiSquareDetector, RecursiveFit, restrict
from dualid.problem import IdentificationProblem

FS = 1000.0
BATCH = 10
PAYLOAD = 2.0  # [kg]
SIGMA_TAU, SIGMA_A = 0.1, 0.1  # [N m], [rad/s²]
WEIGHTS = ("dm", "ols")  # the figure shows the first
SETTINGS = {"time_constant": 2000, "project_every": 100, "window": 50, "alpha": 1e-6, "memory": 5000,
            "warmup": 2000, "hold": 2000, "reset_samples": 100}
CALIBRATION = (1e-2, 1e-3, 1e-4)  # per-window false-alarm probabilities checked on the log without a change


def trajectory(lo, hi, seconds: float, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q, v, a (T, n) of a sum of four sinusoids per joint (fundamental 4 s) inside a third of each range."""
    t = np.arange(int(round(seconds * FS)))[:, None] / FS
    q, v, a = np.zeros((t.size, lo.size)), np.zeros((t.size, lo.size)), np.zeros((t.size, lo.size))
    centre, span = 0.5 * (lo + hi), (hi - lo) / 6
    q += centre
    for k in range(1, 5):
        w = 2 * np.pi * k / 4.0
        amp = span * rng.uniform(0.3, 1.0, lo.size) / (2 * k)
        phase = rng.uniform(0, 2 * np.pi, lo.size)
        q += amp * np.sin(w * t + phase)
        v += amp * w * np.cos(w * t + phase)
        a -= amp * w * w * np.sin(w * t + phase)
    return q, v, a


def payload_inertia(model: pin.Model) -> pin.Inertia:
    tcp = model.frames[model.getFrameId("panda_hand_tcp")].placement
    side = 0.08
    return pin.Inertia(PAYLOAD, tcp.translation, np.eye(3) * PAYLOAD * side ** 2 / 6)


def simulate(urdf: str, seconds: float, pickup: float | None, seed: int) -> dict:
    """A log of the true arm (module doc): q, v, a (noisy), τ (noisy), θ of the last link before and after."""
    rng = np.random.default_rng(seed)
    truth = pin.buildModelFromXML(urdf)
    names = tuple(truth.names[1:])
    q, v, a = trajectory(*joint_ranges(urdf, names), seconds, rng)
    heavy = pin.Model(truth)
    heavy.inertias[truth.njoints - 1] = truth.inertias[truth.njoints - 1] + payload_inertia(truth)
    change = len(q) if pickup is None else int(round(pickup * FS))
    tau = np.empty_like(q)
    for model, rows in ((truth, range(0, change)), (heavy, range(change, len(q)))):
        data = model.createData()
        for i in rows:
            tau[i] = pin.rnea(model, data, q[i], v[i], a[i])
    tau += SIGMA_TAU * rng.normal(size=tau.shape)
    a_measured = a + SIGMA_A * rng.normal(size=a.shape)
    return {"q": q, "v": v, "a": a_measured, "tau": tau, "change": change,
            "before": truth.inertias[truth.njoints - 1].toDynamicParameters(),
            "after": heavy.inertias[truth.njoints - 1].toDynamicParameters()}


def tracker(model: RigidBodyModel, weight: str = "ols", detect: bool = True, project_every: int | None = None,
            time_constant: float | None = SETTINGS["time_constant"]) -> RecursiveFit:
    n = model.nv
    detector = ChiSquareDetector(n, SETTINGS["window"], SETTINGS["alpha"], SETTINGS["memory"], SETTINGS["warmup"],
                                 SETTINGS["hold"]) if detect else None
    noise = {"sigma_tau": SIGMA_TAU ** 2 * np.eye(n), "sigma_a": SIGMA_A ** 2 * np.eye(n)} if weight == "dm" else {}
    return RecursiveFit(model.parameters, model.nominal, model=model, free=[model.parameters.blocks[-1].name],
                        time_constant=time_constant, weight=weight, detector=detector,
                        project_every=SETTINGS["project_every"] if project_every is None else project_every,
                        reset_samples=SETTINGS["reset_samples"], **noise)


def track(model: RigidBodyModel, log: dict, start: int = 0, stop: int | None = None, **kw) -> dict:
    """Run the tracker over log[start:stop] in batches; the history and the time per sample."""
    fit = tracker(model, **kw)
    mass = model.parameters.blocks[-1].indices[0]
    q, v, a, tau = (log[k][start:stop] for k in ("q", "v", "a", "tau"))
    rows = []
    windows = []
    t0 = time.perf_counter()
    for s in range(0, len(q), BATCH):
        step = fit.update(q[s:s + BATCH], v[s:s + BATCH], a[s:s + BATCH], tau[s:s + BATCH])
        rows.append((start + step.samples, step.theta[mass], np.nan if step.consistent is None
                     else step.consistent[mass], step.reset))
        windows += [(start + i, z, e) for i, z, e in step.windows]
    elapsed = time.perf_counter() - t0
    return {"fit": fit, "rows": np.array(rows, dtype=float), "windows": windows, "seconds_per_sample": elapsed / len(q),
            "samples": len(q)}


def settle_time(rows: np.ndarray, change: int, truth: float, column: int) -> float:
    """Seconds from the change until the estimate enters and stays within 10 % of the payload."""
    t, est = rows[:, 0], rows[:, column]
    bad = (t > change) & ~(np.abs(est - truth) <= 0.1 * PAYLOAD)
    after = t[t > change]
    if not after.size:
        return float("nan")
    last_bad = t[bad].max() if bad.any() else change
    return float((last_bad - change) / FS) if last_bad < t.max() else float("inf")


def timing(out: dict) -> dict:
    """Per-sample cost of the tracking run, with the projections' own (timed inside the fit) separated."""
    fit, total = out["fit"], out["seconds_per_sample"] * out["samples"]
    proj = np.array(fit.projection_seconds)
    return {"per_sample_ms": 1e3 * total / out["samples"],
            "per_sample_without_projection_ms": 1e3 * (total - proj.sum()) / out["samples"],
            "projection_ms": 1e3 * float(proj.mean()), "projection_median_ms": 1e3 * float(np.median(proj)),
            "projection_max_ms": 1e3 * float(proj.max()), "projections": fit.projections,
            "projections_interior": fit.projections_interior, "projection_failures": fit.projection_failures}


def dm_gap(model: RigidBodyModel, log: dict, start: int, stop: int) -> dict:
    """Online dm (forgetting 1, weights frozen per batch, projected at the end) against the batch dm fit of the same
    window, both with the true noise levels; the online fit starts from θ before the window."""
    fit = track(model, log, start, stop, weight="dm", detect=False, time_constant=None)["fit"]
    fit.project()
    q, v, a, tau = (log[k][start:stop] for k in ("q", "v", "a", "tau"))
    whole = IdentificationProblem(model.regressor(q, v, a), tau, model.metric(q), v, model.parameters,
                                  coordinates=model.coordinates)
    sub = restrict(whole, fit.idx, fit.theta0)
    S_tau, S_a = SIGMA_TAU ** 2 * np.eye(model.nv), SIGMA_A ** 2 * np.eye(model.nv)
    batch_fit = NoiseModelDM(sigma_tau=S_tau, sigma_a=S_a).fit(sub)  # its held-out check keeps the noise model here
    batch = batch_fit.theta
    online = fit.consistent[fit.idx]
    ols = track(model, log, start, stop, detect=False, time_constant=None)["fit"]
    ols.project()
    truth = log["after"] if start >= log["change"] else log["before"]
    f = {k: noise_model_objective(sub, th, S_tau, S_a) for k, th in
         (("online", online), ("batch", batch), ("ols", ols.consistent[ols.idx]))}
    return {"window_s": [start / FS, stop / FS], "objective_gap": (f["online"] - f["batch"]) / f["batch"],
            "ols_objective_gap": (f["ols"] - f["batch"]) / f["batch"],
            "theta_gap": float(np.linalg.norm(online - batch) / np.linalg.norm(batch)),
            "mass_online": float(online[0]), "mass_batch": float(batch[0]), "mass_ols": float(ols.consistent[ols.idx][0]),
            "mass_true": float(truth[0]), "batch_choice": batch_fit.noise.choice}


def measure(model: RigidBodyModel, log: dict, quiet_log: dict, weight: str, quiet_seconds: float) -> tuple:
    """The payload log and the log without a change, tracked with one weight: the table's numbers, the history."""
    out = track(model, log, weight=weight)
    change, added = log["change"], log["after"][0] - log["before"][0]
    rows = out["rows"]
    rows[:, 1:3] -= log["before"][0]  # the mass change estimated
    events = [i for i, _, e in out["windows"] if e]
    quiet = track(model, quiet_log, weight=weight)
    z = np.array([w[1] for w in quiet["windows"]])
    return {
        "within_10pct_s": settle_time(rows, change, added, 1),
        "within_10pct_consistent_s": settle_time(rows, change, added, 2),
        "detection_delay_s": (min([i for i in events if i >= change], default=np.nan) - change) / FS,
        "false_alarms_before_pickup": len([i for i in events if i < change]),
        "events_after_pickup": len([i for i in events if i >= change]),
        "quiet_log_s": quiet_seconds, "quiet_false_alarms": len([w for w in quiet["windows"] if w[2]]),
        "quiet_windows": len(z),
        "quiet_calibration": [{"alpha": c, "expected": c * len(z),
                               "observed": int(np.sum(z > chi2.isf(c, model.nv * SETTINGS["window"])))}
                              for c in CALIBRATION],
        "mass_final": float(rows[-1, 1]), "mass_final_consistent": float(rows[-1, 2]),
        "timing": timing(out),
    }, rows, out["windows"], out["fit"].detector


def run(args) -> tuple:
    urdf = arm_urdf(example_robot_urdf())
    model = RigidBodyModel(pin.buildModelFromXML(urdf))
    log = simulate(urdf, args.seconds, args.pickup, args.seed)
    quiet_log = simulate(urdf, args.quiet_seconds, None, args.seed + 1)
    by_weight = {w: measure(model, log, quiet_log, w, args.quiet_seconds) for w in WEIGHTS}
    _, rows, windows, detector = by_weight[WEIGHTS[0]]
    change = log["change"]
    result = {
        "command": " ".join(["python"] + sys.argv), "commit": git_commit() or "unknown", "machine": machine(),
        "settings": {**SETTINGS, "batch": BATCH, "fs_hz": FS, "sigma_tau": SIGMA_TAU, "sigma_a": SIGMA_A,
                     "payload_kg": PAYLOAD, "pickup_s": args.pickup, "seconds": args.seconds, "seed": args.seed},
        "mass_change_true": float(log["after"][0] - log["before"][0]),
        "stated_false_alarms_per_hour": 3600 * detector.false_alarm_rate(FS),
        "weights": {w: m[0] for w, m in by_weight.items()},
        "dm_gap": [dm_gap(model, log, 0, change), dm_gap(model, log, change, change + int(10 * FS))],
    }
    return result, rows, windows, detector.threshold


def figure(rows, windows, threshold, result, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig, (ax, az) = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    t = rows[:, 0] / FS
    pickup, added = result["settings"]["pickup_s"], result["mass_change_true"]
    ax.plot(t, rows[:, 1], lw=0.8, label="recursive estimate (unconstrained)")
    ax.plot(t, rows[:, 2], lw=1.2, label="consistent projection (10 Hz)")
    ax.axhline(added, color="k", lw=0.8, ls="--", label="true payload")
    ax.axhspan(0.9 * added, 1.1 * added, color="k", alpha=0.08, label="±10 %")
    ax.axvline(pickup, color="r", lw=0.8)
    ax.set_ylabel("last link: mass change [kg]")
    ax.set_ylim(-0.5, 1.5 * added)
    ax.legend(loc="center left", fontsize=8)
    wt = np.array([w[0] for w in windows]) / FS
    az.semilogy(wt, [w[1] / threshold for w in windows], ".", ms=2)
    az.axhline(1.0, color="r", lw=0.8, label="alarm threshold (α = 1e-6 per window)")
    az.axvline(pickup, color="r", lw=0.8)
    az.set_ylabel("χ² window statistic / threshold")
    az.set_xlabel("time [s]")
    az.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def _rows(result: dict) -> list[tuple[str, str, list[str]]]:
    """(quantity, target, [value per weight]) of the table."""
    ws = list(result["weights"].values())
    added = result["mass_change_true"]
    out = [
        (f"mass change within 10 % of {added:.2f} kg after the pick-up: recursive estimate", "≤ 2 s",
         [f"{m['within_10pct_s']:.3f} s" for m in ws]),
        ("the same, consistent estimate (projected at 10 Hz)", "≤ 2 s",
         [f"{m['within_10pct_consistent_s']:.3f} s" for m in ws]),
        ("change flagged after the pick-up", "≤ 0.5 s", [f"{m['detection_delay_s']:.3f} s" for m in ws]),
        ("alarm events before / after the pick-up", "0 / 1",
         [f"{m['false_alarms_before_pickup']} / {m['events_after_pickup']}" for m in ws]),
        (f"false alarms on a {ws[0]['quiet_log_s']:g} s log without a change ({ws[0]['quiet_windows']} windows)",
         f"stated {result['stated_false_alarms_per_hour']:.2f} per hour", [str(m["quiet_false_alarms"]) for m in ws]),
    ]
    for k, c in enumerate(ws[0]["quiet_calibration"]):
        out.append((f"calibration: windows of that log above the χ² quantile of α = {c['alpha']:g}",
                    f"{c['expected']:.1f} expected", [str(m["quiet_calibration"][k]["observed"]) for m in ws]))
    out += [
        ("mass change at the end: recursive / consistent", f"{added:.2f} kg",
         [f"{m['mass_final']:.3f} / {m['mass_final_consistent']:.3f} kg" for m in ws]),
        ("update cost per sample, amortised (regressor, weights, statistics, solve, detector, projection at 10 Hz)",
         "< 1 ms", [f"{m['timing']['per_sample_ms']:.3f} ms" for m in ws]),
        ("the same without the projection", "", [f"{m['timing']['per_sample_without_projection_ms']:.3f} ms" for m in ws]),
        ("one projection: mean / median / max (runs, failed)", "",
         [f"{m['timing']['projection_ms']:.1f} / {m['timing']['projection_median_ms']:.1f} / "
          f"{m['timing']['projection_max_ms']:.1f} ms ({m['timing']['projections']}, "
          f"{m['timing']['projection_failures']})" for m in ws]),
    ]
    return out


def markdown(result: dict, name: str) -> str:
    s, m = result["settings"], result["machine"]
    names = list(result["weights"])
    lines = [
        f"# Online identification of a {s['payload_kg']:g} kg payload picked up by a simulated Panda",
        "",
        f"Command: `{result['command']}` (commit `{result['commit']}`; {m['cpu']}, {m['cores']} cores shared, load "
        f"{m['load_average_at_start'][0]:.1f} at start, OPENBLAS_NUM_THREADS={m['OPENBLAS_NUM_THREADS']}).",
        "System, noise and tracker: the script's docstring. "
        f"{s['seconds']:g} s at {s['fs_hz']:g} Hz, pick-up at {s['pickup_s']:g} s, σ_τ = {s['sigma_tau']} N m, "
        f"σ_a = {s['sigma_a']} rad/s², seed {s['seed']}. Figure (`{names[0]}`): `{name}.png`. Weights: `dm` (C_i at the "
        "latest consistent estimate, true noise levels; the detector sees the innovations whitened by C_i) and `ols`.",
        "",
        "| quantity | target | " + " | ".join(f"`{w}`" for w in names) + " |",
        "| --- | --- | " + " | ".join("---" for _ in names) + " |",
    ]
    lines += [f"| {q} | {t} | " + " | ".join(v) + " |" for q, t, v in _rows(result)]
    lines += [
        "",
        "Online `dm` (each batch weighted with C_i at the consistent estimate before it, never re-weighted; forgetting "
        "1, projected once at the end) against the batch `dm` fit of the same window, both with the true noise "
        "levels; `ols` for scale. Objective gap: (f(θ) − f(θ_batch)) / f(θ_batch) of the dm objective.",
        "",
        "| window | dm objective gap, online | θ gap ‖Δθ‖/‖θ‖ | mass online / batch / true [kg] | ols objective gap "
        "| ols mass [kg] |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for g in result["dm_gap"]:
        lines.append(f"| {g['window_s'][0]:g}–{g['window_s'][1]:g} s | {g['objective_gap']:.2e} | {g['theta_gap']:.2e} "
                     f"| {g['mass_online']:.4f} / {g['mass_batch']:.4f} / {g['mass_true']:.4f} "
                     f"| {g['ols_objective_gap']:.2e} | {g['mass_ols']:.4f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--pickup", type=float, default=15.0)
    parser.add_argument("--quiet-seconds", type=float, default=300.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/online_payload"))
    parser.add_argument("--force", action="store_true", help="replace existing output files")
    args = parser.parse_args()
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out.with_suffix(s) for s in (".json", ".png", ".md")], args.force, parser)
    result, rows, windows, threshold = run(args)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    figure(rows, windows, threshold, result, args.out.with_suffix(".png"))
    args.out.with_suffix(".md").write_text(markdown(result, args.out.name))
    print(markdown(result, args.out.name))


if __name__ == "__main__":
    main()
