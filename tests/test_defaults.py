"""Default preprocessing derived from a log's rate and motion band (dualid.robot.defaults)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dualid.data.trajectory import Trajectory
from dualid.errors import DataError
from dualid.robot.defaults import adaptive_preprocessing, log_rate_and_band

DFKI = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data"


def sines(freq: float, rate: float, seconds: float = 20.0) -> Trajectory:
    t = np.arange(int(seconds * rate)) / rate
    q = np.stack([np.sin(2 * np.pi * freq * t), 0.5 * np.sin(2 * np.pi * 0.5 * freq * t)], axis=1)
    return Trajectory(t=t, q=q, v=np.gradient(q, t, axis=0), tau=q.copy(), coordinates=("a", "b"), name="sines")


@pytest.mark.parametrize("freq,rate", [(2.0, 500.0), (0.5, 200.0), (8.0, 1000.0)])
def test_rate_and_band_of_known_sines(freq, rate):
    fs, band = log_rate_and_band(sines(freq, rate))
    assert fs == pytest.approx(rate)
    assert band == pytest.approx(freq, rel=0.15)  # (Welch resolution) the fastest sine holds the top 1 % of q's power


def test_steps_scale_with_the_band_and_the_rate():
    steps, note = adaptive_preprocessing(sines(2.0, 500.0))
    (r,), (d,), (f,), (ds,) = (s.values() for s in steps)
    assert r == {"rate": 500.0} and d["window"] == pytest.approx(0.1, rel=0.1) and d["velocity"] is True
    assert f["cutoff"] == pytest.approx(10.0, rel=0.1) and ds == {"factor": 5}
    assert "rate 500 Hz, motion band 2" in note
    faster, _ = adaptive_preprocessing(sines(8.0, 1000.0))
    assert faster[2]["filter_lowpass"]["cutoff"] == pytest.approx(40.0, rel=0.1)


def test_a_slow_or_still_log_gets_no_defaults():
    with pytest.raises(DataError, match=r"the log's rate is 0.5 Hz \(median step 2 s\), too slow"):
        adaptive_preprocessing(sines(0.01, 0.5, seconds=1000.0))
    still = sines(1.0, 100.0)
    still = Trajectory(t=still.t, q=np.zeros_like(still.q), v=still.v, tau=still.tau, coordinates=("a", "b"), name="still")
    with pytest.raises(DataError, match="the joints do not move"):
        adaptive_preprocessing(still)


def test_dfki_defaults_are_near_the_example_config():
    from dualid.data.io import ColumnMap, load_log

    steps, _ = adaptive_preprocessing(load_log(DFKI / "trajectory_00.csv", ColumnMap.pattern(["Joint1", "Joint2"])))
    assert steps[0]["resample"]["rate"] == 500.0 and steps[3]["downsample"]["factor"] == 5
    assert 0.08 <= steps[1]["differentiate"]["window"] <= 0.15  # the example: 0.1 s
    assert 7 <= steps[2]["filter_lowpass"]["cutoff"] <= 12  # the example: 10 Hz


def test_dfki_fit_from_flags_alone_is_within_10_percent_of_the_example_config(tmp_path):
    """Flags alone come within 10 % of the example config, on one training and one held-out run (ols), both
    scored with the example's preprocessing (dualid validate --config), so the measured torques compared
    against are the same."""
    import yaml
    from typer.testing import CliRunner

    from dualid.cli import app

    runner = CliRunner()
    example = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "fit.yaml"
    cfg = yaml.safe_load(example.read_text())
    cfg.update(model={"urdf": str(DFKI / "pendubot_model_2.1.urdf")}, train=[str(DFKI / "trajectory_00.csv")],
               test=[], references={}, methods=["ols"])
    (tmp_path / "fit.yaml").write_text(yaml.safe_dump(cfg))
    data = ["--data", str(DFKI / "trajectory_00.csv"), "--method", "ols"]
    flags = runner.invoke(app, ["fit", "--model", str(DFKI / "pendubot_model_2.1.urdf"), *data, "--out", str(tmp_path / "f")])
    config = runner.invoke(app, ["fit", "--config", str(tmp_path / "fit.yaml"), "--out", str(tmp_path / "c")])
    assert flags.exit_code == 0 and config.exit_code == 0, flags.output + config.output
    ncc = {}
    for name in ("f", "c"):
        out = tmp_path / f"val_{name}"
        result = runner.invoke(app, ["validate", "--model", str(tmp_path / name / "ols.urdf"), "--data",
                                     str(DFKI / "trajectory_04.csv"), "--config", str(tmp_path / "fit.yaml"), "--out", str(out)])
        assert result.exit_code == 0, result.output
        ncc[name] = yaml.safe_load((out / "validation.json").read_text())["validation"]["mean"]["tau_ncc"]
    for joint in ("Joint1", "Joint2"):
        assert ncc["f"][joint] >= 0.9 * ncc["c"][joint], ncc
