"""``dualid track``: the recursive fit of ``dualid.online`` over a log, batch by batch, written as θ(t) with alarms."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from dualid.cli.app import FLAG, app
from dualid.cli.common import console, fail

SUFFIXES = (".csv", ".parquet")


@app.command("track")
def track(
    model: Path = typer.Option(..., "--model", help="URDF of the robot; its inertials are the start θ₀ and the "
                               "values of the parameters not tracked"),
    data: Path = typer.Option(..., "--data", help="a log as dualid fit reads it (CSV with the default columns, a ROS "
                              "bag, or any log with --config), a Parquet file (q_0.., v_/a_/tau_<joint>) or a "
                              "directory of q.npy, v.npy, a.npy, tau.npy"),
    out: Path = typer.Option(..., "--out", help="θ(t) and alarms, one row per batch: .csv or .parquet"),
    config: Optional[Path] = typer.Option(None, "--config", help="fit.yaml whose columns and preprocessing read --data"),
    method: str = typer.Option("ols", "--method", help="ols, wls (weights: the running innovation covariance) or dm "
                               "(needs --sigma-tau and --sigma-a)"),
    free: Optional[list[str]] = typer.Option(None, "--free", help="track only this body (a joint's name) or parameter "
                                             "block; repeat for more (default: every parameter)"),
    time_constant: float = typer.Option(2000.0, "--time-constant", help="memory of the exponential forgetting, in "
                                        "samples"),
    window: Optional[int] = typer.Option(None, "--window", help="a sliding window of this many samples instead of "
                                         "forgetting"),
    batch: int = typer.Option(10, "--batch", help="samples per update"),
    project_every: int = typer.Option(100, "--project-every", help="samples between consistent projections (0: none)"),
    ridge: float = typer.Option(1e-6, "--ridge", help="pull toward θ₀, relative to the mean diagonal of YᵀWY (keeps "
                                "the parameters the data do not determine at θ₀)"),
    alpha: float = typer.Option(1e-6, "--alpha", help="false-alarm probability of one detector window"),
    detect_window: int = typer.Option(50, "--detect-window", help="samples per detector window"),
    sigma_tau: Optional[float] = typer.Option(None, "--sigma-tau", help="dm: torque noise std (force units)"),
    sigma_a: Optional[float] = typer.Option(None, "--sigma-a", help="dm: acceleration noise std (rad/s²)"),
    floating_base: bool = typer.Option(False, "--floating-base", metavar=FLAG, help="the URDF's root is free"),
    force: bool = typer.Option(False, "--force", metavar=FLAG, help="overwrite --out if it exists"),
) -> None:
    """Track θ while the robot runs: a recursive least-squares fit with forgetting (or a window), physically
    consistent every --project-every samples, and a χ² change detector that shortens the memory when the data stop
    agreeing with the model (docs/online.md). Writes one row per batch: the sample count, the unconstrained θ, the
    consistent θ (columns consistent.<name>), the largest detector statistic over its threshold and the alarms."""
    import numpy as np

    from dualid.cli.stream import open_source
    from dualid.model.rigid_body import RigidBodyModel
    from dualid.online import ChiSquareDetector, RecursiveFit

    if out.suffix.lower() not in SUFFIXES:
        fail(f"--out {out}: expected a .csv or .parquet file")
    if out.exists() and not force:
        fail(f"--out {out}: exists; pass --force to overwrite it")
    if batch < 1 or detect_window < 1 or project_every < 0:
        fail("--batch and --detect-window must be positive, --project-every ≥ 0")
    rb = RigidBodyModel.from_urdf(model, floating_base=floating_base)
    n = rb.nv
    noise = {}
    if method == "dm":
        if sigma_tau is None or sigma_a is None:
            fail("--method dm needs --sigma-tau and --sigma-a (the noise levels of the torques and accelerations)")
        noise = {"sigma_tau": sigma_tau ** 2 * np.eye(n), "sigma_a": sigma_a ** 2 * np.eye(n)}
    source = open_source(rb, data, config, batch, log_suffixes=(".csv",))
    detector = ChiSquareDetector(n, window=detect_window, alpha=alpha, memory=max(5000.0, detect_window))
    fit = RecursiveFit(rb.parameters, rb.nominal, model=rb, free=free or None, weight=method,
                       time_constant=None if window else time_constant, window=window, project_every=project_every,
                       ridge=ridge, detector=detector, **noise)
    rows = []
    for q, v, a, tau in source.chunks():
        step = fit.update(q, v, a, tau)
        z = max((w[1] for w in step.windows), default=np.nan) / detector.threshold
        consistent = step.consistent if step.consistent is not None else np.full(rb.parameters.p, np.nan)
        rows.append([step.samples, z, int(any(w[2] for w in step.windows)), int(step.reset),
                     *step.theta, *consistent])
    _write(rows, rb.parameters.names, out)
    alarms = sum(r[2] for r in rows)
    console.print(f"tracked {fit.samples} samples in {len(rows)} batches: {fit.projections} projections, "
                  f"{alarms} alarm{'s' * (alarms != 1)}; wrote {out}")


def _write(rows: list, names: tuple[str, ...], out: Path) -> None:
    import pandas as pd

    columns = ["samples", "detector_z_over_threshold", "alarm", "memory_reset", *names,
               *(f"consistent.{n}" for n in names)]
    frame = pd.DataFrame(rows, columns=columns)
    if out.suffix.lower() == ".parquet":
        frame.to_parquet(out, index=False)
    else:
        frame.to_csv(out, index=False)
