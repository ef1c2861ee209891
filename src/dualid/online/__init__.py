"""Online identification: a recursive fit with forgetting or a window, a consistent projection at a lower rate, and
a change detector on its innovations (``estimator``, ``detector``, ``restrict``)."""

from dualid.online.detector import ChiSquareDetector
from dualid.online.estimator import RecursiveFit, Step
from dualid.online.restrict import free_indices, free_space, restrict

__all__ = ["ChiSquareDetector", "RecursiveFit", "Step", "free_indices", "free_space", "restrict"]
