"""A corpus of malformed inputs, tried as a user would: URDFs, configs, logs and flags through the
command line (exit code and the exact message fragment), and library calls (error type and message).

Exit codes: 0 success (a warning case: the fit goes on and says so), 1 a requested fit failed,
2 bad input. ``test_no_case_raises_anything_but_a_dualid_error`` runs every CLI case again with
--debug and fails on any exception that is not a DualidError, an OSError or SystemExit.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
import pinocchio as pin
import pytest
import yaml
from typer.testing import CliRunner

from dualid.cli import app
from dualid.errors import DualidError

runner = CliRunner()

URDF = """<?xml version="1.0"?>
<robot name="two_link">
  <link name="base"/>
  <link name="link1">
    <inertial>
      <origin xyz="0 0 -0.2" rpy="0 0 0"/>
      <mass value="1.0"/>
      <inertia ixx="0.02" ixy="0" ixz="0" iyy="0.021" iyz="0" izz="0.004"/>
    </inertial>
  </link>
  <link name="link2">
    <inertial>
      <origin xyz="0 0 -0.15" rpy="0 0 0"/>
      <mass value="0.5"/>
      <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.011" iyz="0" izz="0.002"/>
    </inertial>
  </link>
  <joint name="Joint1" type="revolute">
    <origin xyz="0 0 0" rpy="0 0 0"/>
    <parent link="base"/>
    <child link="link1"/>
    <axis xyz="1 0 0"/>
    <limit lower="-3.2" upper="3.2" effort="10" velocity="20"/>
    <dynamics damping="0.01" friction="0.0"/>
  </joint>
  <joint name="Joint2" type="revolute">
    <origin xyz="0 0 -0.4" rpy="0 0 0"/>
    <parent link="link1"/>
    <child link="link2"/>
    <axis xyz="1 0 0"/>
    <limit lower="-3.2" upper="3.2" effort="10" velocity="20"/>
    <dynamics damping="0.02" friction="0.0"/>
  </joint>
