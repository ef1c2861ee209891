"""``dualid fit`` and ``dualid validate``: the real-robot workflow (URDF + logs) on the command line."""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from dualid.cli.app import FLAG, app
from dualid.cli.common import (
    EXIT_FAILED,
    StageClock,
    console,
    fail,
    no_mujoco_rendering,
    one_blas_thread,
    output_dir,
    print_error,
    progress_status,
    show_warnings,
)
from dualid.cli.fit_summary import print_summary

_STAGES = {"loading": "logs", "margin": "margin", "uncertainty": "uncertainty", "validating": "validation",
           "choosing": "plausible", "scoring": "training scores", "writing": "files", "drawing": "report"}


def _stage(message: str) -> str:
    """The stage a progress message of ``robot.fit`` opens (the --verbose timing line's names)."""
    words = message.split()
    if not words:
        return ""
    if words[0] == "fitting":
        return f"fit {words[1]}"
    if words[0] == "building":
        return "regressors" if "regressors" in message else "model"
    return _STAGES.get(words[0], words[0])


def _command_line() -> str:
    """The command as typed (recorded in the run metadata of the reports)."""
    import shlex
    import sys

    return shlex.join(["dualid", *sys.argv[1:]])


def _config(config: Optional[Path], model: Optional[Path], data: List[Path]):
    from dualid.robot.config import FitConfig

    if config is not None:
        return FitConfig.from_yaml(config)
    if model is None or not data:
        fail("give --model ROBOT.urdf and at least one --data RUN.csv, or a --config file")
    return FitConfig.from_dict({"model": {"urdf": str(model)}, "train": [str(p) for p in data]})


def _solver_overrides(cfg, flags: List[str]):
    """cfg.solver with each --solver METHOD=SOLVER merged in (None when no flag was given); SOLVER "cvxpy:NAME" also
    sets the estimator's cvxpy_solver."""
    from dualid.errors import ConfigError

    if not flags:
        return None
    options = {m: dict(o) for m, o in cfg.solver}
    for flag in flags:
        method, sep, name = flag.partition("=")
        if not sep or not method or not name:
            raise ConfigError(f"--solver: expected METHOD=SOLVER (e.g. dm-paper=cvxpy), got {flag!r}")
        name, colon, backend = name.partition(":")
        options.setdefault(method, {})["solver"] = name
        if colon:
            options[method]["cvxpy_solver"] = backend
    return tuple((m, tuple(sorted(o.items()))) for m, o in options.items())


