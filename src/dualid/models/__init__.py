from dualid.models.base import Model, build_problem

__all__ = ["Model", "build_problem"]
