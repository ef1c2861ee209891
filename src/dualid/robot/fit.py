"""``fit_robot``: a URDF and logs in; identified parameters, uncertainty and held-out validation out.

Steps: load the logs through a column map (``logs.io``), preprocess them (``preprocess``; the
differentiation gives the accelerations and every step is recorded), build the model (the URDF's
``RigidBodyModel`` plus joint friction/armature), the problem and its identifiability report, fit
every requested method (physically consistent; ``allow_unidentifiable=True`` because a URDF chain is
never fully identifiable: the estimate in the null space is one of many minimisers), and validate on
the held-out runs (``workflow.validate``). A method that fails is recorded, not fatal.

Uncertainty (every method): 95 % intervals of the base parameters by the sandwich covariance of
``dualid.robot.uncertainty`` (gradients summed over segments of the training runs); a parameter has its own
standard error only when it is a base parameter on its own, otherwise "not identifiable".
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pinocchio as pin

from dualid.data.bag_inspect import bag_summary, default_topics
from dualid.data.bags import is_bag
from dualid.data.checks import check_efforts
from dualid.data.files import read_mapping
from dualid.data.io import ColumnMap, load_log, read_table
from dualid.data.lie import BASE_COORDINATES
from dualid.data.preprocessing import preprocess
from dualid.data.tables import reading_once
from dualid.data.trajectory import Trajectory
from dualid.errors import DataError, DualidError, DualidWarning, MissingFileError, PlausibleWarning
from dualid.estimators import IdentificationResult
from dualid.estimators.methods import make_estimator
from dualid.estimators.methods import method as method_entry
from dualid.evaluation.plausible import PlausibleParameters
from dualid.evaluation.plausible_newton import ball_prior
from dualid.evaluation.uncertainty import BaseUncertainty
from dualid.evaluation.validation import Validation, prepare_runs, validate, validate_each
from dualid.metric_guard import guard_info
from dualid.model.external_wrench import apply_wrenches
from dualid.model.joint_terms import JointTermsModel, with_joint_terms
from dualid.model.rigid_body import RigidBodyModel
from dualid.model.urdf_check import read_urdf
from dualid.problem import Identifiability, IdentificationProblem, build_problem
from dualid.robot.config import FitConfig
from dualid.robot.defaults import adaptive_preprocessing, warn_far_from_data
from dualid.robot.inputs import array_column_map, check_floating, check_runs_differ, check_units
from dualid.robot.margin_config import apply_margin
from dualid.robot.plausible_step import choose_plausible, refused_files
from dualid.robot.prior import prior_theta
from dualid.robot.uncertainty import method_uncertainty, parameter_errors

Progress = Callable[[str], None]


# --- data -------------------------------------------------------------------------------------
def column_map(config_columns, joints: tuple[str, ...], first_log: Path) -> ColumnMap:
    """The configured map, or the DFKI pattern (time, pos_meas{i}, vel_meas{i}, tau_meas{i}) when none is
    configured and the first log has exactly those columns (or the one joint-state topic of a bag);
    otherwise a DataError asking for a map."""
    model_joints = [j for j in joints if j not in BASE_COORDINATES]
    if config_columns is not None:
        return ColumnMap.from_dict(config_columns, model_joints)
    if not Path(first_log).exists():
        raise MissingFileError(f"log file not found: {first_log}")
    if is_bag(first_log):
        return ColumnMap.from_dict({"topics": default_topics(bag_summary(first_log))}, model_joints)
    cmap = ColumnMap.pattern(joints)
    _, available = read_table(Path(first_log))
    missing = [c for c in cmap.columns() if c not in available]
    arrays = array_column_map(joints, available)
    if missing and arrays is not None:
        return arrays
    if missing:
        raise DataError(f"no column map given and {first_log} lacks the default DFKI columns {missing} "
                        f"(available: {available}); give a 'columns' map in a --config file")
    return cmap


def choose_preprocessing(steps, first_log: Path, cmap: ColumnMap, joints: tuple[str, ...]) -> tuple[tuple, str]:
    """The configured steps (with warnings when far from the data) or, when none are configured, steps
    derived from the first log's rate and motion band, and a sentence saying how (dualid.robot.defaults)."""
    velocity = velocity_source(cmap)
    raw = load_log(first_log, cmap, joints, velocity=velocity)
    if steps is not None:
        warn_far_from_data(raw, steps)
        return tuple(steps), ""
    return adaptive_preprocessing(raw)


