"""dualid: coordinate-independent robot model identification (dual-metric weighted least squares)."""

from dualid.estimators import OLS, WLS, DualMetric, EnergyLS, IdentificationResult, RegularizedWLS
from dualid.models import Model, build_problem
from dualid.problem import AffineMetric, IdentificationProblem, MetricTerm, ParameterBlock, ParameterSpace
from dualid.trajectories import Trajectory

__version__ = "0.1.0"

__all__ = [
    "OLS",
    "WLS",
    "EnergyLS",
    "RegularizedWLS",
    "DualMetric",
    "IdentificationResult",
    "IdentificationProblem",
    "AffineMetric",
    "MetricTerm",
    "ParameterBlock",
    "ParameterSpace",
    "Model",
    "build_problem",
    "Trajectory",
]
