"""The dual-metric solver benchmark: Newton (interior point) vs the SDP (Clarabel, SCS) and constrained OLS.

Problems (built with Pinocchio; random states, τ = Yθ + 5 % noise, per coordinate relative to mean |τ|):

- ``crazyflie``: free-flyer base + universal joint (2 revolute) + pendulum, n = 8, p = 30 (6-dim null space);
- ``arm7``: a 7-joint serial arm (RZ, RY, RX, ...), n = 7, p = 70 (rank deficient).

Up to ``BASE_SAMPLES`` = 20,000 distinct samples are generated (fewer when the largest N is smaller; the
samples are a deterministic prefix, so a problem of N samples is the same whatever the largest N);
larger N repeat them with fresh noise on τ. Every (problem, solver, N) runs in its own subprocess, so
the peak memory is that process's maximum resident set (data + solver), and a run that exceeds the
timeout is killed and recorded as an error. Once a solver's run takes longer than the budget (or
fails), its larger N are skipped for that problem.

The result is a plain dict (what results.json holds): ``machine``, ``noise``, ``base_samples``,
``config`` and ``runs`` (one dict per run: problem, solver, N, n, p, wall_time_s, peak_rss_GB,
data_GB, dual_metric_objective, iterations, status, relative_gap, objective_gap_to_sdp_clarabel —
or problem, solver, N, error).
"""

from __future__ import annotations

import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dualid.errors import ConfigError

PROBLEMS = ("crazyflie", "arm7")
SOLVERS = ("newton", "ols_constrained", "sdp_clarabel", "sdp_scs")  # run order within one N
SIZES = (100, 1_000, 10_000, 100_000, 1_000_000)
BASE_SAMPLES = 20_000  # distinct random states at most
NOISE = 0.05  # force noise, relative to the mean |τ| per coordinate
REFERENCE = "sdp_clarabel"  # the objective gap is relative to this solver's f at the same (problem, N)
RUN_KEYS = ("problem", "solver", "N")


# --- configuration ------------------------------------------------------------------------------
@dataclass(frozen=True)
class BenchConfig:
    """Which runs to make. ``caps``: per-problem largest N (memory: Y alone is N·n·p·8 bytes)."""

    problems: tuple[str, ...] = PROBLEMS
    solvers: tuple[str, ...] = SOLVERS
    max_n: int = 1_000_000
    sdp_max_n: int = 10_000  # the SDP solvers only up to this N
    budget: float = 300.0  # [s] skip a solver's larger N once one of its runs took longer
    timeout: float = 900.0  # [s] kill a single run after this long
    caps: Mapping[str, int] = field(default_factory=dict)

    def __post_init__(self):
        for what, given, known in (("problem", self.problems, PROBLEMS), ("solver", self.solvers, SOLVERS)):
            if not given:
                raise ConfigError(f"{what}s: expected at least one of {', '.join(known)}, got none")
            unknown = [x for x in given if x not in known]
            if unknown:
                raise ConfigError(f"unknown {what} {unknown[0]!r}; expected one of {', '.join(known)}")
        if self.max_n < SIZES[0]:
            raise ConfigError(f"max_n: expected at least {SIZES[0]} (the smallest N), got {self.max_n}")
        for name in ("budget", "timeout"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name}: expected a positive number of seconds, got {getattr(self, name)}")
        bad = [k for k in self.caps if k not in PROBLEMS]
        if bad:
            raise ConfigError(f"caps: unknown problem {bad[0]!r}; expected one of {', '.join(PROBLEMS)}")
        object.__setattr__(self, "problems", tuple(self.problems))
        object.__setattr__(self, "solvers", tuple(s for s in SOLVERS if s in self.solvers))
        object.__setattr__(self, "caps", dict(self.caps))

    @classmethod
    def quick(cls, **changes) -> BenchConfig:
        """A smoke run of about a minute: N ≤ 1,000, SDP with Clarabel (SCS only if asked for; it can
        take minutes at N = 100), 120 s per run at most."""
        d = {"solvers": ("newton", "ols_constrained", "sdp_clarabel"), "max_n": 1_000, "sdp_max_n": 1_000,
             "budget": 60.0, "timeout": 120.0}
        d.update({k: v for k, v in changes.items() if v is not None})
        return cls(**d)

    def sizes(self, problem: str) -> list[int]:
        return [N for N in SIZES if N <= min(self.max_n, self.caps.get(problem, self.max_n))]

    def planned(self) -> list[tuple[str, str, int]]:
        """Every (problem, solver, N) the run would make if no solver were skipped over the budget."""
        return [
            (name, solver, N)
            for name in self.problems
            for N in self.sizes(name)
            for solver in self.solvers
            if not (solver.startswith("sdp") and N > self.sdp_max_n)
        ]

    def as_dict(self) -> dict:
        return {"problems": list(self.problems), "solvers": list(self.solvers), "max_n": self.max_n,
                "sdp_max_n": self.sdp_max_n, "budget_s": self.budget, "timeout_s": self.timeout,
                "caps": dict(self.caps)}


