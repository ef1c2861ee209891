"""The estimator family, all under the same physical-consistency constraints."""

from dualid.estimators.dual_metric import DualMetric
from dualid.estimators.guards import Guarded, guard_info
from dualid.estimators.least_squares import OLS, WLS, EnergyLS, RegularizedWLS
from dualid.estimators.noise_dm import NoiseModelDM
from dualid.estimators.result import BodyProperties, IdentificationResult

__all__ = [
    "OLS", "WLS", "EnergyLS", "RegularizedWLS", "DualMetric", "NoiseModelDM", "Guarded",
    "guard_info", "IdentificationResult", "BodyProperties",
]