@app.command()
def fit(
    model: Optional[Path] = typer.Option(None, "--model", help="the robot's URDF"),
    data: List[Path] = typer.Option([], "--data", help="training log (csv/parquet/npz, a ROS 1 .bag or a rosbag2 folder); "
                                "repeatable"),
    test: List[Path] = typer.Option([], "--test", help="held-out log for validation; repeatable"),
    method: List[str] = typer.Option([], "--method", help="ols, wls, energy, logdet, pullback, dm-paper or dm; repeatable"),
    solver: List[str] = typer.Option([], "--solver", help="METHOD=SOLVER, SOLVER newton (dualid's interior point) or cvxpy "
                                     "(the conic reference; cvxpy:SCS for SCS): dm-paper=cvxpy, wls=newton, "
                                     "wls=cvxpy:SCS, …; repeatable (more options: 'solver:' in the config)"),
    config: Optional[Path] = typer.Option(None, "--config", help="fit.yaml (columns, preprocessing, ...); flags override it"),
    out: Optional[Path] = typer.Option(None, "--out", help="output directory"),
    force: bool = typer.Option(False, "--force", metavar=FLAG, help="write into an existing non-empty output directory"),
    margin: Optional[float] = typer.Option(None, "--margin", metavar="EPS", help="every method under M(θ) ⪰ EPS·M(θ_ref), "
                                           "θ_ref a WLS pilot (or the config's margin.reference); 0 ≤ EPS < 1"),
    package_path: List[Path] = typer.Option([], "--package-path", metavar="DIR", help="a folder holding the packages "
                                            "that the URDF's package:// mesh URIs name (searched before the config's "
                                            "model.package_path and ROS_PACKAGE_PATH); repeatable"),
    verbose: bool = typer.Option(False, "--verbose", metavar=FLAG, help="print the CPU time of every stage"),
) -> None:
    """Identify a robot's inertial parameters, joint friction and armature from a URDF and logs (or a drag
    model's drag and damping: model.kind: drag in the config)."""
    clock = StageClock(_stage)
    one_blas_thread()  # before numpy loads: small products, a second thread only spins (docs/performance.md)
    no_mujoco_rendering()
    import warnings
    from dataclasses import replace

    from dualid.report.robot import write_fit
    from dualid.robot.fit import fit_robot
    from dualid.robot.margin_config import with_epsilon

    cfg = _config(config, model, data)
    if model is not None and config is not None:
        cfg = cfg.with_overrides(model=replace(cfg.model, urdf=model))
    cfg = cfg.with_overrides(
        model=replace(cfg.model, package_path=(*package_path, *cfg.model.package_path)) if package_path else None,
        train=tuple(data) if data and config is not None else None,
        test=tuple(test) or None,
        methods=tuple(method) or None,
        solver=_solver_overrides(cfg, solver),
        out=out,
        margin=with_epsilon(cfg.margin, margin),
    )
    if cfg.out is None:
        fail("no output directory: pass --out DIR (or set 'out' in the config)")
    output_dir(cfg.out, force)
    if cfg.model.kind == "drag":  # a drag-dominated model: its own workflow and report
        from dualid.cli.drag import fit_drag_command

        return fit_drag_command(cfg, force, config_file=config, command=_command_line())

    def say(message: str) -> None:
        clock.tick(message)
        status(message)

    with warnings.catch_warnings(record=True) as caught:  # recorded in the outcome by fit_robot
        warnings.simplefilter("always")
        try:
            with progress_status() as status:
                outcome = fit_robot(cfg, progress=say)
                say(f"writing {cfg.out}")
                written = write_fit(outcome, cfg.out, force, command=_command_line(), config_file=config, progress=say)
        finally:  # also when an error follows: a warning may explain it
            show_warnings(caught)
    failed = print_summary(outcome, written, cfg.out)
    if verbose:
        console.print(clock.line(), markup=False)
    if failed:
        raise typer.Exit(EXIT_FAILED)


@app.command()
def validate(
    model: Path = typer.Option(..., "--model", help="an (identified) URDF (friction from <dynamics>) or MJCF (.xml)"),
    data: List[Path] = typer.Option(..., "--data", help="log to validate on (csv/parquet/npz or a ROS bag); repeatable"),
    config: Optional[Path] = typer.Option(None, "--config", help="fit.yaml for columns, preprocessing, gravity"),
    out: Optional[Path] = typer.Option(None, "--out", help="write validation.json, report.md/.html and PNGs here"),
    force: bool = typer.Option(False, "--force", metavar=FLAG, help="write into an existing non-empty output directory"),
) -> None:
    """Predicted vs measured effort (inverse dynamics) and acceleration (forward dynamics) of a URDF on logs."""
    from dualid.report.robot import score_table, write_validation
    from dualid.robot.config import FitConfig
    from dualid.robot.validate import validate_urdf

    if out is not None:
        output_dir(out, force)
    import warnings

    kw: dict = {}
    if config is not None:
        cfg = FitConfig.from_yaml(config)
        kw = dict(columns=cfg.columns, preprocessing=cfg.preprocessing, xcorr_window=cfg.xcorr_window,
                  coulomb_velocity=cfg.joint_terms.coulomb_velocity, gravity=cfg.model.gravity,
                  floating_base=cfg.model.floating_base)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            with progress_status(f"validating {model.name} on {len(data)} runs") as say:
                say(f"validating {model.name} on {len(data)} runs")
                _, _, val = validate_urdf(model, data, **kw)
            if out is not None:
                meta = {"model": str(model), "data": [str(p) for p in data],
                        "config": None if config is None else str(config)}
                write_validation(val, out, meta, force, command=_command_line(),
                                 xcorr_window=kw.get("xcorr_window", 0.02))
        finally:
            show_warnings(caught)
    typer.echo(score_table({val.label: val}))
    if out is not None:
        console.print(f"wrote validation.json, report.md, report.html and figures to {out}", markup=False)
