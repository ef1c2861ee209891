"""``FitConfig``: everything a real-robot fit needs, from a YAML file or a dict (and CLI overrides).

YAML form (relative paths are relative to the YAML file's folder)::

    model: {urdf: robot.urdf, floating_base: false, gravity: [0, 0, -9.81]}
    columns: {time: time, joints: {Joint1: {position: pos_meas1, velocity: vel_meas1, effort: tau_meas1}}}
    train: [run0.csv, run1.csv]
    test: [run2.csv]
    preprocessing: [{resample: {rate: 500}}, {differentiate: {window: 0.05}}, {downsample: {factor: 5}}]
    joint_terms: {viscous: true, coulomb: true, coulomb_velocity: 0.01, armature: true, joints: [Joint1]}
    bounds: {Joint1.b: [0, 1]}
    methods: [ols, wls, energy, logdet, pullback, dm]
    prior: {source: urdf, gamma: 0.1, per_equation: true, plausible: true}
    validation: {xcorr_window: 0.02}
    references: {lab: lab_parameters.yml}
    out: results/robot
    uncertainty: {method: sandwich, blocks: segments, segments_per_run: null, resamples: 200, seed: 0}

Only ``model.urdf`` and ``train`` are required. ``columns`` may be omitted when the logs carry the
DFKI double-pendulum columns (time, pos_meas{i}, vel_meas{i}, tau_meas{i}; see ``fit.column_map``).
A drag-dominated system is ``model: {kind: drag, urdf: …, drag: …}`` (``dualid.robot.drag_config``;
no accelerations needed, no joint_terms).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from dualid.errors import ConfigError
from dualid.estimators.methods import METHODS, make_estimator
from dualid.estimators.methods import method as method_entry  # the one list of method names
from dualid.model.drag_spec import DragSpec
from dualid.robot.drag_config import check_kind, drag_spec
from dualid.robot.margin_config import MarginConfig, margin_option
from dualid.robot.plausible_step import PLAUSIBLE_LEVEL, plausible_dict, plausible_option
from dualid.robot.uncertainty import UncertaintyConfig

_TOP_KEYS = (
    "model", "columns", "train", "test", "preprocessing", "joint_terms", "bounds", "methods", "solver", "prior",
    "validation", "references", "out", "uncertainty", "margin",
)
_MODEL_KEYS = ("urdf", "floating_base", "gravity", "kind", "drag", "package_path")
_JOINT_TERM_KEYS = ("viscous", "coulomb", "coulomb_velocity", "armature", "joints")
_PRIOR_KEYS = ("source", "gamma", "per_equation", "plausible")
_VALIDATION_KEYS = ("xcorr_window",)


def _check_keys(d: Any, known: tuple[str, ...], where: str) -> Mapping:
    if d is None:
        return {}
    if not isinstance(d, Mapping):
        raise ConfigError(f"{where}: expected a mapping with keys {list(known)}, got {type(d).__name__} {d!r}")
    unknown = [k for k in d if k not in known]
    if unknown:
        raise ConfigError(f"{where}: unknown keys {unknown}; known keys: {list(known)}")
    return d


def _path(x, base: Path | None, where: str) -> Path:
    if not isinstance(x, (str, Path)) or not str(x):
        raise ConfigError(f"{where}: expected a file path, got {x!r}")
    p = Path(x).expanduser()
    return p if p.is_absolute() or base is None else base / p


def _paths(x, base: Path | None, where: str) -> tuple[Path, ...]:
    if x is None:
        return ()
    if isinstance(x, (str, Path)):
        x = [x]
    if not isinstance(x, (list, tuple)):
        raise ConfigError(f"{where}: expected a list of file paths, got {x!r}")
    return tuple(_path(p, base, where) for p in x)


def _float(x, where: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float, str)):
        raise ConfigError(f"{where}: expected a number, got {x!r}")
    try:
        return float(x)
    except ValueError:
        raise ConfigError(f"{where}: expected a number, got {x!r}") from None


def _bool(x, where: str) -> bool:
    if not isinstance(x, bool):
        raise ConfigError(f"{where}: expected true or false, got {x!r}")
    return x


@dataclass(frozen=True)
class ModelConfig:
    urdf: Path | None  # None only for a drag model built from model.drag.chain
    floating_base: bool = False
    gravity: tuple[float, float, float] | None = None  # [m/s²]; None: the URDF/Pinocchio default (0, 0, −9.81)
    kind: str = "inertia"  # "inertia" (rigid bodies) or "drag" (dualid.robot.drag_config)
    drag: DragSpec | None = None  # the drag model's spec (kind "drag")
    package_path: tuple[Path, ...] = ()  # folders holding the packages of package:// mesh URIs (model.meshes)


@dataclass(frozen=True)
class JointTermsConfig:
    viscous: bool = True  # b_j v_j [N m s/rad]
    coulomb: bool = True  # fc_j tanh(v_j / v_c) [N m]
    coulomb_velocity: float = 0.01  # v_c [rad/s]
    armature: bool = True  # Ia_j a_j [kg m²] (reflected rotor inertia)
    joints: tuple[str, ...] | None = None  # None: every joint of the model that is not a floating base


@dataclass(frozen=True)
class PriorConfig:
    source: str = "urdf"  # "urdf" (the URDF's inertials) or a parameters.yaml/json file (from a previous fit)
    gamma: float = 0.1  # weight of the prior: per equation (γ·N·n, the study's convention) or absolute
    per_equation: bool = True
    plausible: bool = True  # written URDF/MJCF: the plausible θ closest to the prior (robot.plausible_step)
    plausible_level: float = PLAUSIBLE_LEVEL  # confidence level of the region (0: θ̂'s predictions exactly)
    plausible_joint: bool = False  # χ²_r (joint region) instead of χ²₁ (each combination within its interval)


@dataclass(frozen=True)
class FitConfig:
    """A real-robot fit (see the module docstring for the YAML form)."""

    model: ModelConfig
    train: tuple[Path, ...]
    test: tuple[Path, ...] = ()
    columns: Mapping | None = None  # ColumnMap dict form; None: DFKI default if the logs have those columns
    preprocessing: tuple[dict, ...] | None = None  # None: derived from the first log (dualid.robot.defaults)
    joint_terms: JointTermsConfig = field(default_factory=JointTermsConfig)
    bounds: tuple[tuple[str, float, float], ...] = ()  # (name, lo, hi)
    methods: tuple[str, ...] = ("ols", "dm")
    solver: tuple[tuple[str, tuple[tuple[str, Any], ...]], ...] = ()  # (method, estimator options) pairs
    prior: PriorConfig = field(default_factory=PriorConfig)
    xcorr_window: float = 0.02  # [s] shift window ± of the normalized cross-correlation
    references: tuple[tuple[str, Path], ...] = ()  # (label, DFKI reference_parameters yml)
    out: Path | None = None
    uncertainty: UncertaintyConfig = field(default_factory=UncertaintyConfig)
    margin: MarginConfig | None = None  # C_b(θ) ⪰ ε·C_b(θ_ref) on every method (robot/margin_config.py); None: off

    def __post_init__(self) -> None:
        if not self.train:
            raise ConfigError("train: at least one training log file is required")
        unknown = [m for m in self.methods if m not in METHODS]
        if unknown:
            raise ConfigError(f"unknown method {unknown[0]!r}; known methods: {', '.join(METHODS)}")
        if not self.methods:
            raise ConfigError(f"methods: choose at least one of {', '.join(METHODS)}")
        for m, options in self.solver:  # bad estimator options are bad input, found before any work
            method_entry(m)
            make_estimator(m, theta0=np.zeros(1), options=dict(options))
        if len(set(self.methods)) != len(self.methods):
            object.__setattr__(self, "methods", tuple(dict.fromkeys(self.methods)))
        if not (np.isfinite(self.xcorr_window) and self.xcorr_window >= 0):
            raise ConfigError(f"validation.xcorr_window: expected seconds ≥ 0, got {self.xcorr_window!r}")
        if not (np.isfinite(self.joint_terms.coulomb_velocity) and self.joint_terms.coulomb_velocity > 0):
            raise ConfigError(
                f"joint_terms.coulomb_velocity: expected a velocity > 0 [rad/s], got {self.joint_terms.coulomb_velocity!r}")
        if not (np.isfinite(self.prior.gamma) and self.prior.gamma >= 0):
            raise ConfigError(f"prior.gamma: expected a number ≥ 0, got {self.prior.gamma!r}")
        for name, lo, hi in self.bounds:
            if not lo <= hi:
                raise ConfigError(f"bounds: {name!r} has lower {lo} > upper {hi}")

    # --- construction -----------------------------------------------------------------------
    @staticmethod
    def from_dict(d: Mapping, base_dir: str | Path | None = None) -> "FitConfig":
        """From the YAML form; relative paths are taken relative to ``base_dir`` (if given)."""
        base = None if base_dir is None else Path(base_dir)
        d = _check_keys(d, _TOP_KEYS, "config")
        missing = [k for k in ("model", "train") if d.get(k) in (None, [], "")]
        if missing:
            raise ConfigError(f"config: missing required keys {missing}")
        m = d["model"]
        if isinstance(m, (str, Path)):
            m = {"urdf": m}
        m = _check_keys(m, _MODEL_KEYS, "model")
        if check_kind(m) == "drag":
            spec = drag_spec(m)
            urdf = None if m.get("urdf") is None else _path(m["urdf"], base, "model.urdf")
            return FitConfig._from_dict(d, base, ModelConfig(urdf, kind="drag", drag=spec))
        if not m.get("urdf"):
            raise ConfigError("model: missing required key 'urdf'")
        gravity = m.get("gravity")
        if gravity is not None:
            try:
                gravity = tuple(_float(x, "model.gravity") for x in gravity)
            except (TypeError, ConfigError):
                gravity = ()
            if len(gravity) != 3:
                raise ConfigError(f"model.gravity: expected 3 numbers [m/s²], got {m.get('gravity')!r}")
        model = ModelConfig(_path(m["urdf"], base, "model.urdf"), _bool(m.get("floating_base", False), "model.floating_base"),
                            gravity, package_path=_paths(m.get("package_path"), base, "model.package_path"))
        return FitConfig._from_dict(d, base, model)

    @staticmethod
    def _from_dict(d: Mapping, base: Path | None, model: ModelConfig) -> "FitConfig":
        if model.kind == "drag" and d.get("joint_terms") is not None:
            raise ConfigError("joint_terms: not used by a drag model (model.kind: drag); damp joints with model.drag.damping")
        jt = _check_keys(d.get("joint_terms"), _JOINT_TERM_KEYS, "joint_terms")
        joints = jt.get("joints")
        if joints is not None:
            joints = (joints,) if isinstance(joints, str) else tuple(str(j) for j in joints)
        joint_terms = JointTermsConfig(
            viscous=_bool(jt.get("viscous", True), "joint_terms.viscous"),
            coulomb=_bool(jt.get("coulomb", True), "joint_terms.coulomb"),
            coulomb_velocity=_float(jt.get("coulomb_velocity", 0.01), "joint_terms.coulomb_velocity"),
            armature=_bool(jt.get("armature", True), "joint_terms.armature"),
            joints=joints,
        )
        pr = d.get("prior")
        if isinstance(pr, str):
            pr = {"source": pr}
        pr = _check_keys(pr, _PRIOR_KEYS, "prior")
        source = str(pr.get("source", "urdf"))
        if source != "urdf":
            source = str(_path(source, base, "prior.source"))
        prior = PriorConfig(source, _float(pr.get("gamma", 0.1), "prior.gamma"),
                            _bool(pr.get("per_equation", True), "prior.per_equation"),
                            *plausible_option(pr.get("plausible", True)))

        bounds_in = d.get("bounds") or {}
        if not isinstance(bounds_in, Mapping):
            raise ConfigError(f"bounds: expected a mapping {{parameter name: [lower, upper]}}, got {bounds_in!r}")
        bounds = []
        for name, pair in bounds_in.items():
            if not isinstance(pair, (list, tuple)) or len(pair) != 2:
                raise ConfigError(f"bounds: {name!r} must be [lower, upper] (use null for none), got {pair!r}")
            lo = -np.inf if pair[0] is None else _float(pair[0], f"bounds.{name}[0]")
            hi = np.inf if pair[1] is None else _float(pair[1], f"bounds.{name}[1]")
            bounds.append((str(name), lo, hi))

        solver = d.get("solver") or {}
        if not isinstance(solver, Mapping) or not all(isinstance(v, Mapping) for v in solver.values()):
            raise ConfigError("solver: expected a mapping {method: {option: value}}, e.g. {dm-paper: {solver: cvxpy, tol: 1e-8}}; "
                              f"got {solver!r}")
        for m in solver:
            if m not in METHODS:
                raise ConfigError(f"solver: unknown method {m!r}; known methods: {', '.join(METHODS)}")
        methods = d.get("methods", ("ols", "dm"))
        methods = (methods,) if isinstance(methods, str) else tuple(str(x) for x in methods)
        steps = d.get("preprocessing")
        if steps is not None and not isinstance(steps, (list, tuple)):
            raise ConfigError(f"preprocessing: expected a list of steps {{name: parameters}}, got {steps!r}")
        val = _check_keys(d.get("validation"), _VALIDATION_KEYS, "validation")
        refs = d.get("references") or {}
        if not isinstance(refs, Mapping):
            raise ConfigError(f"references: expected a mapping {{label: reference parameters .yml}}, got {refs!r}")
        columns = d.get("columns")
        if columns is not None and not isinstance(columns, Mapping):
            raise ConfigError(f"columns: expected a column map (time, joints, units), got {columns!r}")
        return FitConfig(
            model=model,
            train=_paths(d["train"], base, "train"),
            test=_paths(d.get("test"), base, "test"),
            columns=columns,
            preprocessing=None if steps is None else tuple(steps),
            joint_terms=joint_terms,
            bounds=tuple(bounds),
            methods=methods,
            solver=tuple((str(m), tuple(sorted(dict(o).items()))) for m, o in solver.items()),
            prior=prior,
            xcorr_window=_float(val.get("xcorr_window", 0.02), "validation.xcorr_window"),
            references=tuple((str(k), _path(v, base, f"references.{k}")) for k, v in refs.items()),
            out=None if d.get("out") is None else _path(d["out"], base, "out"),
            uncertainty=UncertaintyConfig.from_dict(d.get("uncertainty")),
            margin=margin_option(d.get("margin")),
        )

    @staticmethod
    def from_yaml(path: str | Path) -> "FitConfig":
        """Read a YAML config; relative paths in it are relative to its folder."""
        from dualid.data.files import read_mapping

        path = Path(path)
        from dualid.robot.schema import check_shape

        d = read_mapping(path, "config file")
        config = FitConfig.from_dict(d, base_dir=path.resolve().parent)  # its messages first: they are the most specific
        check_shape(d, f"config file {path}")  # then what only the schema sees (e.g. a list where a name belongs)
        return config

    def with_overrides(self, **changes) -> "FitConfig":
        """A copy with the given fields replaced (None values are ignored), e.g. from CLI flags."""
        known = {f.name for f in fields(self)}
        unknown = [k for k in changes if k not in known]
        if unknown:
            raise ConfigError(f"unknown config fields {unknown}; known: {sorted(known)}")
        return replace(self, **{k: v for k, v in changes.items() if v is not None})

    def as_dict(self) -> dict:
        """The YAML form (paths as strings), for the record written next to the results."""
        return {
            "model": {"urdf": None if self.model.urdf is None else str(self.model.urdf),
                      "floating_base": self.model.floating_base,
                      "gravity": None if self.model.gravity is None else list(self.model.gravity),
                      **({"package_path": [str(x) for x in self.model.package_path]} if self.model.package_path else {}),
                      **({"kind": "drag", "drag": self.model.drag.as_dict()} if self.model.kind == "drag" else {})},
            "columns": None if self.columns is None else dict(self.columns),
            "train": [str(p) for p in self.train],
            "test": [str(p) for p in self.test],
            "preprocessing": None if self.preprocessing is None else [dict(s) for s in self.preprocessing],
            "joint_terms": None if self.model.kind == "drag" else {  # a drag model damps its joints in model.drag
                            "viscous": self.joint_terms.viscous, "coulomb": self.joint_terms.coulomb,
                            "coulomb_velocity": self.joint_terms.coulomb_velocity,
                            "armature": self.joint_terms.armature,
                            "joints": None if self.joint_terms.joints is None else list(self.joint_terms.joints)},
            "bounds": {n: [lo, hi] for n, lo, hi in self.bounds},
            "methods": list(self.methods),
            "solver": {m: dict(o) for m, o in self.solver},
            "prior": {"source": self.prior.source, "gamma": self.prior.gamma, "per_equation": self.prior.per_equation,
                      "plausible": plausible_dict(self.prior)},
            "validation": {"xcorr_window": self.xcorr_window},
            "references": {k: str(v) for k, v in self.references},
            "out": None if self.out is None else str(self.out),
            "uncertainty": self.uncertainty.as_dict(),
            **({} if self.margin is None else {"margin": self.margin.as_dict()}),
        }
