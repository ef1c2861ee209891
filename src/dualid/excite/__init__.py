"""Optimal excitation trajectories: periodic Fourier-series joint motions, at rest at both
ends, optimised for identification under the robot's limits. Computes and returns values; the files
are written by ``dualid.report.excite`` and the command is ``dualid excite``."""

from dualid.excite.config import CRITERIA, ExciteConfig
from dualid.excite.design import Design, Limits, build_design
from dualid.excite.fourier import FourierTrajectory
from dualid.excite.optimize import Excitation, LimitCheck, check_limits, optimize, random_trajectory

__all__ = [
    "CRITERIA", "Design", "Excitation", "ExciteConfig", "FourierTrajectory", "LimitCheck", "Limits", "build_design",
    "check_limits", "optimize", "random_trajectory",
]