# --- problems -----------------------------------------------------------------------------------
def pinocchio_model(name: str):
    """The Pinocchio model of a benchmark problem (true inertias in the bodies)."""
    import pinocchio as pin

    if name == "crazyflie":  # the study's Crazyflie–pendulum (true inertias)
        from dualid.systems.crazyflie_model import build_model

        return build_model()
    if name == "arm7":
        m, parent = pin.Model(), 0
        for j in range(7):
            joint = (pin.JointModelRZ(), pin.JointModelRY(), pin.JointModelRX())[j % 3]
            parent = m.addJoint(parent, joint, pin.SE3(np.eye(3), np.array([0, 0, 0.3 if j else 0.0])), f"j{j}")
            inertia = pin.Inertia(2.0 - 0.2 * j, np.array([0.01, 0.0, 0.12]), np.diag([0.05, 0.05, 0.01]))
            m.appendBodyToJoint(parent, inertia, pin.SE3.Identity())
        return m
    raise ConfigError(f"unknown problem {name!r}; expected one of {', '.join(PROBLEMS)}")


def base_samples(name: str, cache: Path, count: int = BASE_SAMPLES) -> Path:
    """Y (count, n, p), body Jacobians J (bodies, count, 6, n) in the local frame, θ (p,) and the body
    names for ``count`` random states, cached as ``cache/NAME-COUNT.npz``. The states come from fixed
    seeds, so fewer samples are a prefix of more."""
    if not 1 <= count <= BASE_SAMPLES:
        raise ConfigError(f"count: expected 1 … {BASE_SAMPLES} samples, got {count}")
    cache = Path(cache)
    path = cache / f"{name}-{count}.npz"
    if path.exists():
        return path
    import pinocchio as pin

    from dualid.model.rigid_body import RigidBodyModel

    model = pinocchio_model(name)
    rb = RigidBodyModel(model)
    rng = np.random.default_rng(0)
    pin.seed(0)
    q = np.stack([pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq)) for _ in range(count)])
    va = rng.normal(size=(count, 2, model.nv))  # per sample v then a: fewer samples are a prefix of more
    v, a = va[:, 0], va[:, 1]
    Y = rb.regressor(q, v, a)  # (count, n, p)
    J = np.swapaxes(rb.jacobians(q), 0, 1)  # (bodies, count, 6, n), LOCAL frames
    theta = rb.nominal
    names = np.array(rb.bodies)
    cache.mkdir(parents=True, exist_ok=True)
    tmp = cache / f".{name}-{count}.{os.getpid()}.npz"
    np.savez(tmp, Y=Y, J=J, theta=theta, names=names)
    tmp.replace(path)  # atomic: a concurrent reader never sees half a file
    return path


def build_problem(path: Path, N: int):
    """The identification problem of N samples from a ``base_samples`` file: rows i mod count, τ = Yθ
    plus NOISE·mean|τ| Gaussian noise (seed N); the metric is the mass matrix Σ_b J_bᵀ G(θ_b) J_b."""
    from dualid.model.metric import AffineMetric, MetricTerm
    from dualid.model.parameters import rigid_body_space
    from dualid.model.rigid_body import spatial_inertia_basis
    from dualid.problem import IdentificationProblem, owned

    if N < 1:
        raise ConfigError(f"N: expected a positive number of samples, got {N}")
    data = np.load(path)
    count = data["Y"].shape[0]
    idx = np.arange(N) % count
    Y = owned(data["Y"][idx] if N > count else data["Y"][:N])  # (N, n, p), taken by the problem without a copy
    tau = Y @ data["theta"]  # (N, n)
    rng = np.random.default_rng(N)
    tau += NOISE * np.abs(tau).mean(axis=0) * rng.normal(size=tau.shape)
    E = spatial_inertia_basis()
    J = data["J"]
    terms = tuple(MetricTerm(tuple(range(10 * b, 10 * b + 10)), E, J[b][idx]) for b in range(J.shape[0]))
    return IdentificationProblem(Y, tau, AffineMetric(Y.shape[2], terms), np.zeros_like(tau),
                                 rigid_body_space(list(data["names"])))