def velocity_source(cmap: ColumnMap) -> str:
    """"logged" when the map names a velocity column for every joint (and the base twist of a floating
    base), else "gradient" (v from dq/dt)."""
    base_twist = cmap.base is None or bool(cmap.base.twist)
    return "logged" if all(j.velocity for j in cmap.joints) and base_twist else "gradient"


def load_runs(paths, cmap: ColumnMap, joints: tuple[str, ...], steps, rigid: RigidBodyModel | None = None
              ) -> list[Trajectory]:
    """Load and preprocess each log; the runs must end with accelerations (a 'differentiate' step).
    External wrenches (the map's ``wrenches``) are folded into τ with ``rigid``'s frame Jacobians."""
    runs = []
    velocity = velocity_source(cmap)
    for p in paths:
        traj = preprocess(load_log(p, cmap, joints, velocity=velocity), [dict(s) for s in steps])
        if traj.a is None:
            raise DataError(f"{p}: no accelerations after preprocessing; add a 'differentiate' step (e.g. "
                            "{differentiate: {method: savgol, window: 0.05}})")
        if traj.wrench is not None:
            if rigid is None:
                raise DataError(f"{p}: external wrench columns need the rigid-body model to apply them")
            traj = apply_wrenches(rigid, traj)
        runs.append(traj)
    return runs


def build_model(config: FitConfig) -> tuple[RigidBodyModel, JointTermsModel | RigidBodyModel]:
    """The URDF's rigid-body model and it with the configured joint terms."""
    rigid = RigidBodyModel.from_urdf(config.model.urdf, config.model.floating_base, config.model.gravity)
    jt = config.joint_terms
    if jt.joints is not None:
        unknown = [j for j in jt.joints if j not in rigid.coordinates]
        if unknown:
            raise DataError(f"joint_terms.joints: joints {unknown} are not in the model; model joints: {list(rigid.coordinates)}")
    no_joints = jt.joints is None and len(rigid.coordinates) == len(rigid.base_coordinates)  # a single floating body
    if not (jt.viscous or jt.coulomb or jt.armature) or no_joints:
        return rigid, rigid
    return rigid, with_joint_terms(rigid, jt.viscous, jt.coulomb, jt.armature, jt.joints, jt.coulomb_velocity)


def with_bounds(problem: IdentificationProblem, bounds) -> IdentificationProblem:
    if not bounds:
        return problem
    names = problem.parameters.names
    unknown = [n for n, _, _ in bounds if n not in names]
    if unknown:
        raise DataError(f"bounds: unknown parameters {unknown}; parameters are {list(names)}")
    params = problem.parameters.with_bounds({n: lo for n, lo, _ in bounds}, {n: hi for n, _, hi in bounds})
    return dataclasses.replace(problem, parameters=params)


def urdf_joint_terms(urdf: Path, joints: tuple[str, ...]) -> dict[str, dict[str, float]]:
    """{joint: {damping, friction, armature}} from the <dynamics> of the URDF's moving joints (0 if absent)."""
    root = read_urdf(urdf)  # <dynamics> values checked finite and ≥ 0
    out = {}
    for joint in root.findall("joint"):
        name = joint.get("name")
        if name in joints:
            dyn = joint.find("dynamics")
            out[name] = {k: float(dyn.get(k, 0.0)) if dyn is not None else 0.0 for k in ("damping", "friction", "armature")}
    return out


