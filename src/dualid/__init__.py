"""dualid: coordinate-independent robot model identification (dual-metric weighted least squares).

The user's whole path, without private imports::

    logs  → load_log / ColumnMap → preprocess → Trajectory
    model → RigidBodyModel (URDF or Pinocchio) / with_joint_terms / DragModel + DragSpec (drag) / LandSalpModel
    build_problem(model, runs) → IdentificationProblem
    OLS / WLS / EnergyLS / RegularizedWLS / DualMetric (or make_estimator(key) from METHODS) .fit
    predict / forward_dynamics / validate / scores → write_urdf
"""

from dualid.data import ColumnMap, JointColumns, Trajectory, load_dataset, load_log, load_logs
from dualid.data.preprocessing import differentiate, filter_lowpass, preprocess, resample, trim
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
from dualid.estimators import (
    OLS,
    WLS,
    DualMetric,
    EnergyLS,
    FeasibleGLS,
    Guarded,
    IdentificationResult,
    RegularizedWLS,
    guard_info,
)
from dualid.estimators.methods import METHODS, Method, make_estimator
from dualid.estimators.uncertainty import BaseUncertainty, base_uncertainty, bootstrap
from dualid.evaluation.prediction import forward_dynamics, predict
from dualid.evaluation.scores import max_normalized_xcorr, metric_rmse, rmse, score_run
from dualid.evaluation.validation import Validation, validate
from dualid.identifiability import BaseParameter, BaseParameters
from dualid.model import (
    AffineMetric,
    MetricTerm,
    Model,
    ParameterBlock,
    ParameterSpace,
    RigidBodyModel,
    with_joint_terms,
)
from dualid.model.drag import DragModel
from dualid.model.drag_spec import DragSpec
from dualid.model.extra_terms import with_base_drag
from dualid.model.joint_terms import JointTermsModel
from dualid.model.landsalp import LandSalpModel
from dualid.problem import Identifiability, IdentificationProblem, build_problem
from dualid.report.urdf import write_urdf

__version__ = "0.1.0"

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
    "OLS", "WLS", "EnergyLS", "RegularizedWLS", "DualMetric", "FeasibleGLS", "Guarded", "guard_info",
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
