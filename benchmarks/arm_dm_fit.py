"""A small simulated arm: OLS, WLS, the paper's DM and the feasible-GLS ``dm`` under torque noise and model error.

A fixed 4-DoF arm with exact states, a smaller companion of benchmarks/statistical_quality.py (random 3–7-DoF arms).

System: a 4-DoF Pinocchio arm (boxes; axes z, y, y, x) with viscous + Coulomb friction and armature
on every joint, all of which the identification model has (``with_joint_terms``). Exact states
(no differentiation), sums of sinusoids per joint, train and test runs at other phases. The true
parameters are the simulated arm's; no estimator is told them.

Families (torque noise is i.i.d. Gaussian per joint with std = level × the joint's clean-torque rms):
- noise: 0 / 2 / 5 / 10 %;
- model error (2 % noise plus an unmodelled torque, sized against the joint's inertial torque M a):
  ``stribeck``: +A_j exp(−(v/0.1)²) sign(v) on joints 3, 4 with A = 3 × inertial rms;
  ``cogging``: A_j sin(8 q_j) on joints 2–4 with A = 2 × inertial rms;
  ``offset``: a constant torque-sensor offset of 1 × inertial rms on joints 1, 4 and a 5 % gain error on joint 2.

Scores on the held-out runs (per joint, then mean over joints):
- clean-torque error: rms(τ̂ − τ_true) / rms(τ_true), τ_true the noise-free torque (with the
  unmodelled part), reported as the ratio to the best of OLS/WLS in the same seed (and the raw value);
- forward dynamics: Pearson correlation of â = M̂⁻¹(τ_meas − ĥ) with the true a;
- re-chart: every fit repeated in the chart q = q̃ + 0.3·(sin q̃_{j+1}, …) (configuration dependent,
  sensor chart recorded by the problem): the relative change of the clean-torque error.
Every fit also carries the metric guard against the WLS fit.

    PYTHONPATH=src python -W ignore benchmarks/arm_dm_fit.py --seeds 5 --durations 10 40 --out benchmarks/arm_dm_fit.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import pinocchio as pin

from dualid.errors import DualidError
from dualid.report.outdir import check_output_files
from dualid.estimators.dual_metric import DualMetric
from dualid.estimators.least_squares import OLS, WLS
from dualid.estimators.noise_dm import NoiseModelDM
from dualid.metric_guard import guard_info
from dualid.model.joint_terms import with_joint_terms
from dualid.model.rigid_body import RigidBodyModel
from dualid.problem import IdentificationProblem

METHODS = {
    # a fixed-base arm has the usual base-parameter null space: predictions do not depend on it
    "ols": OLS(allow_unidentifiable=True),
    "wls": WLS(allow_unidentifiable=True),
    "dm-paper": DualMetric(allow_unidentifiable=True),
    "dm": NoiseModelDM(allow_unidentifiable=True),
}
RATE = 100.0


def build_arm(rng):
    model = pin.Model()
    parent = 0
    axes = [pin.JointModelRZ(), pin.JointModelRY(), pin.JointModelRY(), pin.JointModelRX()]
    lengths = [0.1, 0.4, 0.35, 0.1]
    masses = [3.0, 2.0, 1.2, 0.4]
    for j, (ax, L, m) in enumerate(zip(axes, lengths, masses)):
        placement = pin.SE3(np.eye(3), np.array([0.0, 0.0, lengths[j - 1] if j else 0.1]))
        parent = model.addJoint(parent, ax, placement, f"j{j + 1}")
        m = m * rng.uniform(0.8, 1.2)
        box = pin.Inertia.FromBox(m, 0.06, 0.06, L)
        model.appendBodyToJoint(parent, box, pin.SE3(np.eye(3), np.array([0.0, 0.0, 0.5 * L])))
    return model


def excitation(rng, T, n, phase_seed):
    t = np.arange(T) / RATE
    prng = np.random.default_rng(phase_seed)
    q = np.zeros((T, n)); v = np.zeros((T, n)); a = np.zeros((T, n))
    for j in range(n):
        for k, w in enumerate(2 * np.pi * np.array([0.11, 0.23, 0.37, 0.53]) * (1 + 0.07 * j)):
            A = (0.9 / (k + 1)) * rng.uniform(0.7, 1.0)
            ph = prng.uniform(0, 2 * np.pi)
            q[:, j] += A * np.sin(w * t + ph)
            v[:, j] += A * w * np.cos(w * t + ph)
            a[:, j] += -A * w * w * np.sin(w * t + ph)
    return t, q, v, a


def unmodelled(case, q, v, inertial_rms, rng):
    T, n = q.shape
    extra = np.zeros((T, n))
    gain = np.ones(n)
    if case == "stribeck":
        for j in (2, 3):
            extra[:, j] += 3.0 * inertial_rms[j] * np.exp(-(v[:, j] / 0.1) ** 2) * np.sign(v[:, j])
    elif case == "cogging":
        for j in (1, 2, 3):
            extra[:, j] += 2.0 * inertial_rms[j] * np.sin(8 * q[:, j])
    elif case == "offset":
        extra[:, 0] += 1.0 * inertial_rms[0]
        extra[:, 3] += 1.0 * inertial_rms[3]
        gain[1] = 1.05
    return extra, gain


def simulate(seed, duration, case, level):
    rng = np.random.default_rng(seed)
    pm = build_arm(rng)
    rb = RigidBodyModel(pm)
    model = with_joint_terms(rb, viscous=True, coulomb=True, armature=True, coulomb_velocity=0.01)
    n = pm.nv
    theta = np.concatenate([rb.nominal, rng.uniform(0.05, 0.3, n), rng.uniform(0.05, 0.5, n), rng.uniform(0.01, 0.05, n)])
    runs = {}
    for name, T, ph in (("train", int(duration * RATE), 1000 + seed), ("test", int(20 * RATE), 2000 + seed)):
        t, q, v, a = excitation(rng, T, n, ph)
        Y = model.regressor(q, v, a)
        tau_model = Y @ theta
        Ma = np.einsum("tab,tb->ta", model.metric(q).evaluate(theta), a)
        inertial_rms = np.sqrt(np.mean(Ma**2, axis=0))
        runs[name] = dict(q=q, v=v, a=a, Y=Y, tau_model=tau_model, inertial_rms=inertial_rms)
    inertial_rms = runs["train"]["inertial_rms"]
    for name, r in runs.items():
        extra, gain = unmodelled(case, r["q"], r["v"], inertial_rms, rng)
        r["tau_true"] = r["tau_model"] + extra  # the torque the joint really exerts
        std = level * np.sqrt(np.mean(r["tau_true"] ** 2, axis=0))
        r["tau_meas"] = gain * r["tau_true"] + std * rng.standard_normal(r["tau_true"].shape)
    tr = runs["train"]
    problem = IdentificationProblem(tr["Y"], tr["tau_meas"], model.metric(tr["q"]), tr["v"], model.parameters,
                                    coordinates=model.coordinates)
    return model, theta, problem, runs["test"], tr["q"]


def rechart(problem, q):
    """q = q̃ + 0.3·sin(q̃_{j+1}) (j < n−1): B = I + 0.3 diag-above cos(q_{j+1}) (evaluated at the data)."""
    N, n = q.shape
    B = np.broadcast_to(np.eye(n), (N, n, n)).copy()
    for j in range(n - 1):
        B[:, j, j + 1] = 0.3 * np.cos(q[:, j + 1])
    return problem.in_coordinates(B)


def scores(model, theta_hat, test):
    tau_hat = test["Y"] @ theta_hat
    err = np.sqrt(np.mean((tau_hat - test["tau_true"]) ** 2, axis=0)) / np.sqrt(np.mean(test["tau_true"] ** 2, axis=0))
    M = model.metric(test["q"]).evaluate(theta_hat)
    h = model.bias_regressor(test["q"], test["v"]) @ theta_hat
    try:
        a_hat = np.linalg.solve(M, (test["tau_meas"] - h)[..., None])[..., 0]
        ncc = np.array([np.corrcoef(a_hat[:, j], test["a"][:, j])[0, 1] for j in range(a_hat.shape[1])])
    except np.linalg.LinAlgError:
        ncc = np.full(theta_hat.shape[0] and M.shape[1], np.nan)
    return err, ncc


def run(seeds, cases, durations):
    rows = []
    for case, level in cases:
        for duration in durations:
            for seed in range(seeds):
                model, theta, problem, test, q_train = simulate(seed, duration, case, level)
                other = rechart(problem, q_train)
                wls_theta = None
                for name, est in METHODS.items():
                    row = dict(case=case, level=level, duration=duration, seed=seed, method=name)
                    t0 = time.time()
                    try:
                        res = est.fit(problem)
                        err, ncc = scores(model, res.theta, test)
                        res2 = est.fit(other)
                        err2, _ = scores(model, res2.theta, test)
                        if name == "wls":
                            wls_theta = res.theta
                        g = guard_info(problem, res.theta, wls_theta) if wls_theta is not None else {}
                        row.update(ok=True, err=err.tolist(), ncc=ncc.tolist(), err_rechart=err2.tolist(),
                                   kappa=res.info.get("kappa"), kappa_share=res.info.get("kappa_share"),
                                   ratio_min=g.get("metric_ratio_min"), ratio_max=g.get("metric_ratio_max"),
                                   degenerate=g.get("degenerate"), time=time.time() - t0)
                    except DualidError as exc:
                        row.update(ok=False, error=f"{type(exc).__name__}: {exc}"[:300])
                    rows.append(row)
                err_truth, ncc_truth = scores(model, theta, test)
                rows.append(dict(case=case, level=level, duration=duration, seed=seed, method="truth", ok=True,
                                 err=err_truth.tolist(), ncc=ncc_truth.tolist(), err_rechart=err_truth.tolist()))
            print(f"{case} {level} {duration}s done", flush=True)
    return rows


def table(rows):
    out = ["| family | case | train [s] | method | ok | clean-τ err (mean over joints) | ÷ best(OLS,WLS) mean [max] | "
           "re-chart Δerr rel. | fwd-dyn corr | κ share | metric ratio [min, max] vs WLS |", "|" + "---|" * 11]
    keys = []
    for r in rows:
        k = (r["case"], r["level"], r["duration"])
        if k not in keys:
            keys.append(k)
    for case, level, duration in keys:
        sub = [r for r in rows if (r["case"], r["level"], r["duration"]) == (case, level, duration)]
        seeds = sorted({r["seed"] for r in sub})
        best = {}
        for s in seeds:
            b = [np.mean(r["err"]) for r in sub if r["seed"] == s and r["method"] in ("ols", "wls") and r["ok"]]
            best[s] = min(b) if b else np.nan
        methods = list(dict.fromkeys(r["method"] for r in sub if r["method"] != "truth"))
        for m in methods + ["truth"]:
            rs = [r for r in sub if r["method"] == m]
            ok = [r for r in rs if r["ok"]]
            fam = "noise" if case == "noise" else "model error"
            lab = f"{int(round(100 * level))} % noise" if case == "noise" else f"{case} + {int(round(100 * level))} %"
            if not ok:
                out.append(f"| {fam} | {lab} | {duration:g} | {m} | 0/{len(rs)} | | | | | | |")
                continue
            e = np.array([np.mean(r["err"]) for r in ok])
            ratio = np.array([np.mean(r["err"]) / best[r["seed"]] for r in ok])
            dre = np.array([abs(np.mean(r["err_rechart"]) - np.mean(r["err"])) / np.mean(r["err"]) for r in ok])
            ncc = np.array([np.nanmean(r["ncc"]) for r in ok])
            ks = [r.get("kappa_share") for r in ok if r.get("kappa_share") is not None]
            rmin = [r["ratio_min"] for r in ok if r.get("ratio_min") is not None]
            rmax = [r["ratio_max"] for r in ok if r.get("ratio_max") is not None]
            out.append(
                f"| {fam} | {lab} | {duration:g} | {m} | {len(ok)}/{len(rs)} | {100 * e.mean():.3f} % ± {100 * e.std():.3f} | "
                f"{ratio.mean():.3f} [{ratio.max():.3f}] | {dre.max():.1e} | {ncc.mean():.4f} | "
                f"{'' if not ks else f'{np.mean(ks):.3f}'} | "
                f"{'' if not rmin else f'{min(rmin):.2g}, {max(rmax):.2g}'} |"
            )
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--durations", type=float, nargs="+", default=[20.0])
    ap.add_argument("--families", nargs="+", default=["noise", "model"])
    ap.add_argument("--out", default=None)
    ap.add_argument("--force", action="store_true", help="replace existing output files")
    args = ap.parse_args()
    # before the work: an existing result is not replaced without --force
    check_output_files([args.out] if args.out else [], args.force, ap)
    cases = []
    if "noise" in args.families:
        cases += [("noise", lv) for lv in (0.0, 0.02, 0.05, 0.10)]
    if "model" in args.families:
        cases += [(c, 0.02) for c in ("stribeck", "cogging", "offset")]
    rows = run(args.seeds, cases, args.durations)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)
    print(table(rows))


if __name__ == "__main__":
    main()