# --- prior ------------------------------------------------------------------------------------
def _guarded(result: IdentificationResult, problem: IdentificationProblem, rigid: RigidBodyModel, model):
    """The result with the metric guard against the URDF's own inertials (joint terms at zero) in its info:
    how far the identified mass matrix collapsed or blew up (dualid.evaluation.guards)."""
    theta_urdf = np.zeros(model.parameters.p)
    theta_urdf[: rigid.parameters.p] = rigid.nominal
    try:
        guard = guard_info(problem, result.theta, theta_urdf, reference="the URDF's inertials")
    except DualidError as exc:  # e.g. a URDF whose own mass matrix is singular: recorded, not hidden
        guard = {"metric_guard_error": str(exc)}
    return dataclasses.replace(result, info={**result.info, **guard})


# --- estimators -------------------------------------------------------------------------------
def estimator(method: str, theta0: np.ndarray | None = None, gamma: float = 0.1, per_equation: bool = True,
              options=None):
    """Constrained estimators that accept a URDF chain's null space (never fully identifiable); the prior
    weight γ of logdet/pullback is per equation by default (γ·N·n, as in the paper's study); ``options``
    are the config's estimator options for this method (solver, tolerance, …)."""
    return make_estimator(method, theta0=theta0, gamma=gamma, per_equation=per_equation, allow_unidentifiable=True,
                          options=options)


# --- outcome ----------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class MethodFit:
    """One method's fit: the result (None when it failed, then ``error`` says why), its per-parameter
    standard errors, its held-out validation and the base parameters' uncertainty (``base_error``: why
    there is none)."""

    method: str
    result: IdentificationResult | None
    uncertainty: tuple[float | str | None, ...] = ()
    validation: Validation | None = None
    error: str = ""
    plausible: PlausibleParameters | None = None  # θ closest to the prior the data do not reject (plausible_step)
    plausible_error: str = ""  # why there is none although prior.plausible asked for it
    plausible_validation: Validation | None = None  # held-out scores of θ_plausible (the written model files)
    base: BaseUncertainty | None = None
    base_error: str = ""
    files_refused: str = ""  # why its model files are not written (robot.plausible_step.refused_files), "" if they are

    @property
    def ok(self) -> bool:
        return self.result is not None


class RunOutcome:
    """What every fit outcome (rigid-body ``FitOutcome``, ``robot.drag_fit.DragFitOutcome``) derives from its
    ``fits`` and ``train`` fields."""

    fits: dict[str, MethodFit]
    train: tuple[Trajectory, ...]

    @property
    def complete(self) -> bool:
        """True when every requested method succeeded."""
        return all(f.ok for f in self.fits.values())

    @property
    def steps(self) -> list:
        """The preprocessing steps the training runs went through."""
        return list(self.train[0].meta.get("steps", [])) if self.train else []


@dataclass(frozen=True, eq=False)
class FitOutcome(RunOutcome):
    config: FitConfig
    rigid: RigidBodyModel
    model: JointTermsModel | RigidBodyModel
    columns: ColumnMap
    train: tuple[Trajectory, ...]
    test: tuple[Trajectory, ...]
    problem: IdentificationProblem
    identifiability: Identifiability
    fits: dict[str, MethodFit]
    references: dict[str, tuple[np.ndarray, Validation | None]] = field(default_factory=dict)
    prior: str = ""  # where θ₀ of the regularized methods came from
    warnings: tuple[str, ...] = ()  # the DualidWarnings raised while loading, checking and fitting
    preprocessing_note: str = ""  # how the default preprocessing was derived from the data ("" if configured)
    training: dict[str, Validation] = field(default_factory=dict)  # label → scores on the training runs

    def identifiability_text(self) -> str:
        ident = self.identifiability
        lines = [f"samples: {self.problem.N} (x {self.problem.n} joints) from {len(self.train)} training runs; "
                 f"parameters: {self.problem.p}", ident.describe()]
        if not ident.full_rank:
            lines += [
                "",
                "A URDF chain is never fully identifiable from joint torques: only these combinations (the base",
                "parameters) are. Every method was fitted with allow_unidentifiable=True, so each returns one of",
                "many minimisers; its values along the null directions come from the constraints/solver (or the",
                "prior), not from the data. Compare predictions, not raw parameters.",
                f"not identifiable on their own ({len(ident.unidentifiable)}): {', '.join(ident.unidentifiable)}",
            ]
        return "\n".join(lines)


