"""The estimator family, all under the same physical-consistency constraints."""

from dualid.estimators.dual_metric import DualMetric
from dualid.estimators.least_squares import OLS, WLS, EnergyLS, RegularizedWLS
from dualid.estimators.noise_dm import NoiseModelDM
from dualid.estimators.result import BodyProperties, IdentificationResult
from dualid.metric_guard import guard_info

__all__ = [
    "OLS", "WLS", "EnergyLS", "RegularizedWLS", "DualMetric", "NoiseModelDM", "guard_info",
    "IdentificationResult", "BodyProperties",
]
