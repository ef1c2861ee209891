"""The written files say which parameter the data do not determine: a mass dm's fit completed (the link next to the
fixed base of the DFKI pendubot turns about a fixed axis; its mass only loosens its consistency block:
model.closure) carries an XML comment on its body in the URDF and the MJCF, in closure.NOT_DETERMINED's
words, and its parameters.yaml ``bodies`` entry says ``not_determined_by_data: [Joint1.m]``; the other body has
neither. Before, the three outputs carried the completed value (0.99 kg on this data; 4.9e7 kg on the
example's full runs) with no note."""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import pytest
import yaml

from dualid.errors import ModelError
from dualid.model.closure import NOT_DETERMINED
from dualid.model.mjcf import identified_mjcf
from dualid.model.rigid_body import RigidBodyModel
from dualid.model.urdf import identified_urdf
from dualid.report.model_files import RAW
from dualid.report.robot import write_fit
from dualid.robot.config import FitConfig
from dualid.robot.fit import fit_robot

sys.path.insert(0, str(Path(__file__).parent))
from test_workflow import small_config  # noqa: E402

DFKI = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data"
URDF = DFKI / "pendubot_model_2.1.urdf"
COMMENT = (" dualid: Joint1.m: not determined by the data: the smallest value consistent with the other "
           "parameters ")
URDF_NOTES = {"world": [], "base_link": [], "Link1": [COMMENT], "Link2": [], "Weight": []}  # Weight: welded to Link2


def _comments(text: str, tag: str) -> dict[str, list[str]]:
    """{name of every <tag> element: the comments directly inside it}."""
    root = ET.fromstring(text, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    return {e.get("name"): [c.text for c in e if c.tag is ET.Comment] for e in root.iter(tag)}


def _notes(comments: dict[str, list[str]]) -> dict[str, list[str]]:
    return {name: [c for c in cs if "not determined" in c] for name, cs in comments.items()}


def test_the_comment_is_closures_wording():
    assert COMMENT == f" dualid: Joint1.m: {NOT_DETERMINED} "


def test_urdf_and_mjcf_say_it_on_exactly_that_body():
    rigid = RigidBodyModel.from_urdf(URDF)
    nd = {"Joint1.m": NOT_DETERMINED}
    urdf = _comments(identified_urdf(URDF, rigid, rigid.nominal, not_determined=nd), "link")
    assert _notes(urdf) == URDF_NOTES
    assert urdf["Link1"] == [" dualid: identified inertia of the whole body moved by joint 'Joint1' ", COMMENT]
    xml = identified_mjcf(URDF, rigid, rigid.nominal, not_determined=nd).xml
    assert _notes(_comments(xml, "body")) == {"Link1": [COMMENT], "Link2": []}
    assert f'<body name="Link1" pos="0.034200000000000001 0 0">\n      <!--{COMMENT}-->\n      <inertial ' in xml
    mujoco.MjModel.from_xml_string(xml)  # still a model MuJoCo loads
    # without the argument: no such comment
    assert COMMENT not in identified_urdf(URDF, rigid, rigid.nominal)
    assert "not determined" not in identified_mjcf(URDF, rigid, rigid.nominal).xml


def test_a_label_that_is_not_the_models_is_refused():
    rigid = RigidBodyModel.from_urdf(URDF)
    with pytest.raises(ModelError) as err:
        identified_urdf(URDF, rigid, rigid.nominal, not_determined={"Joint1.fv": NOT_DETERMINED})
    assert str(err.value) == ("write_urdf: not_determined names ['Joint1.fv'], which are not parameters of the model; "
                              "expected inertial parameter names such as 'Joint1.m'")
    with pytest.raises(ModelError, match=r"^write_mjcf: not_determined names \['x'\]"):
        identified_mjcf(URDF, rigid, rigid.nominal, not_determined={"x": NOT_DETERMINED})


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """dm on 4 s of the DFKI logs with the files carrying θ̂ itself (prior.plausible: false)."""
    config = small_config(methods=["dm"], references={}, prior={"source": "urdf", "plausible": False})
    outcome = fit_robot(FitConfig.from_dict(config))
    assert outcome.fits["dm"].result.info["projected_names"] == ["Joint1.m"]
    out = tmp_path_factory.mktemp("fit")
    write_fit(outcome, out)
    return outcome, out


def test_a_fit_with_a_completed_mass_says_it_in_all_three_outputs(written):
    outcome, out = written
    record = yaml.safe_load((out / "parameters.yaml").read_text())["methods"]["dm"]
    assert record["model_files_theta"] == RAW and record["urdf"] == "dm.urdf" and record["mjcf"] == "dm.xml"
    assert _notes(_comments((out / "dm.urdf").read_text(), "link")) == URDF_NOTES
    assert _notes(_comments((out / "dm.xml").read_text(), "body")) == {"Link1": [COMMENT], "Link2": []}
    bodies = {b["name"]: b for b in record["bodies"]}
    assert bodies["Joint1"]["not_determined_by_data"] == ["Joint1.m"]
    assert [n for n, b in bodies.items() if "not_determined_by_data" in b] == ["Joint1"]
    assert bodies["Joint1"]["mass"] == pytest.approx(outcome.fits["dm"].result.theta[0], rel=1e-12)


def test_the_results_own_record_says_it_too(written):
    """IdentificationResult.as_dict() (the study's JSON, a library user's record) carries the same notes as
    parameters.yaml: on the completed parameter and on its body."""
    outcome, out = written
    result = outcome.fits["dm"].result
    d = result.as_dict()
    assert [p["name"] for p in d["parameters"] if p.get("determined_by_data") is False] == ["Joint1.m"]
    assert {p["note"] for p in d["parameters"] if "note" in p} == {NOT_DETERMINED}
    assert [b["name"] for b in d["bodies"] if "not_determined_by_data" in b] == ["Joint1"]
    yaml_bodies = yaml.safe_load((out / "parameters.yaml").read_text())["methods"]["dm"]["bodies"]
    assert [b.get("not_determined_by_data") for b in d["bodies"]] == [b.get("not_determined_by_data") for b in yaml_bodies]


def test_files_carrying_the_plausible_theta_have_no_such_comment(tmp_path):
    """θ_plausible (the default) takes an unseen mass from the prior, not from the completion (0.29 kg here against
    the completed 0.23 kg): the files carry no note, parameters.yaml's bodies (of θ̂) still do."""
    outcome = fit_robot(FitConfig.from_dict(small_config(methods=["dm"], references={})))
    fit = outcome.fits["dm"]
    assert fit.plausible is not None and fit.result.info["projected_names"] == ["Joint1.m"]
    k = outcome.rigid.parameters.index("Joint1.m")
    assert fit.plausible.determined_by[k] == "prior" and abs(fit.plausible.theta[k] - fit.result.theta[k]) > 0.05
    write_fit(outcome, tmp_path / "out")
    for name in ("dm.urdf", "dm.xml"):
        assert "not determined" not in (tmp_path / "out" / name).read_text()
    record = yaml.safe_load((tmp_path / "out" / "parameters.yaml").read_text())["methods"]["dm"]
    marked = {b["name"]: b["not_determined_by_data"] for b in record["bodies"] if "not_determined_by_data" in b}
    assert marked == {"Joint1": ["Joint1.m"]} and len(record["bodies"]) > 2  # the others: Joint2, joint terms
