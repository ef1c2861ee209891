"""``fit_drag``: a drag-dominated system (``model.kind: drag``) from logs of (q, v, τ); no accelerations.

The same stages as ``robot.fit.fit_robot`` with a ``DragModel`` (``dualid.model.drag``) in place of
the URDF's rigid bodies: load the logs through the column map (one column per coordinate of the
model's chart, e.g. x, y, theta of a planar base and the joint angles), preprocess them (the
configured steps, or the defaults derived from the first log), build the problem τ = D(q, θ) v,
fit every requested method under the drag consistency constraints (diagonal coefficients ≥ 0, full
drag matrices ⪰ 0, damping ≥ 0), and validate on held-out runs: effort τ̂ = D(q, θ̂) v and the
forward prediction v̂ = D(q, θ̂)⁻¹ τ against the measured velocity.

The prior θ₀ of logdet/pullback is the spec's nominal values (every body and damped joint needs
one); without them those methods fail with a message saying so.
"""

from __future__ import annotations

from dataclasses import dataclass

import cvxpy as cp
import numpy as np

from dualid.data.io import LINEAR_UNITS, SI_UNITS, ColumnMap, load_log
from dualid.data.preprocessing import preprocess
from dualid.data.trajectory import Trajectory
from dualid.errors import ConfigError, DataError, DualidError
from dualid.estimators.methods import method as method_entry
from dualid.evaluation.validation import validate
from dualid.model.drag import DragModel
from dualid.problem import Identifiability, IdentificationProblem, build_problem
from dualid.robot.config import FitConfig
from dualid.robot.fit import (
    MethodFit,
    Progress,
    RunOutcome,
    choose_preprocessing,
    column_map,
    estimator,
    run_workflow,
    velocity_source,
    with_bounds,
)
from dualid.robot.inputs import check_runs_differ
from dualid.robot.margin_config import apply_margin
from dualid.robot.uncertainty import method_uncertainty, parameter_errors


def build_drag_model(config: FitConfig) -> DragModel:
    if config.model.kind != "drag" or config.model.drag is None:
        raise ConfigError(f"model.kind: fit_drag needs a drag model (model.kind: drag), got {config.model.kind!r}")
    return DragModel.build(config.model.drag, config.model.urdf)


def check_drag_units(model: DragModel, cmap: ColumnMap) -> None:
    """DataError when a coordinate's unit does not fit it: a linear unit (m, mm, N, …) on an angle, or a
    non-SI angular one (deg, N mm, …) on a length (a planar base's x, y; a prismatic joint)."""
    linear_coords = set(model.linear_coordinates)
    for name in cmap.joint_names:
        for quantity in ("position", "velocity", "acceleration", "effort"):
            unit = cmap.unit(quantity, name)
            linear = unit in LINEAR_UNITS
            if name in linear_coords and not linear and unit != SI_UNITS[quantity]:
                raise DataError(f"column map: coordinate {name!r} is a length but its {quantity} unit is {unit!r} (angular)")
            if name not in linear_coords and linear:
                raise DataError(f"column map: coordinate {name!r} is an angle but its {quantity} unit is {unit!r} (linear)")


def load_drag_runs(paths, cmap: ColumnMap, coordinates: tuple[str, ...], steps) -> list[Trajectory]:
    """Load and preprocess each log (accelerations are not needed)."""
    velocity = velocity_source(cmap)
    return [preprocess(load_log(p, cmap, coordinates, velocity=velocity), [dict(s) for s in steps]) for p in paths]


@dataclass(frozen=True, eq=False)
class DragFitOutcome(RunOutcome):
    config: FitConfig
    model: DragModel
    columns: ColumnMap
    train: tuple[Trajectory, ...]
    test: tuple[Trajectory, ...]
    problem: IdentificationProblem
    identifiability: Identifiability
    fits: dict[str, MethodFit]
    prior: str = ""
    warnings: tuple[str, ...] = ()
    preprocessing_note: str = ""


def fit_drag(config: FitConfig, progress: Progress | None = None) -> DragFitOutcome:
    """The workflow of the module docstring; each log is parsed once, DualidWarnings are recorded in the outcome
    and re-issued (robot.fit.run_workflow)."""
    return run_workflow(_fit_drag, config, progress or (lambda _: None))


def _fit_drag(config: FitConfig, say: Progress) -> DragFitOutcome:
    say(f"building the drag model from {config.model.urdf or 'model.drag.chain'}")
    model = build_drag_model(config)
    coords = model.coordinates
    cmap = column_map(config.columns, coords, config.train[0])
    check_drag_units(model, cmap)
    check_runs_differ(config.train, config.test)
    say(f"loading {len(config.train)} training and {len(config.test)} test logs")
    steps, steps_note = choose_preprocessing(config.preprocessing, config.train[0], cmap, coords)
    train = load_drag_runs(config.train, cmap, coords, steps)
    test = load_drag_runs(config.test, cmap, coords, steps)
    say("building regressors")
    problem = with_bounds(build_problem(model, train), config.bounds)
    theta0, prior_text = model.nominal, ""
    if config.margin is not None:  # every method under C_b(θ) ⪰ ε·C_b(θ_ref) (robot/margin_config.py)
        problem = apply_margin(problem, config.margin, lambda: theta0)  # prior: model.drag's nominal values
    ident = problem.identifiability()
    if theta0 is not None:
        prior_text = "the nominal values of model.drag"
    fits: dict[str, MethodFit] = {}
    for method in config.methods:
        say(f"fitting {method} ({method_entry(method).description})")
        try:
            if method_entry(method).needs_prior and theta0 is None:
                raise ConfigError(f"{method}: needs a prior θ₀: give nominal values for every body (diagonal: "
                                  "[…] or full: [[…]]) and damped joint ({joint: value}) in model.drag")
            est = estimator(method, theta0, config.prior.gamma, config.prior.per_equation,
                            dict(dict(config.solver).get(method, ())))
            result = est.fit(problem)
        except (DualidError, ValueError, np.linalg.LinAlgError, cp.error.DCPError, cp.error.SolverError) as exc:
            fits[method] = MethodFit(method, None, error=f"{type(exc).__name__}: {exc}")
            continue
        validation = None
        if test:
            say(f"validating {method} on {len(test)} held-out runs")
            validation = validate(model, result.theta, test, method, config.xcorr_window)
        base_unc, base_error = method_uncertainty(problem, result, est, ident.base, [len(t.t) for t in train],
                                                  config.uncertainty)
        fits[method] = MethodFit(method, result, parameter_errors(base_unc, ident.base), validation, base=base_unc,
                                 base_error=base_error)
    return DragFitOutcome(config, model, cmap, tuple(train), tuple(test), problem, ident, fits, prior_text,
                          preprocessing_note=steps_note)
