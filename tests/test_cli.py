"""The simulate and reproduce commands end to end, on tiny settings."""

import json

from typer.testing import CliRunner

from dualid.cli import app

runner = CliRunner()


def test_simulate_writes_a_data_set_and_refuses_to_overwrite(tmp_path):
    out = tmp_path / "pt"
    result = runner.invoke(app, ["simulate", "pan-tilt", "--out", str(out), "--size", "small", "--seed", "3"])
    assert result.exit_code == 0, result.output
    index = json.loads((out / "dataset.json").read_text())
    assert index["info"]["system"] == "pan-tilt" and index["info"]["seed"] == 3
    assert len(index["splits"]["train"]) == 1 and len(index["splits"]["test"]) == 2
    again = runner.invoke(app, ["simulate", "pan-tilt", "--out", str(out), "--size", "small"])
    assert again.exit_code == 2
    assert f"output directory {out}: exists and is not empty; choose another or pass --force" in again.output
    forced = runner.invoke(app, ["simulate", "pan-tilt", "--out", str(out), "--size", "small", "--force"])
    assert forced.exit_code == 0, forced.output


def test_unknown_system_is_named():
    result = runner.invoke(app, ["simulate", "segway", "--out", "unused"])
    assert result.exit_code == 2
    assert "unknown system 'segway'; expected one of pan-tilt, crazyflie, landsalp" in result.output


def test_reproduce_smoke_run_writes_results_table_and_figures(tmp_path):
    out = tmp_path / "study"
    result = runner.invoke(app, ["reproduce", "pan-tilt", "--size", "small", "--seeds", "2", "--data-seeds", "2",
                                 "--out", str(out)])
    assert result.exit_code == 0, result.output
    for name in ("results.json", "results.md", "score_bars_low.png", "score_bars_high.png", "trajectory_high.png"):
        assert (out / name).is_file(), name
    doc = json.loads((out / "results.json").read_text())
    assert doc["system"] == "pan-tilt" and set(doc["cases"]) == {"low", "high"}
    md = (out / "results.md").read_text()
    assert "DM" in md and "2 simulated data sets (seeds [0, 1])" in md and "Paired score difference against WLS" in md
    assert doc["config"]["data_seeds"] == [0, 1] and {f["data_seed"] for f in doc["cases"]["high"]["fits"]} == {0, 1}
    bad = runner.invoke(app, ["reproduce", "pan-tilt", "--case", "medium"])
    assert bad.exit_code == 2 and "--case: expected one of low, high, both, got 'medium'" in bad.output


def test_reproduce_writes_progress_lines_into_a_redirected_log(tmp_path):
    """`dualid reproduce … > log.txt 2>&1`: one plain line per fit (as the pool's jobs finish), no spinner."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "src"
    log = tmp_path / "log.txt"
    env = {**os.environ, "PYTHONPATH": f"{src}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    with open(log, "w") as f:
        code = subprocess.run([sys.executable, "-m", "dualid.cli", "reproduce", "pan-tilt", "--size", "small",
                               "--case", "high", "--data-seeds", "2", "--workers", "2", "--out", str(tmp_path / "o")],
                              stdout=f, stderr=subprocess.STDOUT, env=env, cwd=tmp_path).returncode
    text = log.read_text()
    assert code == 0, text
    for line in ("0/16 data set 0: simulating", "0/16 data set 1: simulating", "] 16/16 data set ", "data set 0: high: dm",
                 "data set 1: high: dm", "done in"):
        assert line in text, line
    assert "⠋" not in text and "\r" not in text  # no spinner frames, no redrawn lines
