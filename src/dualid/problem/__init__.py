from dualid.problem.metric import AffineMetric, MetricTerm
from dualid.problem.parameters import ParameterBlock, ParameterSpace, rigid_body_space
from dualid.problem.problem import Identifiability, IdentificationProblem

__all__ = [
    "AffineMetric",
    "MetricTerm",
    "ParameterBlock",
    "ParameterSpace",
    "rigid_body_space",
    "Identifiability",
    "IdentificationProblem",
]
