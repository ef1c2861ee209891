"""dualid: coordinate-independent robot model identification (dual-metric weighted least squares)."""

from dualid.data import Trajectory
from dualid.estimators import OLS, WLS, DualMetric, EnergyLS, IdentificationResult, RegularizedWLS
from dualid.model import AffineMetric, MetricTerm, Model, ParameterBlock, ParameterSpace
from dualid.problem import IdentificationProblem, build_problem

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
