"""The margin in the fit config (``margin: {epsilon, reference}``) and the CLI (``dualid fit --margin EPS``)."""

from __future__ import annotations

import pytest
import yaml

from dualid.cli import app
from dualid.errors import ConfigError
from dualid.robot.config import FitConfig
from dualid.robot.margin_config import MarginConfig, margin_option, with_epsilon
from tests.test_cli_fit import DFKI, _config, _out, runner


def test_config_forms_and_round_trip():
    assert margin_option(None) is None
    assert margin_option(0.1) == MarginConfig(0.1, "wls")
    assert margin_option({"epsilon": 0.2, "reference": "prior"}) == MarginConfig(0.2, "prior")
    cfg = FitConfig.from_dict({"model": {"urdf": "r.urdf"}, "train": ["a.csv"], "margin": {"epsilon": 0.1}})
    assert cfg.margin == MarginConfig(0.1, "wls")
    assert cfg.as_dict()["margin"] == {"epsilon": 0.1, "reference": "wls"}
    assert "margin" not in FitConfig.from_dict({"model": {"urdf": "r.urdf"}, "train": ["a.csv"]}).as_dict()
    assert with_epsilon(None, 0.05) == MarginConfig(0.05, "wls")
    assert with_epsilon(MarginConfig(0.1, "prior"), 0.05) == MarginConfig(0.05, "prior")


@pytest.mark.parametrize(
    "value, message",
    [
        ({"epsilon": 1.0}, "margin.epsilon: expected a number in [0, 1), got 1.0"),
        ({"epsilon": -1}, "margin.epsilon: expected a number in [0, 1), got -1"),
        ({"reference": "wls"}, "margin: 'epsilon' is required (a number in [0, 1))"),
        ({"epsilon": 0.1, "reference": "ols"}, "margin.reference: expected one of ['wls', 'prior'], got 'ols'"),
        ({"epsilon": 0.1, "ref": "wls"}, "margin: unknown keys ['ref']; known keys: ['epsilon', 'reference']"),
        ("big", "margin: expected a mapping {epsilon: 0.1, reference: wls}, got 'big'"),
    ],
)
def test_bad_margin_sections(value, message):
    with pytest.raises(ConfigError) as exc:
        FitConfig.from_dict({"model": {"urdf": "r.urdf"}, "train": ["a.csv"], "margin": value})
    assert str(exc.value) == message


def test_cli_margin_reaches_every_method_and_the_report(tmp_path):
    out = tmp_path / "m"
    result = runner.invoke(app, ["fit", "--config", str(_config(tmp_path)), "--method", "wls", "--method", "dm-paper",
                                 "--margin", "0.5", "--out", str(out)])
    assert result.exit_code == 0, _out(result)
    record = yaml.safe_load((out / "parameters.yaml").read_text())
    for m in ("wls", "dm-paper"):
        info = record["methods"][m]["margin"]
        assert info["epsilon"] == 0.5 and info["reference"] == "wls pilot" and info["enforced"] is True, m
        assert info["min_ratio"] >= 0.5 - 1e-6, m
    assert "dm-paper: margin ε = 0.5 against the wls pilot" in (out / "report.md").read_text()
    bad = runner.invoke(app, ["fit", "--config", str(_config(tmp_path)), "--margin", "1.5", "--out", str(tmp_path / "x")])
    assert bad.exit_code == 2 and "margin.epsilon: expected a number in [0, 1), got 1.5" in _out(bad)


def test_prior_reference_in_a_config_file(tmp_path):
    out = tmp_path / "p"
    cfg = _config(tmp_path, margin={"epsilon": 0.1, "reference": "prior"}, test=[str(DFKI / "trajectory_04.csv")])
    result = runner.invoke(app, ["fit", "--config", str(cfg), "--method", "ols", "--out", str(out)])
    assert result.exit_code == 0, _out(result)
    info = yaml.safe_load((out / "parameters.yaml").read_text())["methods"]["ols"]["margin"]
    assert info["reference"] == "prior" and info["min_ratio"] >= 0.1 - 1e-6


def test_the_drag_workflow_applies_the_margin_too():
    from pathlib import Path

    from dualid.robot.drag_fit import fit_drag

    example = Path(__file__).resolve().parents[1] / "examples" / "drag"
    raw = yaml.safe_load((example / "drag.yaml").read_text())
    raw.update(methods=["ols", "dm-paper"], test=[], margin={"epsilon": 0.5})
    fits = fit_drag(FitConfig.from_dict(raw, example)).fits
    for m in ("ols", "dm-paper"):
        info = fits[m].result.info
        assert info["margin_reference"] == "wls pilot" and info["margin_min_ratio"] >= 0.5 - 1e-6, m