def _say(progress: Progress | None, message: str) -> None:
    if progress is not None:
        progress(message)


def run_workflow(workflow, config, progress):
    """workflow(config, progress) with each log parsed once (the first one is checked, sampled and loaded) and every
    DualidWarning raised on the way recorded in the outcome's ``warnings`` (and re-issued to the caller)."""
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", DualidWarning)
            with reading_once():
                outcome = workflow(config, progress)
    finally:  # re-issued (each once) also when an error follows: a warning may explain it
        for w in {(str(w.message), w.category): w for w in caught}.values():
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    ours = [w for w in caught if issubclass(w.category, DualidWarning)]
    return dataclasses.replace(outcome, warnings=tuple(dict.fromkeys(str(w.message) for w in ours)))


def fit_robot(config: FitConfig, progress: Progress | None = None) -> FitOutcome:
    """Run the whole workflow (see the module docstring); progress(message) is called between stages.
    Every DualidWarning raised on the way is recorded in the outcome (and re-issued to the caller)."""
    return run_workflow(_fit_robot, config, progress)


def _plausible(config: FitConfig, rigid, model, problem, method: str, theta: np.ndarray, base_unc, base_error):
    """(plausible parameters or None, the error that stopped them or ""): a failure is recorded (numpy's LinAlgError
    is a ValueError) and warned, so the files carry θ̂ and the report, parameters.yaml and the exit code say why."""
    try:
        plausible = choose_plausible(problem, theta, prior_theta(config, rigid, model, theta, problem)[0], base_unc,
                                     base_error, config.prior.plausible_level, config.prior.plausible_joint)
    except (DualidError, ValueError, ArithmeticError) as exc:
        error = f"{type(exc).__name__}: {exc}"
        warnings.warn(PlausibleWarning(f"{method}: no plausible parameters ({error}); its model files carry the raw "
                                       "fit θ̂"), stacklevel=1)
        return None, error
    if plausible.note and not plausible.note.startswith("prior.plausible.level: 0"):
        warnings.warn(PlausibleWarning(f"{method}: plausible parameters: {plausible.note}"), stacklevel=1)
    return plausible, ""


def _refused(config: FitConfig, rigid, model, problem, method: str, theta: np.ndarray, plausible) -> str:
    """Why ``method``'s model files are not written ("" when they are): the θ they would carry (θ_plausible, else θ̂)
    has a link heavier than twice the prior's whole moving mass (``robot.plausible_step.refused_files``)."""
    try:  # a URDF without inertials: compared with the regularised prior the plausible step uses
        theta0 = ball_prior(problem, prior_theta(config, rigid, model, theta, problem)[0])[0]
    except DualidError:  # an unreadable prior file (only read here when no step needs it): nothing to compare with
        return ""
    links = {}
    for f in rigid.model.frames:  # the first body frame on a joint is its child link
        if f.type == pin.FrameType.BODY and f.parentJoint > 0:
            links.setdefault(rigid.model.names[f.parentJoint], f.name)
    written = theta if plausible is None else plausible.theta
    return refused_files(method, problem.parameters, written, theta0, "raw" if plausible is None else "plausible",
                         links, config.prior.plausible)