def _estimator(solver: str):
    from dualid.estimators import OLS, DualMetric

    if solver == "newton":
        return DualMetric(solver="newton", allow_unidentifiable=True)
    if solver == "sdp_clarabel":
        return DualMetric(solver="cvxpy", cvxpy_solver="CLARABEL", allow_unidentifiable=True)
    if solver == "sdp_scs":
        return DualMetric(solver="cvxpy", cvxpy_solver="SCS", allow_unidentifiable=True)
    if solver == "ols_constrained":
        return OLS(allow_unidentifiable=True)
    raise ConfigError(f"unknown solver {solver!r}; expected one of {', '.join(SOLVERS)}")


# --- one run ------------------------------------------------------------------------------------
def run_one(problem_name: str, solver: str, N: int, cache: Path, count: int = BASE_SAMPLES) -> dict:
    """Build the problem and time one fit in this process. The peak memory is this process's maximum
    resident set so far: call it in a fresh process (``run_benchmark`` does) for a per-run figure."""
    from dualid.estimators.newton import dual_metric_derivatives

    estimator = _estimator(solver)
    problem = build_problem(base_samples(problem_name, cache, count), N)
    data_bytes = problem.Y.nbytes + problem.tau.nbytes + sum(t.J.nbytes for t in problem.metric.terms)
    rss_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # kB → GB
    t0 = time.perf_counter()
    try:
        result = estimator.fit(problem)
    except Exception as exc:  # recorded, not hidden
        return {"problem": problem_name, "solver": solver, "N": N, "error": f"{type(exc).__name__}: {exc}"}
    wall = time.perf_counter() - t0
    row = {
        "problem": problem_name, "solver": solver, "N": N, "n": problem.n, "p": problem.p,
        "wall_time_s": wall,
        "peak_rss_GB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6,
        "rss_before_fit_GB": rss_before,
        "data_GB": data_bytes / 1e9,
        "iterations": result.iterations, "status": result.status,
        "relative_gap": result.info.get("relative_gap"),
    }
    # f at θ̂ for every solver, chunked (the dense evaluation would need N·n² memory)
    try:
        row["dual_metric_objective"] = float(dual_metric_derivatives(problem, np.asarray(result.theta), 0).f)
    except Exception as exc:  # e.g. some M_i(θ̂) not positive definite for a constrained-OLS θ̂
        row["dual_metric_objective"] = None
        row["objective_error"] = f"{type(exc).__name__}: {exc}"
    return row


def _single_cli() -> None:
    """Subprocess entry: argv = PROBLEM SOLVER N CACHE COUNT; prints the run's dict as one JSON line."""
    name, solver, N, cache, count = sys.argv[1:6]
    print(json.dumps(run_one(name, solver, int(N), Path(cache), int(count))), flush=True)