</robot>
"""

RATE = 500.0  # [Hz]


def good_frame(T: int = 1000, seed: int = 0) -> pd.DataFrame:
    """A 2 s, 500 Hz log of the two-link arm in the DFKI column layout; τ from pin.rnea."""
    model = pin.buildModelFromXML(URDF)
    data = model.createData()
    t = np.arange(T) / RATE
    w = np.array([2.1, 3.3]) * (1 + 0.05 * seed)
    q = np.stack([np.sin(w[0] * t), 0.8 * np.sin(w[1] * t + 0.3)], axis=1)
    v = np.stack([w[0] * np.cos(w[0] * t), 0.8 * w[1] * np.cos(w[1] * t + 0.3)], axis=1)
    a = np.stack([-w[0] ** 2 * np.sin(w[0] * t), -0.8 * w[1] ** 2 * np.sin(w[1] * t + 0.3)], axis=1)
    tau = np.stack([pin.rnea(model, data, q[k], v[k], a[k]) for k in range(T)])
    return pd.DataFrame({"time": t, "pos_meas1": q[:, 0], "pos_meas2": q[:, 1], "vel_meas1": v[:, 0],
                         "vel_meas2": v[:, 1], "tau_meas1": tau[:, 0], "tau_meas2": tau[:, 1]})


GOOD = good_frame()


def _text(result) -> str:
    return " ".join((result.output + (result.stderr if result.stderr_bytes is not None else "")).split())


def write_urdf(tmp: Path, text: str = URDF, name: str = "robot.urdf") -> Path:
    path = tmp / name
    path.write_text(text)
    return path


def write_log(tmp: Path, df: pd.DataFrame | None = None, name: str = "run.csv") -> Path:
    df = GOOD if df is None else df
    path = tmp / name
    if path.suffix == ".parquet":
        df.to_parquet(path, index=False)
    elif path.suffix == ".npz":
        np.savez(path, **{c: df[c].to_numpy() for c in df.columns})
    else:
        df.to_csv(path, index=False)
    return path


def write_config(tmp: Path, extra: dict | None = None, drop=(), name: str = "fit.yaml") -> Path:
    d = {"model": {"urdf": str(write_urdf(tmp))}, "train": [str(write_log(tmp))], "methods": ["ols"]}
    d.update(extra or {})
    for k in drop:
        d.pop(k)
    path = tmp / name
    path.write_text(yaml.safe_dump(d))
    return path


def fit(tmp: Path, urdf: Path | None = None, logs=None, *extra: str) -> list[str]:
    urdf = write_urdf(tmp) if urdf is None else urdf
    logs = [write_log(tmp)] if logs is None else logs
    return ["fit", "--model", str(urdf), *[a for p in logs for a in ("--data", str(p))], "--method", "ols",
            "--out", str(tmp / "out"), *extra]


@dataclass(frozen=True)
class Case:
    id: str
    args: Callable[[Path], list[str]]  # builds its files in a temporary folder, returns the CLI arguments
    code: int
    message: str  # a fragment of the output (whitespace-normalized)


CASES: list[Case] = []


def case(id: str, code: int, message: str):
    def register(fn):
        CASES.append(Case(id, fn, code, message))
        return fn
    return register


# --- URDFs (exit 2 before any log is read) ----------------------------------------------------------
def _urdf_case(id: str, old: str | None, new: str, message: str, command: str = "fit") -> None:
    def args(tmp: Path) -> list[str]:
        text = new if old is None else URDF.replace(old, new, 1)
        assert old is None or old in URDF, old
        urdf = write_urdf(tmp, text)
        if command == "validate":
            return ["validate", "--model", str(urdf), "--data", str(write_log(tmp))]
        return fit(tmp, urdf)
    CASES.append(Case(f"urdf-{command}-{id}", args, 2, message))


URDF_CASES = [
    ("empty", None, "", "not a valid URDF: XML parse error at line 1, column 0 (no element found"),
    ("truncated", None, URDF[:400], "not a valid URDF: XML parse error at line"),
    ("not-xml", None, "this is not a robot\n", "not a valid URDF: XML parse error at line 1, column 0 (syntax error"),
    ("json", None, '{"robot": {"name": "x"}}', "not a valid URDF: XML parse error at line 1"),
    ("sdf-root", None, '<sdf version="1.6"><model name="x"/></sdf>', "not a URDF: expected a <robot> root element, got <sdf>"),
    ("no-links", None, '<robot name="x"/>', "the <robot> has no links and no joints"),
    ("mass-nan", '<mass value="1.0"/>', '<mass value="nan"/>', "link 'link1' <inertial> <mass value>: expected 1 finite number, got 'nan'"),
    ("mass-word", '<mass value="1.0"/>', '<mass value="heavy"/>', "<mass value>: expected 1 finite number, got 'heavy'"),
    ("mass-inf", '<mass value="0.5"/>', '<mass value="inf"/>', "link 'link2' <inertial> <mass value>: expected 1 finite number, got 'inf'"),
    ("mass-negative", '<mass value="1.0"/>', '<mass value="-1"/>', "link 'link1' <inertial> <mass value>: expected a mass ≥ 0 kg, got '-1'"),
    ("mass-two-numbers", '<mass value="1.0"/>', '<mass value="1 2"/>', "expected 1 finite number, got '1 2'"),
    ("mass-no-value", '<mass value="1.0"/>', "<mass/>", "<mass value>: expected 1 finite number, got None"),
    ("mass-missing", '<mass value="1.0"/>', "", "link 'link1' <inertial> has no <mass value=...>"),
    ("mimic-unknown-joint", '<dynamics damping="0.02" friction="0.0"/>', '<dynamics damping="0.02" friction="0.0"/><mimic joint="Joint9"/>',
     "joint 'Joint2' <mimic joint>: expected the name of a joint of the URDF, got 'Joint9'"),
    ("inertia-nan", 'ixx="0.02"', 'ixx="nan"', "link 'link1' <inertial> <inertia ixx>: expected 1 finite number, got 'nan'"),
    ("inertia-word", 'iyy="0.011"', 'iyy="big"', "link 'link2' <inertial> <inertia iyy>: expected 1 finite number, got 'big'"),
    ("inertia-negative", 'ixx="0.02"', 'ixx="-0.02"', "<inertia>: expected a positive semi-definite matrix, got principal moments"),
    ("inertia-triangle", 'izz="0.004"', 'izz="0.1"', "break the triangle inequality"),
    ("inertia-products", 'ixy="0" ixz="0" iyy="0.021"', 'ixy="0.5" ixz="0" iyy="0.021"', "expected a positive semi-definite matrix"),
    ("inertia-missing", '<inertia ixx="0.02" ixy="0" ixz="0" iyy="0.021" iyz="0" izz="0.004"/>', "", "link 'link1' <inertial> has a mass of 1.0 kg but no <inertia>"),
    ("inertial-origin-short", '<origin xyz="0 0 -0.2" rpy="0 0 0"/>', '<origin xyz="0 0" rpy="0 0 0"/>', "link 'link1' <inertial> <origin xyz>: expected 3 finite numbers, got '0 0'"),
    ("inertial-origin-words", '<origin xyz="0 0 -0.15" rpy="0 0 0"/>', '<origin xyz="0 0 -0.15" rpy="a b c"/>', "link 'link2' <inertial> <origin rpy>: expected 3 finite numbers, got 'a b c'"),
    ("axis-zero", '<axis xyz="1 0 0"/>', '<axis xyz="0 0 0"/>', "joint 'Joint1' <axis xyz>: expected a non-zero direction, got '0 0 0'"),
    ("axis-short", '<axis xyz="1 0 0"/>', '<axis xyz="1 0"/>', "joint 'Joint1' <axis xyz>: expected 3 finite numbers, got '1 0'"),
    ("axis-nan", '<axis xyz="1 0 0"/>', '<axis xyz="nan 0 0"/>', "joint 'Joint1' <axis xyz>: expected 3 finite numbers, got 'nan 0 0'"),
    ("axis-empty", '<axis xyz="1 0 0"/>', '<axis xyz=""/>', "joint 'Joint1' <axis xyz>: expected 3 finite numbers, got ''"),
    ("duplicate-link", '<link name="link2">', '<link name="link1">', "link names must be unique; ['link1'] appear more than once"),
    ("duplicate-joint", '<joint name="Joint2"', '<joint name="Joint1"', "joint names must be unique; ['Joint1'] appear more than once"),
    ("link-no-name", '<link name="base"/>', "<link/>", "a <link> has no name"),
    ("joint-type", 'type="revolute"', 'type="hinge"', "joint 'Joint1': unknown type 'hinge'; expected one of revolute, continuous"),
    ("joint-no-type", ' type="revolute"', "", "joint 'Joint1': unknown type None"),
    ("child-undeclared", '<child link="link2"/>', '<child link="link3"/>', "joint 'Joint2': child link 'link3' is not declared"),
    ("parent-undeclared", '<parent link="link1"/>', '<parent link="lnk1"/>', "joint 'Joint2': parent link 'lnk1' is not declared"),
    ("child-missing", '<child link="link1"/>', "", "joint 'Joint1' has no <child link=...>"),
    ("joint-origin", '<origin xyz="0 0 -0.4" rpy="0 0 0"/>', '<origin xyz="0 0 x" rpy="0 0 0"/>', "joint 'Joint2' <origin xyz>: expected 3 finite numbers, got '0 0 x'"),
    ("damping-negative", 'damping="0.02"', 'damping="-0.1"', "joint 'Joint2' <dynamics damping>: expected a value ≥ 0, got '-0.1'"),
    ("friction-nan", 'damping="0.01" friction="0.0"', 'damping="0.01" friction="nan"', "joint 'Joint1' <dynamics friction>: expected 1 finite number, got 'nan'"),
    ("all-fixed", None, URDF.replace('type="revolute"', 'type="fixed"'), "the model has no moving joint, so nothing to identify"),
]
for _id, _old, _new, _msg in URDF_CASES:
    _urdf_case(_id, _old, _new, _msg)
for _id, _old, _new, _msg in URDF_CASES[:3] + URDF_CASES[6:10] + URDF_CASES[22:23] + URDF_CASES[35:37]:
    _urdf_case(_id, _old, _new, _msg, command="validate")


@case("urdf-missing-file", 2, "no URDF file at")
def _(tmp):
    return fit(tmp, tmp / "nowhere.urdf")


@case("urdf-is-a-directory", 2, "no URDF file at")
def _(tmp):
    (tmp / "dir.urdf").mkdir()
    return fit(tmp, tmp / "dir.urdf")


# --- configs ------------------------------------------------------------------------------------
def _config_case(id: str, extra: dict, message: str, code: int = 2, drop=()) -> None:
    CASES.append(Case(f"config-{id}", lambda tmp: ["fit", "--config", str(write_config(tmp, extra, drop)),
                                                   "--out", str(tmp / "out")], code, message))


DIFF = {"differentiate": {"window": 0.05}}
for _id, _extra, _msg in [
    ("unknown-key", {"method": ["ols"]}, "config: unknown keys ['method']; known keys: ['model', 'columns'"),
    ("gravity-two", {"model": {"urdf": "r.urdf", "gravity": [0, 1]}}, "model.gravity: expected 3 numbers [m/s²], got [0, 1]"),
    ("gravity-word", {"model": {"urdf": "r.urdf", "gravity": "down"}}, "model.gravity: expected 3 numbers [m/s²], got 'down'"),
    ("gravity-text", {"model": {"urdf": "r.urdf", "gravity": ["0", "0", "fast"]}}, "model.gravity: expected 3 numbers [m/s²]"),
    ("floating-base-word", {"model": {"urdf": "r.urdf", "floating_base": "yes"}}, "model.floating_base: expected true or false, got 'yes'"),
    ("model-unknown-key", {"model": {"urdf": "r.urdf", "mesh": "x"}}, "model: unknown keys ['mesh']"),
    ("model-no-urdf", {"model": {"floating_base": False}}, "model: missing required key 'urdf'"),
    ("coulomb-velocity-word", {"joint_terms": {"coulomb_velocity": "fast"}}, "joint_terms.coulomb_velocity: expected a number, got 'fast'"),
    ("coulomb-velocity-negative", {"joint_terms": {"coulomb_velocity": -1}}, "joint_terms.coulomb_velocity: expected a velocity > 0 [rad/s], got -1"),
    ("coulomb-velocity-zero", {"joint_terms": {"coulomb_velocity": 0}}, "joint_terms.coulomb_velocity: expected a velocity > 0 [rad/s], got 0"),
    ("viscous-word", {"joint_terms": {"viscous": "no"}}, "joint_terms.viscous: expected true or false, got 'no'"),
    ("joint-terms-unknown-joint", {"joint_terms": {"joints": ["Joint9"]}}, "joint_terms.joints: joints ['Joint9'] are not in the model"),
    ("joint-terms-list", {"joint_terms": [1, 2]}, "joint_terms: expected a mapping with keys"),
    ("gamma-word", {"prior": {"gamma": "big"}}, "prior.gamma: expected a number, got 'big'"),
    ("gamma-negative", {"prior": {"gamma": -1}}, "prior.gamma: expected a number ≥ 0, got -1.0"),
    ("gamma-dict", {"prior": {"gamma": {"per_equation": 1}}}, "prior.gamma: expected a number, got {'per_equation': 1}"),
    ("per-equation-word", {"prior": {"per_equation": "yes"}}, "prior.per_equation: expected true or false, got 'yes'"),
    ("bounds-reversed", {"bounds": {"Joint1.m": [2, 1]}}, "bounds: 'Joint1.m' has lower 2.0 > upper 1.0"),
    ("bounds-not-pair", {"bounds": {"Joint1.m": 3}}, "bounds: 'Joint1.m' must be [lower, upper] (use null for none), got 3"),
    ("bounds-word", {"bounds": {"Joint1.m": ["a", 1]}}, "bounds.Joint1.m[0]: expected a number, got 'a'"),
    ("bounds-list", {"bounds": [1, 2]}, "bounds: expected a mapping {parameter name: [lower, upper]}, got [1, 2]"),
    ("bounds-unknown-parameter", {"bounds": {"Joint9.m": [0, 1]}}, "bounds: unknown parameters ['Joint9.m']"),
    ("method-unknown", {"methods": ["lasso"]}, "unknown method 'lasso'; known methods: ols"),
    ("methods-empty", {"methods": []}, "methods: choose at least one of ols"),
    ("preprocessing-dict", {"preprocessing": {"resample": 500}}, "preprocessing: expected a list of steps {name: parameters}"),
    ("step-unknown", {"preprocessing": [{"smooth": {}}]}, "unknown preprocessing step 'smooth' (step 0); known steps:"),
    ("step-two-keys", {"preprocessing": [{"resample": {}, "trim": {}}]}, "preprocessing step 0 must be a one-key mapping {name: parameters}"),
    ("step-bad-parameter", {"preprocessing": [{"resample": {"hz": 5}}]}, "preprocessing step 0 (resample): bad parameters {'hz': 5}"),
    ("step-parameters-list", {"preprocessing": [{"resample": [500]}]}, "preprocessing.0.resample: Input should be a valid dictionary (got [500])"),
    ("window-negative", {"preprocessing": [{"differentiate": {"window": -0.1}}]}, "differentiate: window must be a positive number of seconds, got -0.1"),
    ("window-zero", {"preprocessing": [{"differentiate": {"window": 0}}]}, "differentiate: window must be a positive number of seconds, got 0"),
    ("window-long", {"preprocessing": [{"differentiate": {"window": 100}}]}, "Savitzky–Golay window of 50001 samples is longer than the signal (1000 samples)"),
    ("polyorder-one", {"preprocessing": [{"differentiate": {"polyorder": 1}}]}, "differentiate: polyorder must be an integer ≥ 2"),
    ("diff-method", {"preprocessing": [{"differentiate": {"method": "spline"}}]}, "differentiate: method must be 'savgol' or 'central', got 'spline'"),
    ("cutoff-negative", {"preprocessing": [{"filter_lowpass": {"cutoff": -5}}, DIFF]}, "low-pass cutoff must be in (0, 250) Hz (Nyquist at fs=500 Hz), got -5"),
    ("cutoff-above-nyquist", {"preprocessing": [{"filter_lowpass": {"cutoff": 1000}}, DIFF]}, "low-pass cutoff must be in (0, 250) Hz"),
    ("filter-field", {"preprocessing": [{"filter_lowpass": {"cutoff": 20, "fields": ["torque"]}}, DIFF]}, "filter_lowpass: unknown fields ['torque']"),
    ("downsample-zero", {"preprocessing": [DIFF, {"downsample": {"factor": 0}}]}, "downsample: factor must be a positive integer, got 0"),
    ("downsample-fraction", {"preprocessing": [DIFF, {"downsample": {"factor": 2.5}}]}, "downsample: factor must be a positive integer, got 2.5"),
    ("downsample-cutoff-negative", {"preprocessing": [DIFF, {"downsample": {"factor": 2, "cutoff": -1}}]}, "downsample: cutoff must be a positive number of Hz, got -1"),
    ("resample-negative", {"preprocessing": [{"resample": {"rate": -1}}, DIFF]}, "resample: rate must be a positive number of Hz, got -1"),
    ("resample-too-fast", {"preprocessing": [{"resample": {"rate": 50000}}, DIFF]}, "100 samples would be invented per logged one"),
    ("trim-reversed", {"preprocessing": [{"trim": {"start": 2, "stop": 1}}, DIFF]}, "trim: start must be before stop, got start=2, stop=1"),
    ("trim-word", {"preprocessing": [{"trim": {"start": "a"}}, DIFF]}, "trim: start must be a number of seconds or null, got 'a'"),
    ("trim-outside", {"preprocessing": [{"trim": {"start": 50, "stop": 60}}, DIFF]}, "trim: [50, 60] s keeps 0 samples"),
    ("no-differentiate", {"preprocessing": [{"resample": {"rate": 500}}]}, "no accelerations after preprocessing; add a 'differentiate' step"),
    ("columns-list", {"columns": ["time"]}, "columns: expected a column map (time, joints, units), got ['time']"),
    ("columns-unknown-key", {"columns": {"time": "time", "joint": {}}}, "columns.joint: Extra inputs are not permitted (got {})"),
    ("columns-no-effort", {"columns": {"joints": {"Joint1": {"position": "pos_meas1"}, "Joint2": {"position": "pos_meas2"}}}},
     "columns.joints.Joint1.effort: Field required (got {'position': 'pos_meas1'})"),
    ("columns-unit", {"columns": {"joints": {"Joint1": {"position": "pos_meas1", "effort": "tau_meas1", "velocity": "vel_meas1"},
                                            "Joint2": {"position": "pos_meas2", "effort": "tau_meas2", "velocity": "vel_meas2"}},
                                 "units": {"effort": "kNm"}}}, "column map: units.effort: unknown effort unit 'kNm'; allowed: ['N m', 'N mm', 'N']"),
    ("columns-extra-joint", {"columns": {"joints": {"Joint1": {"position": "pos_meas1", "effort": "tau_meas1"},
                                                   "Joint2": {"position": "pos_meas2", "effort": "tau_meas2"},
                                                   "Joint3": {"position": "pos_meas2", "effort": "tau_meas2"}}}},
     "column map names joints ['Joint3'] that are not in the model"),
    ("columns-missing-joint", {"columns": {"joints": {"Joint1": {"position": "pos_meas1", "effort": "tau_meas1"}}}},
     "column map has no columns for model joints ['Joint2']"),
    ("columns-wrong-name", {"columns": {"joints": {"Joint1": {"position": "q1[rad]", "effort": "tau_meas1", "velocity": "vel_meas1"},
                                                  "Joint2": {"position": "pos_meas2", "effort": "tau_meas2", "velocity": "vel_meas2"}}}},
     "missing columns ['q1[rad]']; available columns: ['time', 'pos_meas1'"),
    ("xcorr-negative", {"validation": {"xcorr_window": -1}}, "validation.xcorr_window: expected seconds ≥ 0, got -1.0"),
    ("xcorr-word", {"validation": {"xcorr_window": "wide"}}, "validation.xcorr_window: expected a number, got 'wide'"),
    ("references-missing", {"references": {"lab": "nowhere.yml"}}, "DFKI reference parameters not found:"),
    ("references-list", {"references": ["a.yml"]}, "references: expected a mapping {label: reference parameters .yml}"),
    ("prior-source-missing", {"methods": ["logdet"], "prior": {"source": "nowhere.yaml"}}, "prior.source parameters file not found:"),
    ("train-missing-file", {"train": ["nowhere.csv"]}, "log file not found: "),
    ("test-missing-file", {"test": ["nowhere.csv"]}, "log file not found: "),
    ("train-number", {"train": 5}, "train: expected a list of file paths, got 5"),
]:
    _config_case(_id, _extra, _msg)
_config_case("missing-model", {}, "config: missing required keys ['model']", drop=("model",))
_config_case("missing-train", {}, "config: missing required keys ['train']", drop=("train",))


def _raw_config(id: str, text: str, message: str) -> None:
    def args(tmp: Path) -> list[str]:
        path = tmp / "fit.yaml"
        path.write_text(text)
        return ["fit", "--config", str(path), "--out", str(tmp / "out")]
    CASES.append(Case(f"config-{id}", args, 2, message))


_config_case("schema-references-list-value", {"references": {"lab": [1]}}, "references.lab: expected a file path, got [1]")
_config_case("schema-time-list", {"columns": {"time": ["t"], "joints": {}}}, "columns.time: Input should be a valid string (got ['t'])")
_config_case("schema-motor-no-kt", {"columns": {"joints": {"Joint1": {"position": "pos_meas1", "effort": {"current": "I1"}}}}},
             "columns.joints.Joint1.effort.torque_constant: Field required (got {'current': 'I1'})")
_config_case("schema-out-list", {"out": ["a", "b"]}, "out: expected a file path, got ['a', 'b']")
_raw_config("yaml-unclosed", "model: [robot.urdf\ntrain: a.csv\n", "YAML syntax error at line 2")
_raw_config("yaml-tab", "model:\n\turdf: robot.urdf\n", "YAML syntax error at line 2, column 1")
_raw_config("yaml-bad-indent", "model:\n  urdf: r.urdf\n   floating_base: true\n", "YAML syntax error at line 3")
_raw_config("yaml-list", "- model\n- train\n", "expected a mapping of keys to values at the top level, got list")
_raw_config("yaml-scalar", "just words\n", "expected a mapping of keys to values at the top level, got str")
_raw_config("yaml-empty", "", "config: missing required keys ['model', 'train']")


@case("config-missing-file", 2, "config file not found:")
def _(tmp):
    return ["fit", "--config", str(tmp / "nowhere.yaml"), "--out", str(tmp / "out")]


@case("config-is-a-directory", 2, "is a directory, expected a file")
def _(tmp):
    return ["fit", "--config", str(tmp), "--out", str(tmp / "out")]


@case("references-yaml-syntax", 2, "DFKI reference parameters")
def _(tmp):
    (tmp / "ref.yml").write_text("m1: [0.5\nm2: 1\n")
    return ["fit", "--config", str(write_config(tmp, {"references": {"lab": str(tmp / "ref.yml")}})), "--out", str(tmp / "o")]


@case("references-missing-keys", 2, "missing DFKI parameters")
def _(tmp):
    (tmp / "ref.yml").write_text("m1: 0.5\n")
    return ["fit", "--config", str(write_config(tmp, {"references": {"lab": str(tmp / "ref.yml")}})), "--out", str(tmp / "o")]


@case("prior-source-bad-json", 2, "JSON syntax error at line 1")
def _(tmp):
    (tmp / "prior.json").write_text("{parameters: ]")
    return ["fit", "--config", str(write_config(tmp, {"methods": ["logdet"], "prior": {"source": str(tmp / "prior.json")}})),
            "--out", str(tmp / "o")]


# --- logs ---------------------------------------------------------------------------------------
def _log_case(id: str, make: Callable[[Path], Path], message: str, code: int = 2, test: bool = False) -> None:
    def args(tmp: Path) -> list[str]:
        bad = make(tmp)
        if test:
            return fit(tmp, None, None, "--test", str(bad))
        return fit(tmp, None, [bad])
    CASES.append(Case(f"log-{id}{'-test' if test else ''}", args, code, message))


def _with(change: Callable[[pd.DataFrame], pd.DataFrame], name: str = "bad.csv"):
    return lambda tmp: write_log(tmp, change(GOOD.copy()), name)


def _text_file(text: str | bytes, name: str):
    def make(tmp: Path) -> Path:
        p = tmp / name
        p.write_bytes(text) if isinstance(text, bytes) else p.write_text(text)
        return p
    return make


def _set(col, row, value):
    def change(df):
        df[col] = df[col].astype(object) if isinstance(value, str) else df[col]
        df.loc[row, col] = value
        return df
    return change


def _duplicate_columns(tmp: Path) -> Path:
    p = tmp / "dup.csv"
    df = GOOD.copy()
    df.insert(3, "tau_meas1_", 1000 * df["tau_meas1"])
    df.to_csv(p, index=False)
    p.write_text(p.read_text().replace("tau_meas1_", "tau_meas1", 1))
    return p


def _ms(df):
    df["time"] *= 1000
    return df


def _gap(df):
    df.loc[500:, "time"] += 1000.0
    return df


def _back(df):
    df.loc[300, "time"] = df.loc[100, "time"]
    return df


def _repeat(df):
    df.loc[41, "time"] = df.loc[40, "time"]
    return df


def _npz_2d(tmp: Path) -> Path:
    p = tmp / "run.npz"
    np.savez(p, time=GOOD["time"].to_numpy(), q=GOOD[["pos_meas1", "pos_meas2"]].to_numpy())
    return p


def _npz_lengths(tmp: Path) -> Path:
    p = tmp / "run.npz"
    np.savez(p, **{c: GOOD[c].to_numpy()[: (500 if c == "tau_meas2" else None)] for c in GOOD.columns})
    return p


LOG_CASES = [
    ("empty", _text_file("", "empty.csv"), "empty.csv: log is empty (no rows)"),
    ("header-only", _text_file(",".join(GOOD.columns) + "\n", "head.csv"), "head.csv: log is empty (no rows)"),
    ("one-row", _with(lambda df: df.iloc[:1]), "bad.csv: log has 1 row; need at least 2"),
    ("duplicated-columns", _duplicate_columns, "column names appear more than once in the header: {'tau_meas1': [3, 6]}"),
    ("missing-column", _with(lambda df: df.drop(columns=["tau_meas2"])), "lacks the default DFKI columns ['tau_meas2']"),
    ("bracket-columns", _with(lambda df: df.rename(columns={"pos_meas1": "q1[rad]", "tau_meas1": "tau1[nm]"})),
     "available: ['time', 'q1[rad]', 'pos_meas2', 'vel_meas1', 'vel_meas2', 'tau1[nm]', 'tau_meas2']"),
    ("nan", _with(_set("pos_meas1", 17, np.nan)), "column 'pos_meas1' has non-finite values (NaN or inf), first at row 17"),
    ("inf", _with(_set("tau_meas2", 5, np.inf)), "column 'tau_meas2' has non-finite values (NaN or inf), first at row 5"),
    ("text-cell", _with(_set("vel_meas2", 3, "fast")), "column 'vel_meas2' is not numeric (dtype object)"),
    ("repeated-time", _with(_repeat), "time column 'time' repeats a time stamp: rows 40 and 41 both have 0.08"),
    ("time-goes-back", _with(_back), "time column 'time' must be strictly increasing; row 299 has 0.598 and row 300 has 0.2 (time goes back)"),
    ("gap", _with(_gap), "a gap of 1000 s"),
    ("time-in-ms", _with(_ms), "bad: the log's rate is 0.5 Hz (median step 2 s), too slow to derive default preprocessing"),
    ("time-in-ms-warns", _with(_ms), "bad.csv: the median time step is 2 s (0.5 Hz), slow for a robot log"),
    ("unknown-format", _text_file("time\n0\n1\n", "run.txt"), "run.txt: unknown log format '.txt'; expected one of .csv, .parquet, .npz"),
    ("missing", lambda tmp: tmp / "nowhere.csv", "log file not found:"),
    ("directory", lambda tmp: (tmp / "d.csv").mkdir() or tmp / "d.csv", "Is a directory"),
    ("binary-csv", _text_file(bytes(range(256)) * 4, "bin.csv"), "cannot read it as CSV"),
    ("garbage-parquet", _text_file("not parquet", "run.parquet"), "run.parquet: cannot read it as Parquet"),
    ("garbage-npz", _text_file("not npz", "run.npz"), "run.npz: cannot read it as .npz"),
    ("npz-lengths", _npz_lengths, "npz channels have different lengths"),
    ("short", _with(lambda df: df.iloc[:10]), "bad: 10 samples are too few to derive default preprocessing (need 100)"),
    ("tau-1e300", _with(lambda df: df.assign(tau_meas1=df["tau_meas1"] * 1e300)),
     "column 'tau_meas1' reaches 2.91e+300 in SI units; more than 1e+12 is not a robot measurement"),
    ("ragged-csv", _text_file("time,pos_meas1\n0,1,2,3\n", "ragged.csv"),
     "ragged.csv: cannot read it as CSV (ArrowInvalid: CSV parse error: Expected 2 columns, got 4: 0,1,2,3)"),
]
for _id, _make, _msg in LOG_CASES:
    _log_case(_id, _make, _msg)
for _id, _make, _msg in LOG_CASES[6:12]:
    _log_case(_id, _make, _msg, test=True)
_log_case("time-in-ms", _with(_ms), "1000 samples would be invented per logged one. Is time logged in ms? set the "
          "column map's units: {time: ms}", test=True)


@case("config-time-in-ms-with-a-stated-rate", 2, "the log's median step is 2 s (0.5 Hz), 1000 × the step at 500 Hz")
def _(tmp):
    ms = write_log(tmp, _ms(GOOD.copy()), "ms.csv")
    return ["fit", "--config", str(write_config(tmp, {"train": [str(ms)], "preprocessing": [{"resample": {"rate": 500}}, DIFF]})),
            "--out", str(tmp / "out")]


@case("config-cutoff-below-motion", 0, "filter_lowpass cutoff 0.8 Hz is below the motion band")
def _(tmp):
    return ["fit", "--config", str(write_config(tmp, {"preprocessing": [DIFF, {"filter_lowpass": {"cutoff": 0.8}}]})),
            "--out", str(tmp / "out")]


@case("config-window-beyond-period", 0, "a differentiate window of 1.5 s is longer than the period")
def _(tmp):
    return ["fit", "--config", str(write_config(tmp, {"preprocessing": [{"differentiate": {"window": 1.5}}]})),
            "--out", str(tmp / "out")]

# warnings: the fit goes on (exit 0) and says what it saw
_log_case("velocity-in-deg", _with(lambda df: df.assign(vel_meas1=df["vel_meas1"] * 180 / np.pi)),
          "joint 'Joint1': the logged velocity is 57.3 × dq/dt in RMS", code=0)


@case("log-train-equals-test", 0, "is the same data as training log")
def _(tmp):
    return fit(tmp, None, None, "--test", str(write_log(tmp, GOOD, "copy.csv")))


@case("log-test-overlaps-train", 0, "shares 50% of its rows with training log")
def _(tmp):
    later = good_frame(500, seed=2).assign(time=lambda d: d["time"] + 2.0)  # new data after the shared half
    return fit(tmp, None, None, "--test", str(write_log(tmp, pd.concat([GOOD.iloc[500:], later]), "half.csv")))


@case("log-train-twice", 0, "are the same data; it is counted twice")
def _(tmp):
    p = write_log(tmp)
    return fit(tmp, None, [p, p])


@case("good-fit-exits-0", 0, "wrote parameters.yaml, parameters.json, ols.urdf, ols.xml, identifiability.txt, "
                             "report.md, report.html and ")
def _(tmp):
    return fit(tmp, None, None, "--test", str(write_log(tmp, good_frame(seed=1), "test.csv")))


# --- flags --------------------------------------------------------------------------------------
def _flag_case(id: str, args: Callable[[Path], list[str]], message: str, code: int = 2) -> None:
    CASES.append(Case(f"flags-{id}", args, code, message))


def _existing_file(tmp: Path) -> Path:
    (tmp / "out.txt").write_text("keep me")
    return tmp / "out.txt"


def _non_empty_dir(tmp: Path) -> Path:
    (tmp / "full").mkdir()
    (tmp / "full" / "x").write_text("x")
    return tmp / "full"


for _id, _args, _msg in [
    ("fit-nothing", lambda tmp: ["fit", "--out", str(tmp / "o")], "give --model ROBOT.urdf and at least one --data RUN.csv, or a --config file"),
    ("fit-model-only", lambda tmp: ["fit", "--model", str(write_urdf(tmp)), "--out", str(tmp / "o")], "give --model ROBOT.urdf and at least one --data"),
    ("fit-no-out", lambda tmp: fit(tmp)[:-2], "no output directory: pass --out DIR (or set 'out' in the config)"),
    ("fit-method", lambda tmp: fit(tmp) + ["--method", "lasso"], "unknown method 'lasso'; known methods:"),
    ("fit-out-file", lambda tmp: fit(tmp)[:-1] + [str(_existing_file(tmp))], "exists and is a file, expected a directory"),
    ("fit-out-file-force", lambda tmp: fit(tmp)[:-1] + [str(_existing_file(tmp)), "--force"], "exists and is a file, expected a directory"),
    ("fit-out-non-empty", lambda tmp: fit(tmp)[:-1] + [str(_non_empty_dir(tmp))], "exists and is not empty; choose another or pass --force"),
    ("fit-out-below-file", lambda tmp: fit(tmp)[:-1] + [str(_existing_file(tmp) / "o")], "out.txt is a file, so no directory can be made below it"),
    ("fit-unknown-flag", lambda tmp: fit(tmp) + ["--speed", "3"], "No such option: --speed"),
    ("fit-force-value", lambda tmp: fit(tmp) + ["--force", "yes"], "Got unexpected extra argument"),
    ("validate-no-data", lambda tmp: ["validate", "--model", str(write_urdf(tmp))], "Missing option '--data'"),
    ("validate-out-file", lambda tmp: ["validate", "--model", str(write_urdf(tmp)), "--data", str(write_log(tmp)),
                                       "--out", str(_existing_file(tmp))], "exists and is a file, expected a directory"),
    ("validate-missing-log", lambda tmp: ["validate", "--model", str(write_urdf(tmp)), "--data", str(tmp / "x.csv")], "log file not found:"),
    ("simulate-system", lambda tmp: ["simulate", "segway", "--out", str(tmp / "o")], "unknown system 'segway'; expected one of pan-tilt, crazyflie, landsalp"),
    ("simulate-format", lambda tmp: ["simulate", "pan-tilt", "--out", str(tmp / "o"), "--format", "csv"], "--format: expected one of parquet, npz, got 'csv'"),
    ("simulate-noise", lambda tmp: ["simulate", "pan-tilt", "--out", str(tmp / "o"), "--noise", "loud"], "--noise: expected one of realistic, ideal, none, got 'loud'"),
    ("simulate-size", lambda tmp: ["simulate", "pan-tilt", "--out", str(tmp / "o"), "--size", "huge"], "--size: expected one of default, small, got 'huge'"),
    ("simulate-seed", lambda tmp: ["simulate", "pan-tilt", "--out", str(tmp / "o"), "--seed", "abc"], "Invalid value for '--seed'"),
    ("simulate-out-file", lambda tmp: ["simulate", "pan-tilt", "--size", "small", "--out", str(_existing_file(tmp)), "--force"],
     "exists and is a file, expected a directory"),
    ("simulate-no-out", lambda tmp: ["simulate", "pan-tilt"], "Missing option '--out'"),
    ("reproduce-out-file", lambda tmp: ["reproduce", "pan-tilt", "--size", "small", "--out", str(_existing_file(tmp)), "--force"],
     "exists and is a file, expected a directory"),
    ("reproduce-out-non-empty", lambda tmp: ["reproduce", "pan-tilt", "--size", "small", "--out", str(_non_empty_dir(tmp))],
     "exists and is not empty; choose another or pass --force"),
    ("reproduce-system", lambda tmp: ["reproduce", "segway", "--out", str(tmp / "o")], "unknown system 'segway'"),
    ("reproduce-case", lambda tmp: ["reproduce", "pan-tilt", "--case", "medium", "--out", str(tmp / "o")], "--case: expected one of low, high, both, got 'medium'"),
    ("reproduce-seeds", lambda tmp: ["reproduce", "pan-tilt", "--seeds", "0", "--out", str(tmp / "o")], "--seeds: expected a positive number of seeds, got 0"),
    ("reproduce-ablation", lambda tmp: ["reproduce", "pan-tilt", "--ablation", "metres", "--out", str(tmp / "o")], "--ablation: expected units, got 'metres'"),
    ("reproduce-noise", lambda tmp: ["reproduce", "pan-tilt", "--noise", "loud", "--out", str(tmp / "o")], "--noise: expected one of realistic, ideal, none"),
    ("bench-solver", lambda tmp: ["bench", "--out", str(tmp / "o"), "--solvers", "cvx"], "unknown solver 'cvx'; expected one of"),
    ("bench-problem", lambda tmp: ["bench", "--out", str(tmp / "o"), "--problems", "quadruped"], "unknown problem 'quadruped'"),
    ("bench-max-n", lambda tmp: ["bench", "--out", str(tmp / "o"), "--max-n", "10"], "max_n: expected at least 100 (the smallest N), got 10"),
    ("bench-cap", lambda tmp: ["bench", "--out", str(tmp / "o"), "--cap", "arm7:100"], "cap: expected PROBLEM=N (e.g. arm7=100000), got 'arm7:100'"),
    ("bench-out-file", lambda tmp: ["bench", "--quick", "--out", str(_existing_file(tmp))], "exists and is a file, expected a directory"),
    ("unknown-command", lambda tmp: ["identify"], "No such command 'identify'"),
]:
    _flag_case(_id, _args, _msg)


# --- what vendors' URDFs and new users' inputs do (each a typed error or a warning, never a traceback) ------------
TOOL = '''  <link name="tool">
    <inertial>
      <mass value="0"/>
      <inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/>
    </inertial>
  </link>
  <joint name="tool_joint" type="fixed">
    <parent link="link2"/>
    <child link="tool"/>
  </joint>
</robot>'''
MESH = '<collision><geometry><mesh filename="package://arm_description/meshes/link1.stl"/></geometry></collision></link>'
for _id, _old, _new, _msg in [
    ("massless-frame-with-inertia", "</robot>", TOOL, "link 'tool' <inertial>: a mass of 0 kg with a non-zero inertia "
     "(ixx=0.001, ixy=0, ixz=0, iyy=0.001, iyz=0, izz=0.001); treated as a massless frame"),
    ("two-origins", '<origin xyz="0 0 -0.4" rpy="0 0 0"/>', '<origin xyz="0 0 -0.4" rpy="0 0 0"/><origin xyz="0 0 -0.5"/>',
     "joint 'Joint2' has 2 <origin> elements; the first is used (as urdfdom does)"),
    ("mimic", '<dynamics damping="0.02" friction="0.0"/>', '<dynamics damping="0.02" friction="0.0"/><mimic joint="Joint1"/>',
     "joint 'Joint2' mimics joint 'Joint1' (<mimic>); Pinocchio's regressor does not support mimic joints"),
    ("package-mesh-not-found", "</inertial>\n  </link>\n  <link name=\"link2\">", "</inertial>\n  " + MESH + "\n  <link name=\"link2\">",
     "MJCF: 1 collision mesh not found and left out of the MJCF (e.g. package://arm_description/meshes/link1.stl)"),
]:
    CASES.append(Case(f"urdf-warns-{_id}", (lambda old, new: lambda tmp: fit(tmp, write_urdf(tmp, URDF.replace(old, new, 1))))(_old, _new),
                      0, _msg))
    assert _old in URDF, _old
_config_case("resample-rate-word", {"preprocessing": [{"resample": {"rate": "fast"}}, DIFF]},
             "resample: rate must be a positive number of Hz, got 'fast'")
_config_case("window-word", {"preprocessing": [{"differentiate": {"window": "short"}}]},
             "differentiate: window must be a positive number of seconds, got 'short'")
_config_case("cutoff-word", {"preprocessing": [DIFF, {"filter_lowpass": {"cutoff": "low"}}]}, "low-pass cutoff must be in (0, 250) Hz")
_config_case("package-path-number", {"model": {"urdf": "r.urdf", "package_path": 5}}, "model.package_path: expected a list of file paths, got 5")
_log_case("effort-all-zero", _with(lambda df: df.assign(tau_meas1=0.0, tau_meas2=0.0)),
          "every effort column is 0 in every row (tau_meas1, tau_meas2): nothing to identify")
_log_case("effort-one-joint-zero", _with(lambda df: df.assign(tau_meas2=0.0)), "effort column 'tau_meas2' is 0 in every row", code=0)
PRISMATIC_COLUMNS = {"joints": {f"Joint{k}": {"position": f"pos_meas{k}", "velocity": f"vel_meas{k}", "effort": f"tau_meas{k}"}
                                for k in (1, 2)}}


@case("config-angular-unit-on-prismatic", 2, "column map: joint 'Joint1' is prismatic but its position unit is 'rad' "
      "(angular); expected one of ['m', 'mm']")
def _(tmp):
    urdf = write_urdf(tmp, URDF.replace('type="revolute"', 'type="prismatic"', 1), "prismatic.urdf")
    cfg = write_config(tmp, {"columns": {**PRISMATIC_COLUMNS, "units": {"position": {"Joint1": "rad"}}}})
    return ["fit", "--config", str(cfg), "--model", str(urdf), "--out", str(tmp / "out")]


_flag_case("simulate-seed-negative", lambda tmp: ["simulate", "pan-tilt", "--size", "small", "--seed", "-1", "--out", str(tmp / "o")],
           "--seed: expected an integer ≥ 0, got -1")


def _stream(tmp: Path, make: Callable[[Path], Path], *extra: str) -> list[str]:
    return ["fit-stream", "--model", str(write_urdf(tmp)), "--data", str(make(tmp)), *extra]


def _parquet(rows: int, random: bool):
    def make(tmp: Path) -> Path:
        model, rng = pin.buildModelFromXML(URDF), np.random.default_rng(0)
        df = GOOD.iloc[:rows]
        q, v = df[["pos_meas1", "pos_meas2"]].to_numpy(), df[["vel_meas1", "vel_meas2"]].to_numpy()
        a = np.gradient(v, 1 / RATE, axis=0) if rows > 2 else np.zeros_like(v)
        tau = np.stack([pin.rnea(model, model.createData(), *x) for x in zip(q, v, a)])
        cols = {"q_0": q[:, 0], "q_1": q[:, 1], "v_Joint1": v[:, 0], "v_Joint2": v[:, 1], "a_Joint1": a[:, 0],
                "a_Joint2": a[:, 1], "tau_Joint1": tau[:, 0], "tau_Joint2": tau[:, 1]}
        if random:
            cols = {k: rng.normal(size=rows) for k in cols}
        pd.DataFrame(cols).to_parquet(tmp / "run.parquet")
        return tmp / "run.parquet"
    return make


for _id, _make, _code, _msg in [
    ("empty-file", lambda tmp: _text_file(b"", "e.parquet")(tmp), 2, "e.parquet: not a Parquet file"),
    ("csv", lambda tmp: write_log(tmp), 2, "run.csv: not a Parquet file"),
    ("one-row", _parquet(1, False), 2, "1 sample × 2 coordinates = 2 equations for 20 parameters; a fit needs more samples"),
    ("random-numbers", _parquet(400, True), 0, "the fitted model explains"),
    ("good", _parquet(400, False), 0, "ols: optimal"),
]:
    CASES.append(Case(f"stream-{_id}", (lambda make: lambda tmp: _stream(tmp, make))(_make), _code, _msg))


IDS = [c.id for c in CASES]
assert len(set(IDS)) == len(IDS), sorted({i for i in IDS if IDS.count(i) > 1})


def test_the_corpus_is_large():
    assert len(CASES) + len(LIBRARY_CASES) >= 100


@pytest.mark.parametrize("c", CASES, ids=IDS)
def test_cli_case(c: Case, tmp_path):
    result = runner.invoke(app, c.args(tmp_path))
    text = _text(result)
    assert result.exit_code == c.code, text
    assert " ".join(c.message.split()) in text
    assert "Traceback" not in text
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    if c.code == 2 and "out" not in c.id:
        assert not (tmp_path / "out").exists()  # bad input writes nothing


@pytest.mark.parametrize("c", CASES, ids=IDS)
def test_no_case_raises_anything_but_a_dualid_error(c: Case, tmp_path):
    result = runner.invoke(app, ["--debug", *c.args(tmp_path)])
    exc = result.exception
    assert exc is None or isinstance(exc, (DualidError, OSError, SystemExit)), f"{type(exc).__name__}: {exc}"


# --- library calls ------------------------------------------------------------------------------
def _lib_cases():
    from dualid.data.io import ColumnMap, load_log
    from dualid.data.preprocessing import (
        differentiate,
        downsample,
        filter_lowpass,
        lowpass,
        preprocess,
        resample,
        trim,
    )
    from dualid.data.trajectory import Trajectory
    from dualid.errors import ConfigError, DataError
    from dualid.model.urdf_check import read_urdf
    from dualid.robot.config import FitConfig

    t = np.arange(200) / 100.0
    traj = Trajectory(t=t, q=np.sin(t)[:, None], v=np.cos(t)[:, None], tau=t[:, None], coordinates=("j",))
    jc = {"position": "p", "effort": "e"}
    return [
        ("colmap-not-mapping", lambda: ColumnMap.from_dict([1]), DataError, "column map must be a mapping"),
        ("colmap-no-joints", lambda: ColumnMap.from_dict({"time": "t"}), DataError, "column map: 'joints' must map"),
        ("colmap-joint-not-mapping", lambda: ColumnMap.from_dict({"joints": {"j": "p"}}), DataError, "joint 'j' must map to a mapping"),
        ("colmap-joint-unknown-key", lambda: ColumnMap.from_dict({"joints": {"j": {**jc, "torque": "x"}}}), DataError, "unknown keys ['torque']"),
        ("colmap-units-not-mapping", lambda: ColumnMap.from_dict({"joints": {"j": jc}, "units": "deg"}), DataError, "'units' must be a mapping"),
        ("colmap-unknown-quantity", lambda: ColumnMap.from_dict({"joints": {"j": jc}, "units": {"speed": "m/s"}}), DataError, "unknown quantity 'speed'"),
        ("colmap-unknown-unit", lambda: ColumnMap.from_dict({"joints": {"j": jc}, "units": {"position": "grad"}}), DataError, "unknown position unit 'grad'"),
        ("colmap-empty", lambda: ColumnMap(time="t", joints=()), DataError, "column map: no joints given"),
        ("load-log-velocity", lambda: load_log("x.csv", ColumnMap.pattern(["a"]), velocity="spline"), DataError, "velocity must be 'logged' or 'gradient'"),
        ("load-log-no-velocity", lambda: load_log("x.csv", ColumnMap.pattern(["a"], velocity=None)), DataError, "column map has no velocity columns"),
        ("resample-method", lambda: resample(traj, 100, method="nearest"), DataError, "method must be 'linear' or 'cubic'"),
        ("resample-nan-rate", lambda: resample(traj, float("nan")), DataError, "rate must be a positive number of Hz"),
        ("differentiate-window-nan", lambda: differentiate(traj, window=float("nan")), DataError, "window must be a positive number"),
        ("differentiate-polyorder-float", lambda: differentiate(traj, polyorder=2.5), DataError, "polyorder must be an integer ≥ 2"),
        ("lowpass-field-a", lambda: filter_lowpass(traj, 5, fields=["a"]), DataError, "field 'a' requested but the trajectory has no acceleration"),
        ("downsample-bool", lambda: downsample(traj, True), DataError, "factor must be a positive integer, got True"),
        ("downsample-aliasing", lambda: downsample(traj, 2, cutoff=40), DataError, "is not below the new Nyquist frequency"),
        ("trim-nan", lambda: trim(traj, start=float("nan")), DataError, "start must be a number of seconds or null"),
        ("preprocess-not-list-item", lambda: preprocess(traj, ["resample"]), DataError, "must be a one-key mapping"),
        ("config-not-mapping", lambda: FitConfig.from_dict([1]), ConfigError, "config: expected a mapping"),
        ("config-no-train", lambda: FitConfig.from_dict({"model": "r.urdf", "train": []}), ConfigError, "missing required keys ['train']"),
        ("lowpass-too-short", lambda: lowpass(np.zeros(10), 100.0, 5.0), DataError,
         "low-pass: a signal of 10 samples is too short for an order-4 zero-phase filter (needs more than 15)"),
        ("read-urdf-missing", lambda: read_urdf("/nonexistent/robot.urdf"), DataError, "no URDF file at /nonexistent/robot.urdf"),
    ]


LIBRARY_CASES = _lib_cases()


@pytest.mark.parametrize("fn,error,message", [c[1:] for c in LIBRARY_CASES], ids=[c[0] for c in LIBRARY_CASES])
def test_library_case(fn, error, message):
    with pytest.raises(error) as info:
        fn()
    assert message in str(info.value)


def test_read_urdf_accepts_the_good_robot_and_the_dfki_one(tmp_path):
    from dualid.model.urdf_check import read_urdf

    assert read_urdf(write_urdf(tmp_path)).tag == "robot"
    dfki = Path(__file__).resolve().parents[1] / "examples" / "dfki" / "data" / "pendubot_model_2.1.urdf"
    if dfki.is_file():
        assert read_urdf(dfki).tag == "robot"


def test_json_dump_of_ids_is_stable():
    json.dumps(IDS)  # ids are plain strings (readable in -k filters)



def test_stream_warns_only_when_the_fit_explains_little(tmp_path):
    good = runner.invoke(app, _stream(tmp_path, _parquet(400, False)))
    assert good.exit_code == 0 and "explains" not in _text(good)


def test_package_path_resolves_meshes_and_the_mjcf_keeps_them(tmp_path, monkeypatch):
    """--package-path and ROS_PACKAGE_PATH find package:// meshes; the MJCF then holds the mesh."""
    pkg = tmp_path / "share" / "arm_description" / "meshes"
    pkg.mkdir(parents=True)
    v = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]], dtype=np.float32)  # a tetrahedron, binary STL
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    record = np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    (pkg / "link1.stl").write_bytes(b"\0" * 80 + np.uint32(4).tobytes()
                                    + np.array([(np.zeros(3), v[list(f)], 0) for f in faces], dtype=record).tobytes())
    urdf = write_urdf(tmp_path, URDF.replace("</inertial>\n  </link>\n  <link name=\"link2\">",
                                             "</inertial>\n  " + MESH + "\n  <link name=\"link2\">", 1))
    mesh_urdf = write_urdf(tmp_path, urdf.read_text(), "mesh.urdf")
    config = write_config(tmp_path, {"model": {"urdf": "mesh.urdf", "package_path": ["share"]}})  # relative to the config
    for args, env in ((fit(tmp_path, mesh_urdf)[:-2] + ["--package-path", str(tmp_path / "share"), "--out"], None),
                      (["fit", "--config", str(config), "--out"], None),
                      (fit(tmp_path, mesh_urdf)[:-1], str(tmp_path / "share"))):
        if env:
            monkeypatch.setenv("ROS_PACKAGE_PATH", env)
        out = tmp_path / f"o{len(list(tmp_path.glob('o*')))}"
        result = runner.invoke(app, args + [str(out)])
        assert result.exit_code == 0 and "not found" not in _text(result), _text(result)
        xml = (out / "ols.xml").read_text()
        assert 'file="' in xml and "link1.stl" in xml


