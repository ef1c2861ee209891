"""Models: parameters and their physical consistency, metrics, rigid bodies, joint terms, drag, URDF."""

from dualid.model.base import Model
from dualid.model.joint_terms import with_joint_terms
from dualid.model.metric import AffineMetric, MetricTerm
from dualid.model.parameters import ParameterBlock, ParameterSpace, rigid_body_space
from dualid.model.rigid_body import RigidBodyModel

__all__ = [
    "AffineMetric", "MetricTerm", "Model", "ParameterBlock", "ParameterSpace", "RigidBodyModel",
    "rigid_body_space", "with_joint_terms",
]