def run_in_subprocess(problem_name: str, solver: str, N: int, cache: Path, count: int, timeout: float) -> dict:
    """``run_one`` in a fresh Python process (own peak memory; killed after ``timeout`` seconds)."""
    cmd = [sys.executable, "-c", "from dualid.bench.runner import _single_cli; _single_cli()",
           problem_name, solver, str(N), str(cache), str(count)]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"problem": problem_name, "solver": solver, "N": N, "error": f"timeout after {timeout:g} s"}
    try:
        return json.loads(out.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        tail = out.stderr.strip()[-500:] or f"exit code {out.returncode}, no output"
        return {"problem": problem_name, "solver": solver, "N": N, "error": tail}


# --- the whole benchmark ------------------------------------------------------------------------
def machine() -> dict:
    """CPU, cores, memory, versions and the load average now (the machine may be shared)."""
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


def with_objective_gaps(rows: Sequence[dict], reference: str = REFERENCE) -> list[dict]:
    """Copies of the rows with ``objective_gap_to_sdp_clarabel`` = (f − f_ref) / f_ref on the dual-metric
    solvers' rows where the reference finished at the same (problem, N)."""
    ref = {(r["problem"], r["N"]): r["dual_metric_objective"] for r in rows
           if r["solver"] == reference and "error" not in r and r.get("dual_metric_objective") is not None}
    out = []
    for r in rows:
        r = dict(r)
        key = (r["problem"], r["N"])
        if (r["solver"] != "ols_constrained" and "error" not in r and key in ref
                and r.get("dual_metric_objective") is not None):
            r["objective_gap_to_sdp_clarabel"] = (r["dual_metric_objective"] - ref[key]) / ref[key]
        out.append(r)
    return out


def run_benchmark(
    config: BenchConfig = BenchConfig(),
    cache: Path | None = None,
    progress: Callable[[int, int, dict | None], None] | None = None,
) -> dict:
    """Run every planned (problem, solver, N) in its own subprocess; the results dict (see module doc).

    cache: where the base samples are kept (default: a temporary directory, removed afterwards);
    progress(done, total, row) is called after each run (row None when runs were skipped over the budget).
    """
    if cache is None:
        with tempfile.TemporaryDirectory(prefix="dualid-bench-") as tmp:
            return run_benchmark(config, Path(tmp), progress)
    info = machine()
    count = min(BASE_SAMPLES, max(max(config.sizes(p), default=1) for p in config.problems))
    plan = config.planned()
    total, done = len(plan), 0
    rows: list[dict] = []
    for name in config.problems:
        base_samples(name, cache, count)
        slow: set[str] = set()
        for _, solver, N in [x for x in plan if x[0] == name]:
            if solver in slow:
                total -= 1
                if progress:
                    progress(done, total, None)
                continue
            row = run_in_subprocess(name, solver, N, cache, count, config.timeout)
            rows.append(row)
            done += 1
            if progress:
                progress(done, total, row)
            if "error" in row or row["wall_time_s"] > config.budget:
                slow.add(solver)
    info["load_average_at_end"] = os.getloadavg()
    return {"machine": info, "noise": NOISE, "base_samples": count, "config": config.as_dict(),
            "runs": with_objective_gaps(rows)}


# --- reading and writing --------------------------------------------------------------------------
def load_results(path: Path) -> dict:
    """A results.json, checked for the keys the writers and the plot use."""
    path = Path(path)
    result = json.loads(path.read_text())
    missing = [k for k in ("machine", "noise", "base_samples", "runs") if k not in result]
    if missing:
        raise ConfigError(f"{path}: expected a benchmark results.json with keys machine, noise, base_samples, "
                         f"runs; missing {', '.join(missing)}")
    for i, r in enumerate(result["runs"]):
        if any(k not in r for k in RUN_KEYS) or ("error" not in r and "wall_time_s" not in r):
            raise ConfigError(f"{path}: run {i} needs problem, solver, N and wall_time_s (or error), got {sorted(r)}")
    return result


def time_ratios(result: dict, solver: str, reference: str) -> dict[tuple[str, int], float]:
    """{(problem, N): wall time of ``reference`` / wall time of ``solver``} where both finished."""
    t = {(r["problem"], r["solver"], r["N"]): r["wall_time_s"] for r in result["runs"] if "error" not in r}
    return {(p, N): t[p, reference, N] / t[p, s, N] for (p, s, N) in t if s == solver and (p, reference, N) in t}


def parse_list(text: str, known: Sequence[str], what: str) -> tuple[str, ...]:
    """'a,b' → ('a', 'b'), each checked against ``known``."""
    items = tuple(x.strip() for x in text.split(",") if x.strip())
    for x in items:
        if x not in known:
            raise ConfigError(f"unknown {what} {x!r}; expected one of {', '.join(known)}")
    if not items:
        raise ConfigError(f"expected a comma-separated list of {what}s from {', '.join(known)}, got {text!r}")
    return items


def parse_caps(text: str) -> dict[str, int]:
    """'arm7=100000,crazyflie=10000' → {'arm7': 100000, 'crazyflie': 10000}."""
    caps: dict[str, Any] = {}
    for item in (x.strip() for x in text.split(",") if x.strip()):
        name, sep, value = item.partition("=")
        if not sep or not value.strip().isdigit():
            raise ConfigError(f"cap: expected PROBLEM=N (e.g. arm7=100000), got {item!r}")
        caps[name.strip()] = int(value)
    return caps
