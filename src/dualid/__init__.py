"""dualid: coordinate-independent robot model identification (dual-metric weighted least squares).

The user's whole path, without private imports::

    logs  → load_log / ColumnMap → preprocess → Trajectory
    model → RigidBodyModel (URDF or Pinocchio) / with_joint_terms / DragModel + DragSpec (drag) / LandSalpModel
    build_problem(model, runs) → IdentificationProblem
    OLS / WLS / EnergyLS / RegularizedWLS / DualMetric (or make_estimator(key) from METHODS) .fit
    predict / forward_dynamics / validate / scores → write_urdf

The public names are imported when first used (module ``__getattr__``), so ``import dualid`` and the
command line's ``--help`` do not pay for scipy, Pinocchio or matplotlib; ``from dualid import OLS``
works as before.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from dualid.errors import (
    ConfigError,
    ConsistencyError,
    DataError,
    DualidError,
    IdentifiabilityError,
    MetricError,
    OutputError,
    SolverError,
)

__version__ = "0.1.0"

# public name → the module that defines it (imported on first access)
_LAZY = {
    **dict.fromkeys(("ColumnMap", "JointColumns", "load_log", "load_logs"), "dualid.data.io"),
    "Trajectory": "dualid.data.trajectory",
    "load_dataset": "dualid.data.dataset",
    **dict.fromkeys(("differentiate", "filter_lowpass", "preprocess", "resample", "trim"),
                    "dualid.data.preprocessing"),
    "Model": "dualid.model.base",
    "RigidBodyModel": "dualid.model.rigid_body",
    **dict.fromkeys(("JointTermsModel", "with_joint_terms"), "dualid.model.joint_terms"),
    "with_base_drag": "dualid.model.extra_terms",
    "LandSalpModel": "dualid.model.landsalp",
    "DragModel": "dualid.model.drag",
    "DragSpec": "dualid.model.drag_spec",
    **dict.fromkeys(("AffineMetric", "MetricTerm"), "dualid.model.metric"),
    **dict.fromkeys(("ParameterBlock", "ParameterSpace"), "dualid.model.parameters"),
    **dict.fromkeys(("IdentificationProblem", "Identifiability", "build_problem"), "dualid.problem"),
    **dict.fromkeys(("BaseParameters", "BaseParameter"), "dualid.identifiability"),
    **dict.fromkeys(("OLS", "WLS", "EnergyLS", "RegularizedWLS"), "dualid.estimators.least_squares"),
    "DualMetric": "dualid.estimators.dual_metric",
    "NoiseModelDM": "dualid.estimators.noise_dm",
    "Guarded": "dualid.evaluation.guards",
    "guard_info": "dualid.metric_guard",
    "IdentificationResult": "dualid.estimators.result",
    **dict.fromkeys(("BaseUncertainty", "base_uncertainty", "bootstrap"), "dualid.evaluation.uncertainty"),
    **dict.fromkeys(("METHODS", "Method", "make_estimator"), "dualid.estimators.methods"),
    **dict.fromkeys(("predict", "forward_dynamics"), "dualid.evaluation.prediction"),
    **dict.fromkeys(("max_normalized_xcorr", "metric_rmse", "rmse", "score_run"), "dualid.evaluation.scores"),
    **dict.fromkeys(("validate", "Validation"), "dualid.evaluation.validation"),
    "write_urdf": "dualid.report.urdf",
}

__all__ = [
    # data
    "ColumnMap", "JointColumns", "Trajectory", "load_dataset", "load_log", "load_logs",
    "differentiate", "filter_lowpass", "preprocess", "resample", "trim",
    # models
    "Model", "RigidBodyModel", "JointTermsModel", "with_joint_terms", "with_base_drag", "LandSalpModel",
    "DragModel", "DragSpec",
    "AffineMetric", "MetricTerm", "ParameterBlock", "ParameterSpace",
    # problem
    "IdentificationProblem", "Identifiability", "BaseParameters", "BaseParameter", "build_problem",
    # estimators
    "OLS", "WLS", "EnergyLS", "RegularizedWLS", "DualMetric", "NoiseModelDM", "Guarded", "guard_info",
    "IdentificationResult", "BaseUncertainty", "base_uncertainty", "bootstrap",
    "METHODS", "Method", "make_estimator",
    # evaluation
    "predict", "forward_dynamics", "validate", "Validation", "max_normalized_xcorr", "metric_rmse", "rmse",
    "score_run",
    # output
    "write_urdf",
    # errors
    "DualidError", "DataError", "ConfigError", "ConsistencyError", "IdentifiabilityError", "MetricError",
    "OutputError", "SolverError",
]


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'dualid' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later accesses skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # static checkers and editors see the names without the runtime import
    from dualid.data.dataset import load_dataset
    from dualid.data.io import ColumnMap, JointColumns, load_log, load_logs
    from dualid.data.preprocessing import differentiate, filter_lowpass, preprocess, resample, trim
    from dualid.data.trajectory import Trajectory
    from dualid.estimators.dual_metric import DualMetric
    from dualid.metric_guard import guard_info
    from dualid.evaluation.guards import Guarded
    from dualid.estimators.least_squares import OLS, WLS, EnergyLS, RegularizedWLS
    from dualid.estimators.methods import METHODS, Method, make_estimator
    from dualid.estimators.noise_dm import NoiseModelDM
    from dualid.estimators.result import IdentificationResult
    from dualid.evaluation.uncertainty import BaseUncertainty, base_uncertainty, bootstrap
    from dualid.evaluation.prediction import forward_dynamics, predict
    from dualid.evaluation.scores import max_normalized_xcorr, metric_rmse, rmse, score_run
    from dualid.evaluation.validation import Validation, validate
    from dualid.identifiability import BaseParameter, BaseParameters
    from dualid.model.base import Model
    from dualid.model.drag import DragModel
    from dualid.model.drag_spec import DragSpec
    from dualid.model.extra_terms import with_base_drag
    from dualid.model.joint_terms import JointTermsModel, with_joint_terms
    from dualid.model.landsalp import LandSalpModel
    from dualid.model.metric import AffineMetric, MetricTerm
    from dualid.model.parameters import ParameterBlock, ParameterSpace
    from dualid.model.rigid_body import RigidBodyModel
    from dualid.problem import Identifiability, IdentificationProblem, build_problem
    from dualid.report.urdf import write_urdf