def test_mjcf_drops_the_range_the_logs_leave():
    """The logged motion leaves Joint2's URDF range: the MJCF has no range there (no limit force in MuJoCo)."""
    import mujoco

    from dualid.model.mjcf import identified_mjcf
    from dualid.model.rigid_body import RigidBodyModel

    tmp = Path(__import__("tempfile").mkdtemp())
    urdf = write_urdf(tmp)
    rigid = RigidBodyModel.from_urdf(urdf)
    text = identified_mjcf(urdf, rigid, rigid.nominal, logged={"Joint1": (-1.0, 1.0), "Joint2": (-0.5, 8.59)})
    assert any("joint 'Joint2': the logs reach [-0.5, 8.59], outside the URDF's range [-3.2, 3.2]" in n for n in text.notes)
    model = mujoco.MjModel.from_xml_string(text.xml)
    assert list(model.jnt_limited) == [1, 0]


def test_quaternion_columns_in_the_wrong_order_are_detected(tmp_path):
    """A permuted quaternion has unit norm too; the logged twist tells the orders apart."""
    from dualid.data.io import load_log
    from dualid.errors import DataError, DualidWarning

    model = pin.Model()
    model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    t = np.arange(200) / 100.0
    w = np.array([0.3, -0.2, 0.5, 0.4, 0.7, -0.3])  # a constant body twist (screw motion)
    q = np.stack([pin.integrate(model, pin.neutral(model), w * tk) for tk in t])
    cols = {"time": t, **{k: q[:, i] for i, k in enumerate(["x", "y", "z", "qx", "qy", "qz", "qw"])},
            **{f"v{k}": np.full(t.size, w[k]) for k in range(6)}}
    pd.DataFrame(cols).to_csv(tmp_path / "base.csv", index=False)
    base = {"position": ["x", "y", "z"], "twist": [f"v{k}" for k in range(6)]}
    load_log(tmp_path / "base.csv", {"time": "time", "base": {**base, "quaternion": ["qx", "qy", "qz", "qw"]}})
    with pytest.raises(DataError, match="matches the quaternion columns .* read in xyzw order .* set columns.base.quaternion_order: xyzw"):
        load_log(tmp_path / "base.csv", {"time": "time", "base": {**base, "quaternion": ["qx", "qy", "qz", "qw"],
                                                                 "quaternion_order": "wxyz"}})
    # without a twist no cheap check tells the orders apart (a permutation keeps the norm and the angular speed): warned
    with pytest.warns(DualidWarning, match=r"read in wxyz order \(quaternion_order\), which could not be checked"):
        load_log(tmp_path / "base.csv", {"time": "time", "base": {"position": ["x", "y", "z"], "quaternion_order": "wxyz",
                                                                 "quaternion": ["qw", "qx", "qy", "qz"]}}, velocity="gradient")


