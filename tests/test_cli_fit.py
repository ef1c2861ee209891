"""``dualid fit`` / ``dualid validate`` through typer's CliRunner (small DFKI runs)."""

from __future__ import annotations

import re
from pathlib import Path

import yaml
from typer.testing import CliRunner

from dualid.cli import app

DFKI = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data"  # shipped with the repository
URDF = DFKI / "pendubot_model_2.1.urdf"
runner = CliRunner()

STEPS = [
    {"resample": {"rate": 500}},
    {"trim": {"stop": 3.0}},
    {"differentiate": {"method": "savgol", "window": 0.1, "velocity": True}},
    {"downsample": {"factor": 10}},
]


def _config(tmp_path, **extra) -> Path:
    d = {"model": {"urdf": str(URDF)}, "train": [str(DFKI / "trajectory_00.csv")], "preprocessing": STEPS}
    d.update(extra)
    path = tmp_path / "fit.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def _out(result) -> str:
    return " ".join((result.output + (result.stderr if result.stderr_bytes is not None else "")).split())


def test_fit_and_validate_end_to_end(tmp_path):
    cfg = _config(tmp_path)
    out = tmp_path / "out"
    result = runner.invoke(app, ["fit", "--config", str(cfg), "--test", str(DFKI / "trajectory_04.csv"),
                                 "--method", "ols", "--method", "wls", "--out", str(out)])
    assert result.exit_code == 0, _out(result)
    record = yaml.safe_load((out / "parameters.yaml").read_text())
    assert list(record["methods"]) == ["ols", "wls"]  # --method overrides the config's default methods
    assert (out / "ols.urdf").is_file() and (out / "scores.svg").is_file()
    assert "held-out τ RMSE [N m], 1 run" in result.output and "± 0.000" not in result.output
    # stderr is not a terminal here: one plain time-stamped line per stage, no spinner frames
    assert re.search(r"^\[ *[0-9.]+ s\] fitting wls \(", result.output, re.M) and "⠋" not in result.output
    assert "CPU time per stage" not in result.output  # only with --verbose

    val = tmp_path / "val"
    result = runner.invoke(app, ["validate", "--model", str(out / "ols.urdf"), "--data", str(DFKI / "trajectory_05.csv"),
                                 "--config", str(cfg), "--out", str(val)])
    assert result.exit_code == 0, _out(result)
    assert (val / "validation.json").is_file() and (val / "report.md").is_file()
    result = runner.invoke(app, ["validate", "--model", str(out / "ols.xml"), "--data", str(DFKI / "trajectory_05.csv"),
                                 "--config", str(cfg)])  # the MJCF beside it: armature, damping, frictionloss
    assert result.exit_code == 0, _out(result)
    assert "τ RMSE [N m], 1 run" in result.output

    # an existing non-empty output directory is refused without --force
    result = runner.invoke(app, ["fit", "--config", str(cfg), "--method", "ols", "--out", str(out)])
    assert result.exit_code == 2
    assert f"output directory {out}: exists and is not empty; choose another or pass --force" in _out(result)


def test_unknown_method(tmp_path):
    result = runner.invoke(app, ["fit", "--model", str(URDF), "--data", str(DFKI / "trajectory_00.csv"),
                                 "--method", "lasso", "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert "unknown method 'lasso'; known methods: ols, ols_unconstrained, wls, energy, logdet, pullback, dm, dm-paper" in _out(result)


def test_unknown_config_key(tmp_path):
    cfg = _config(tmp_path, method=["ols"])
    result = runner.invoke(app, ["fit", "--config", str(cfg), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert "config: unknown keys ['method']; known keys: ['model', 'columns', 'train'" in _out(result)


def test_missing_column_without_map_asks_for_config(tmp_path):
    import pandas as pd

    df = pd.read_csv(DFKI / "trajectory_00.csv", nrows=300).rename(columns={"tau_meas1": "effort1"})
    log = tmp_path / "run.csv"
    df.to_csv(log, index=False)
    result = runner.invoke(app, ["fit", "--model", str(URDF), "--data", str(log), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    text = _out(result)
    assert "no column map given and" in text and "lacks the default DFKI columns ['tau_meas1']" in text
    assert "give a 'columns' map in a --config file" in text


def test_fit_needs_model_and_data(tmp_path):
    result = runner.invoke(app, ["fit", "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert "give --model ROBOT.urdf and at least one --data RUN.csv, or a --config file" in _out(result)


def test_solver_flag_and_config_reach_the_estimator_and_the_report(tmp_path):
    out = tmp_path / "cvxpy"
    EXAMPLE = _config(tmp_path)
    result = runner.invoke(app, ["fit", "--config", str(EXAMPLE), "--method", "dm-paper", "--solver", "dm-paper=cvxpy",
                                 "--out", str(out)])
    assert result.exit_code == 0, _out(result)
    record = yaml.safe_load((out / "parameters.yaml").read_text())
    fit = record["methods"]["dm-paper"]
    assert fit["solver"] == "sdp/CLARABEL" and fit["fallback_used"] is False
    assert "| dm-paper | optimal | sdp/CLARABEL | no |" in (out / "report.md").read_text()
    bad = runner.invoke(app, ["fit", "--config", str(EXAMPLE), "--solver", "dm-paper=gurobi", "--out", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "solver must be one of ('newton', 'cvxpy'), got 'gurobi'" in _out(bad)
    bad = runner.invoke(app, ["fit", "--config", str(EXAMPLE), "--solver", "dm", "--out", str(tmp_path / "y")])
    assert bad.exit_code == 2 and "--solver: expected METHOD=SOLVER (e.g. dm-paper=cvxpy), got 'dm'" in _out(bad)


def test_verbose_prints_the_cpu_time_of_every_stage(tmp_path):
    result = runner.invoke(app, ["fit", "--config", str(_config(tmp_path)), "--method", "ols", "--verbose",
                                 "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, _out(result)
    line = next(x for x in result.output.splitlines() if x.startswith("CPU time per stage [s]: "))
    stages = dict(s.rsplit(" ", 1) for s in line.split(": ", 1)[1].split("; ")[0].split(", "))
    assert {"startup", "setup", "model", "logs", "regressors", "fit ols", "report"} <= set(stages)
    assert abs(sum(map(float, stages.values())) - float(line.rsplit("total ", 1)[1])) < 0.05
