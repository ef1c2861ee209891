"""The command line's error contract: exit codes (0 / 1 failed fit / 2 bad input), no tracebacks for
DualidError and OSError (unless --debug), plain-text messages, flags without '<bool>'."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from dualid.cli import app
from dualid.errors import ConfigError

DFKI = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data"
URDF = DFKI / "pendubot_model_2.1.urdf"
runner = CliRunner()


def _text(result) -> str:
    return " ".join((result.output + (result.stderr if result.stderr_bytes is not None else "")).split())


@pytest.mark.parametrize("command", ["fit", "validate", "simulate", "reproduce", "bench", "track"])
def test_help_shows_flags_without_a_bool_metavar(command):
    text = runner.invoke(app, [command, "--help"]).output
    assert "--force" in text and "--force <bool>" not in " ".join(text.split())
    assert "<bool>" not in text.split("--force")[1].split("\n")[0]


def test_bad_input_is_exit_2_without_traceback_and_debug_shows_it(tmp_path):
    cfg = tmp_path / "fit.yaml"
    cfg.write_text(yaml.safe_dump({"model": {"urdf": "r.urdf", "gravity": [0, 1]}, "train": ["a.csv"]}))
    result = runner.invoke(app, ["fit", "--config", str(cfg), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert "model.gravity: expected 3 numbers [m/s²], got [0, 1]" in _text(result)  # '[m/s²]' survives
    assert "Traceback" not in _text(result) and isinstance(result.exception, SystemExit)
    debug = runner.invoke(app, ["--debug", "fit", "--config", str(cfg), "--out", str(tmp_path / "o")])
    assert isinstance(debug.exception, ConfigError)


def test_a_directory_given_as_a_config_is_a_file_system_error(tmp_path):
    result = runner.invoke(app, ["fit", "--config", str(tmp_path), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit)
    assert f"config file {tmp_path}: is a directory, expected a file" in _text(result)


def test_out_below_a_file_is_exit_2(tmp_path):
    (tmp_path / "file").write_text("x")
    result = runner.invoke(app, ["simulate", "pan-tilt", "--size", "small", "--out", str(tmp_path / "file" / "o")])
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit), _text(result)
    assert str(tmp_path / "file") in _text(result)


@pytest.mark.parametrize("flag,value,message", [
    ("--format", "csv", "--format: expected one of parquet, npz, got 'csv'"),
    ("--noise", "loud", "--noise: expected one of realistic, ideal, none, got 'loud'"),
    ("--size", "huge", "--size: expected one of default, small, got 'huge'"),
])
def test_simulate_checks_its_flags_before_simulating(tmp_path, flag, value, message):
    out = tmp_path / "o"
    result = runner.invoke(app, ["simulate", "pan-tilt", "--out", str(out), flag, value])
    assert result.exit_code == 2 and message in _text(result)
    assert "simulating" not in _text(result) and not out.exists()


def test_a_failed_method_exits_1_and_marks_the_report_incomplete(tmp_path, monkeypatch):
    import dualid.robot.fit as robot_fit
    from dualid.errors import SolverError

    real = robot_fit.estimator

    class Failing:
        def fit(self, problem):
            raise SolverError("dual-metric Newton: no convergence in 100 iterations")

    monkeypatch.setattr(robot_fit, "estimator", lambda m, *a, **k: Failing() if m == "dm" else real(m, *a, **k))
    out = tmp_path / "o"
    result = runner.invoke(app, ["fit", "--model", str(URDF), "--data", str(DFKI / "trajectory_00.csv"),
                                 "--method", "dm", "--method", "ols", "--out", str(out)])
    text = _text(result)
    assert result.exit_code == 1, text
    assert "error: dm: failed: SolverError" in text
    assert (out / "ols.urdf").is_file() and not (out / "dm.urdf").exists()
    assert "**Incomplete: 1 of 2 requested methods failed (dm); see Fits.**" in (out / "report.md").read_text()
    assert yaml.safe_load((out / "parameters.yaml").read_text())["complete"] is False