def _fit_robot(config: FitConfig, progress: Progress | None = None) -> FitOutcome:
    from dualid.robot.dfki import reference_theta

    _say(progress, f"building the model from {config.model.urdf}")
    rigid, model = build_model(config)
    joints = tuple(rigid.coordinates)
    cmap = column_map(config.columns, joints, config.train[0])
    check_units(rigid, cmap)
    check_runs_differ(config.train, config.test)
    if config.prior.source != "urdf" and {"logdet", "pullback"} & set(config.methods):
        read_mapping(config.prior.source.partition("#")[0], "prior.source parameters file")  # bad input: before fitting
    _say(progress, f"loading {len(config.train)} training and {len(config.test)} test logs")
    steps, steps_note = choose_preprocessing(config.preprocessing, config.train[0], cmap, joints)
    check_floating(config.model.floating_base, cmap)
    train = load_runs(config.train, cmap, joints, steps, rigid)
    check_efforts(config.train, train, cmap)  # all efforts 0: a massless robot would be the exact fit
    test = load_runs(config.test, cmap, joints, steps, rigid)
    _say(progress, "building regressors")
    problem = with_bounds(build_problem(model, train), config.bounds)
    if config.margin is not None:  # every method under C_b(θ) ⪰ ε·C_b(θ_ref) (robot/margin_config.py)
        _say(progress, f"margin ε = {config.margin.epsilon:g} against the {config.margin.reference} reference")
        problem = apply_margin(problem, config.margin, lambda: prior_theta(
            config, rigid, model, None if model is rigid else estimator("ols").fit(problem).theta, problem)[0])
    ident = problem.identifiability()
    held_out = prepare_runs(model, test)  # each run's regressor and forward-dynamics data, once for every θ

    fits: dict[str, MethodFit] = {}
    ols_theta = None
    theta0, prior_text = None, ""
    for method in config.methods:
        _say(progress, f"fitting {method} ({method_entry(method).description})")
        try:
            if method in ("logdet", "pullback") and theta0 is None:
                if ols_theta is None and model is not rigid:
                    ols_theta = estimator("ols").fit(problem).theta
                theta0, prior_text = prior_theta(config, rigid, model, ols_theta, problem)
            est = estimator(method, theta0, config.prior.gamma, config.prior.per_equation,
                            dict(dict(config.solver).get(method, ())))
            result = est.fit(problem)
        except (DualidError, ValueError, np.linalg.LinAlgError) as exc:
            # recorded in the report: one method's failure must not lose the others; anything else is a bug and
            # propagates
            fits[method] = MethodFit(method, None, error=f"{type(exc).__name__}: {exc}")
            continue
        if method == "ols":
            ols_theta = result.theta
        result = _guarded(result, problem, rigid, model)
        _say(progress, f"uncertainty of {method}'s base parameters")
        base_unc, base_error = method_uncertainty(problem, result, est, ident.base, [len(t.t) for t in train],
                                                  config.uncertainty)
        validation = None
        if test:
            _say(progress, f"validating {method} on {len(test)} held-out runs")
            validation = validate(model, result.theta, held_out, method, config.xcorr_window)
        plausible, plausible_error = None, ""
        if config.prior.plausible:
            _say(progress, f"choosing {method}'s plausible parameters (closest to the prior, in the confidence region)")
            plausible, plausible_error = _plausible(config, rigid, model, problem, method, result.theta, base_unc,
                                                    base_error)
        plausible_validation = validation  # the exact form keeps θ̂'s predictions
        if test and plausible is not None and plausible.form != "exact":
            plausible_validation = validate(model, plausible.theta, held_out, method, config.xcorr_window)
        fits[method] = MethodFit(method, result, parameter_errors(base_unc, ident.base), validation, base=base_unc,
                                 base_error=base_error, plausible=plausible, plausible_error=plausible_error,
                                 plausible_validation=plausible_validation,
                                 files_refused=_refused(config, rigid, model, problem, method, result.theta, plausible))

    references = {}
    for label, path in config.references:
        _say(progress, f"validating the reference parameters {label}")
        theta_ref = reference_theta(path, model)
        references[label] = (theta_ref, validate(model, theta_ref, held_out, label, config.xcorr_window) if test else None)
    _say(progress, "scoring every fit on the training runs")
    thetas = {m: f.result.theta for m, f in fits.items() if f.ok} | {lab: th for lab, (th, _) in references.items()}
    training = validate_each(model, thetas, train, config.xcorr_window)
    return FitOutcome(config, rigid, model, cmap, tuple(train), tuple(test), problem, ident, fits, references, prior_text,
                      preprocessing_note=steps_note, training=training)