def test_a_floating_body_without_wrenches_is_refused(tmp_path):
    """A free body's motion without the forces on it determines no mass (it was fitted as a 2.5e-14 kg body)."""
    from dualid.data.checks import check_effort
    from dualid.errors import DataError

    with pytest.raises(DataError, match="the floating base has no wrench section"):
        check_effort("box.csv", np.zeros((10, 6)), None, [], True)


def test_report_says_which_model_files_were_written_and_why_not(tmp_path):
    """A mesh MuJoCo cannot read (an ASCII STL) leaves no MJCF: report.md and parameters.yaml say why; a mesh
    not found leaves the MJCF without it, and the report says so."""
    pkg = tmp_path / "share" / "arm_description" / "meshes"
    pkg.mkdir(parents=True)
    (pkg / "link1.stl").write_text("solid t\nendsolid t\n")
    urdf = write_urdf(tmp_path, URDF.replace("</inertial>\n  </link>\n  <link name=\"link2\">",
                                             "</inertial>\n  " + MESH + "\n  <link name=\"link2\">", 1))
    for name, extra, said in (("bad", ["--package-path", str(tmp_path / "share")], "ols.xml not written: write_mjcf: "
                               "MuJoCo refused the identified model"), ("missing", [], "1 collision mesh not found")):
        out = tmp_path / name
        result = runner.invoke(app, fit(tmp_path, urdf)[:-1] + [str(out), *extra])
        assert result.exit_code == 0, _text(result)
        report = " ".join((out / "report.md").read_text().split())
        assert "## Model files" in report and said in report
        record = yaml.safe_load((out / "parameters.yaml").read_text())["methods"]["ols"]
        assert (record["mjcf"].startswith("not written: write_mjcf: MuJoCo refused") if name == "bad"
                else record["mjcf"] == "ols.xml" and "not found" in record["mjcf_notes"])
