"""dualid fit with plausible parameters: on by default (URDF prior), off by prior.plausible: false."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from dualid.errors import ConfigError
from dualid.report.robot import write_fit
from dualid.robot.config import FitConfig
from dualid.robot.fit import fit_robot

sys.path.insert(0, str(Path(__file__).parent))
from test_workflow import small_config  # noqa: E402 - the small DFKI case of the workflow tests


@pytest.mark.parametrize("plausible", [True, False])
def test_fit_writes_urdf_and_mjcf_with_the_plausible_parameters(tmp_path, plausible):
    config = FitConfig.from_dict(small_config(methods=["ols"], references={}, prior={"plausible": plausible}))
    outcome = fit_robot(config)
    write_fit(outcome, tmp_path)
    record = yaml.safe_load((tmp_path / "parameters.yaml").read_text())["methods"]["ols"]
    assert record["urdf"] == "ols.urdf" and record["mjcf"] == "ols.xml"
    assert (tmp_path / "ols.xml").is_file()
    raw = np.array([p["value"] for p in record["parameters"]])
    np.testing.assert_allclose(raw, outcome.fits["ols"].result.theta)  # parameters.yaml keeps θ̂
    from dualid.model.rigid_body import RigidBodyModel

    written = RigidBodyModel.from_urdf(tmp_path / "ols.urdf").nominal
    p0 = outcome.rigid.parameters.p
    if plausible:
        p = outcome.fits["ols"].plausible
        assert record["model_files_theta"].startswith("θ_plausible")
        entries = record["plausible"]["parameters"]
        assert [e["name"] for e in entries] == list(outcome.problem.parameters.names)
        assert {e["determined_by"] for e in entries} == {"data", "prior"}
        by = {e["name"]: e["determined_by"] for e in entries}
        assert by["Joint1.m"] == "prior" and by["Joint2.Ixx"] == "data"
        np.testing.assert_allclose(written, p.theta[:p0], rtol=1e-9, atol=1e-12)
        assert record["plausible"]["predictions_unchanged"] is True
        assert "## Plausible parameters" in (tmp_path / "report.md").read_text()
    else:
        assert record["plausible"] is None and record["model_files_theta"].startswith("raw θ̂")
        np.testing.assert_allclose(written, outcome.fits["ols"].result.theta[:p0], rtol=1e-9, atol=1e-12)


def test_plausible_switch_must_be_a_bool():
    with pytest.raises(ConfigError) as err:
        FitConfig.from_dict(small_config(prior={"plausible": "yes"}))
    assert str(err.value) == "prior.plausible: expected true or false, got 'yes'"
