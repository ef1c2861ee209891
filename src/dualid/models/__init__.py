from dualid.models.base import Model, build_problem
from dualid.models.joint_terms import with_joint_terms
from dualid.models.rigid_body import RigidBodyModel

__all__ = ["Model", "build_problem", "RigidBodyModel", "with_joint_terms"]
