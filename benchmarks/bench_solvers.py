"""Times the dual-metric solvers: Newton (interior point) vs the SDP (Clarabel, SCS), and constrained OLS.

    python benchmarks/bench_solvers.py [--max-n 1000000] [--sdp-max-n 10000] [--budget 300] [--cap arm7=100000]

Problems (built with Pinocchio; random states, τ = Yθ + 5 % noise):
- crazyflie: free-flyer base + universal joint (2 revolute) + pendulum, n = 8, p = 30 (6-dim null space);
- arm7: a 7-joint serial arm (RZ, RY, RX, ...), n = 7, p = 70 (rank deficient).
Up to 20,000 distinct samples are generated; larger N repeats them with fresh noise on τ.
Every (problem, solver, N) runs in its own subprocess, so the peak memory is that process's maximum
resident set (data + solver). Writes benchmarks/results.json and benchmarks/results.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
BASE_SAMPLES = 20_000
NOISE = 0.05


# --- problems -----------------------------------------------------------------------------------
def _models():
    import pinocchio as pin

    def crazyflie():
        m = pin.Model()
        base = m.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
        m.appendBodyToJoint(base, pin.Inertia(0.03, np.zeros(3), np.diag([1.6e-5, 1.6e-5, 2.9e-5])), pin.SE3.Identity())
        a1 = m.addJoint(base, pin.JointModelRX(), pin.SE3(np.eye(3), np.array([0, 0, -0.02])), "a1")
        m.appendBodyToJoint(a1, pin.Inertia(0.002, np.array([0, 0, -0.005]), np.diag([2e-8, 2e-8, 1e-8])), pin.SE3.Identity())
        a2 = m.addJoint(a1, pin.JointModelRY(), pin.SE3.Identity(), "a2")
        m.appendBodyToJoint(a2, pin.Inertia(0.008, np.array([0, 0, -0.15]), np.diag([6e-5, 6e-5, 1e-7])), pin.SE3.Identity())
        return m

    def arm7():
        m, parent = pin.Model(), 0
        for j in range(7):
            joint = (pin.JointModelRZ(), pin.JointModelRY(), pin.JointModelRX())[j % 3]
            parent = m.addJoint(parent, joint, pin.SE3(np.eye(3), np.array([0, 0, 0.3 if j else 0.0])), f"j{j}")
            inertia = pin.Inertia(2.0 - 0.2 * j, np.array([0.01, 0.0, 0.12]), np.diag([0.05, 0.05, 0.01]))
            m.appendBodyToJoint(parent, inertia, pin.SE3.Identity())
        return m

    return {"crazyflie": crazyflie, "arm7": arm7}


def _spatial_inertia_basis():
    import pinocchio as pin

    theta0 = np.array([1.0, 0.1, -0.2, 0.3, 2.0, 0.1, 2.5, -0.2, 0.15, 3.0])
    G0 = pin.Inertia.FromDynamicParameters(theta0).matrix()
    return np.stack([pin.Inertia.FromDynamicParameters(theta0 + np.eye(10)[k]).matrix() - G0 for k in range(10)])


def base_samples(name: str, cache: Path) -> Path:
    """Y (B, n, p), J (bodies, B, 6, n), θ for BASE_SAMPLES random states, cached as .npz."""
    path = cache / f"{name}.npz"
    if path.exists():
        return path
    import pinocchio as pin

    model = _models()[name]()
    data = model.createData()
    rng = np.random.default_rng(0)
    pin.seed(0)
    bodies = list(range(1, model.njoints))
    n, p = model.nv, 10 * len(bodies)
    Y = np.empty((BASE_SAMPLES, n, p))
    J = np.empty((len(bodies), BASE_SAMPLES, 6, n))
    for i in range(BASE_SAMPLES):
        q = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
        Y[i] = pin.computeJointTorqueRegressor(model, data, q, rng.normal(size=n), rng.normal(size=n))
        pin.computeJointJacobians(model, data, q)
        for b, j in enumerate(bodies):
            J[b, i] = pin.getJointJacobian(model, data, j, pin.LOCAL)
    theta = np.concatenate([model.inertias[j].toDynamicParameters() for j in bodies])
    names = np.array([model.names[j] for j in bodies])
    np.savez(path, Y=Y, J=J, theta=theta, names=names)
    return path


def build_problem(path: Path, N: int):
    from dualid.problem.metric import AffineMetric, MetricTerm
    from dualid.problem.parameters import rigid_body_space
    from dualid.problem.problem import IdentificationProblem

    data = np.load(path)
    reps = -(-N // BASE_SAMPLES)
    idx = np.arange(N) % BASE_SAMPLES
    Y = data["Y"][idx] if reps > 1 else data["Y"][:N]
    theta = data["theta"]
    tau = Y @ theta
    rng = np.random.default_rng(N)
    tau += NOISE * np.abs(tau).mean(axis=0) * rng.normal(size=tau.shape)
    E = _spatial_inertia_basis()
    J = data["J"]
    terms = tuple(MetricTerm(tuple(range(10 * b, 10 * b + 10)), E, J[b][idx]) for b in range(J.shape[0]))
    problem = IdentificationProblem(Y, tau, AffineMetric(Y.shape[2], terms), np.zeros_like(tau),
                                    rigid_body_space(list(data["names"])))
    del Y, tau  # the problem holds its own copies
    return problem


def _dual_metric_objective(problem, theta) -> float:
    from dualid.estimators.newton import _objective

    return float(_objective(problem, np.asarray(theta), 4096))


# --- one run (in a subprocess) ------------------------------------------------------------------
def run_one(problem_name: str, solver: str, N: int, cache: Path) -> dict:
    from dualid import OLS, DualMetric

    problem = build_problem(base_samples(problem_name, cache), N)
    data_bytes = problem.Y.nbytes + problem.tau.nbytes + sum(t.J.nbytes for t in problem.metric.terms)
    estimator = {
        "newton": DualMetric(solver="newton", allow_unidentifiable=True),
        "sdp_clarabel": DualMetric(solver="sdp", sdp_solver="CLARABEL", allow_unidentifiable=True),
        "sdp_scs": DualMetric(solver="sdp", sdp_solver="SCS", allow_unidentifiable=True),
        "ols_constrained": OLS(allow_unidentifiable=True),
    }[solver]
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
    t0 = time.perf_counter()
    try:
        result = estimator.fit(problem)
    except Exception as exc:  # recorded, not hidden
        return {"problem": problem_name, "solver": solver, "N": N, "error": f"{type(exc).__name__}: {exc}"}
    wall = time.perf_counter() - t0
    return {
        "problem": problem_name, "solver": solver, "N": N, "n": problem.n, "p": problem.p,
        "wall_time_s": wall,
        "peak_rss_GB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
        "rss_before_fit_GB": rss_before,
        "data_GB": data_bytes / 1e9,
        # f at θ̂ for every solver (chunked for large N: the dense evaluation would need N·n² memory)
        "dual_metric_objective": _dual_metric_objective(problem, result.theta),
        "iterations": result.iterations, "status": result.status,
        "relative_gap": result.info.get("relative_gap"),
    }


# --- driver -------------------------------------------------------------------------------------
def machine() -> dict:
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 1e9
    return {
        "cpu": cpu, "cores": os.cpu_count(), "memory_GB": round(mem, 1), "python": platform.python_version(),
        "numpy": np.__version__, "platform": platform.platform(), "load_average_at_start": os.getloadavg(),
        "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS", "(default)"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-n", type=int, default=1_000_000)
    ap.add_argument("--sdp-max-n", type=int, default=10_000)
    ap.add_argument("--budget", type=float, default=300.0, help="skip larger N for a solver once a run took longer [s]")
    ap.add_argument("--timeout", type=float, default=900.0, help="kill a single run after this many seconds")
    ap.add_argument("--problems", default="crazyflie,arm7")
    ap.add_argument("--cap", default="", help="per-problem largest N, e.g. arm7=100000 (memory: Y is N·n·p·8 bytes)")
    ap.add_argument("--single", nargs=3, metavar=("PROBLEM", "SOLVER", "N"), help=argparse.SUPPRESS)
    ap.add_argument("--cache", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.single:
        name, solver, N = args.single
        print(json.dumps(run_one(name, solver, int(N), Path(args.cache))))
        return
    info = machine()  # load average at the start
    cache = Path(args.cache or tempfile.mkdtemp(prefix="dualid-bench-"))
    sizes = [N for N in (100, 1_000, 10_000, 100_000, 1_000_000) if N <= args.max_n]
    rows = []
    caps = {k: int(v) for k, v in (item.split("=") for item in args.cap.split(",") if item)}
    for name in args.problems.split(","):
        base_samples(name, cache)
        slow: set[str] = set()
        for N in sizes:
            if N > caps.get(name, N):
                continue
            for solver in ("newton", "ols_constrained", "sdp_clarabel", "sdp_scs"):
                if solver.startswith("sdp") and (N > args.sdp_max_n or solver in slow):
                    continue
                if solver in slow:
                    continue
                try:
                    out = subprocess.run(
                        [sys.executable, __file__, "--single", name, solver, str(N), "--cache", str(cache)],
                        capture_output=True, text=True, timeout=args.timeout,
                    )
                    row = json.loads(out.stdout.strip().splitlines()[-1])
                except subprocess.TimeoutExpired:
                    row = {"problem": name, "solver": solver, "N": N, "error": f"timeout after {args.timeout:g} s"}
                except (IndexError, json.JSONDecodeError):
                    row = {"problem": name, "solver": solver, "N": N, "error": out.stderr.strip()[-500:]}
                rows.append(row)
                print(json.dumps(row), flush=True)
                if "error" in row or row["wall_time_s"] > args.budget:
                    slow.add(solver)
    # objective gap to the SDP (Clarabel) at the same (problem, N)
    ref = {(r["problem"], r["N"]): r["dual_metric_objective"] for r in rows if r["solver"] == "sdp_clarabel" and "error" not in r}
    for r in rows:
        if r["solver"] != "ols_constrained" and "error" not in r and (r["problem"], r["N"]) in ref:
            r["objective_gap_to_sdp_clarabel"] = (r["dual_metric_objective"] - ref[r["problem"], r["N"]]) / ref[r["problem"], r["N"]]
    result = {"machine": info, "noise": NOISE, "base_samples": BASE_SAMPLES, "runs": rows}
    (HERE / "results.json").write_text(json.dumps(result, indent=2))
    (HERE / "results.md").write_text(markdown(result))
    print(markdown(result))


def markdown(result: dict) -> str:
    m = result["machine"]
    lines = [
        "# Dual-metric solver benchmark",
        "",
        f"Machine: {m['cpu']}, {m['cores']} cores, {m['memory_GB']} GB RAM; Python {m['python']}, numpy {m['numpy']}; "
        f"OPENBLAS_NUM_THREADS={m['OPENBLAS_NUM_THREADS']}; load average {m.get('load_note', 'at start')} "
        f"{tuple(round(x, 2) for x in m['load_average_at_start'])} "
        "(the machine was shared with other jobs: absolute times are pessimistic, ratios are indicative).",
        "",
        f"Random states, τ = Yθ + {int(100 * result['noise'])} % noise; up to {result['base_samples']:,} distinct samples, "
        "larger N repeat them with fresh noise. Peak memory = the run's process maximum RSS (data + solver). "
        "Objective gap: (f − f_SDP/Clarabel) / f_SDP/Clarabel (negative: lower than the SDP's).",
        "",
        "| problem | solver | N | wall time [s] | peak RSS [GB] | data [GB] | iterations | objective | gap to SDP |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in result["runs"]:
        if r["solver"] == "ols_constrained" and r["N"] > 200_000:
            r.pop("dual_metric_objective", None)  # (was OLS's own objective, not f, for the largest N)
        if "error" in r:
            lines.append(f"| {r['problem']} | {r['solver']} | {r['N']:,} | error: {r['error'][:80]} | | | | | |")
            continue
        gap = r.get("objective_gap_to_sdp_clarabel")
        obj = r["dual_metric_objective"] if r["solver"] != "ols_constrained" else float("nan")
        lines.append(
            f"| {r['problem']} | {r['solver']} | {r['N']:,} | {r['wall_time_s']:.3f} | {r['peak_rss_GB']:.2f} | "
            f"{r['data_GB']:.2f} | {r['iterations'] if r['iterations'] is not None else ''} | {obj:.10g} | "
            f"{'' if gap is None else f'{gap:.2e}'} |"
        )
    if result.get("findings"):
        lines += ["", "## Findings", ""] + ([result["newton_rows_note"], ""] if result.get("newton_rows_note") else [])
        lines += [f"- {x}" for x in result["findings"]]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
