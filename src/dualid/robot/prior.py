"""θ₀, the prior of the regularized methods and of the plausible parameters (``prior_theta``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dualid.data.files import read_mapping
from dualid.errors import DataError
from dualid.evaluation.plausible_newton import torque_weights
from dualid.model.rigid_body import RigidBodyModel
from dualid.problem import IdentificationProblem
from dualid.robot.config import FitConfig


def prior_theta(config: FitConfig, rigid: RigidBodyModel, model, ols_theta: np.ndarray | None,
                problem: IdentificationProblem) -> tuple[np.ndarray, str]:
    """θ₀ for the regularized methods and the plausible parameters, and a sentence saying where it came from.

    "urdf": the URDF's inertials; joint terms (absent from a URDF's inertials) take the given estimate
    (``ols_theta``: the method's own fit, or OLS's) floored at 1e-3 × the value that alone would explain its
    joint's measured torque (``evaluation.plausible_newton.torque_weights``; a log-det prior needs θ₀ > 0, and a
    floor relative to the data keeps it at the data's scale, whatever the units).
    A file: a parameters.json/yaml written by a previous fit ("file#method" picks the method, default
    its first fitted one), or any file with a 'parameters' list of {name, value}; matched by name.
    """
    p0 = rigid.parameters.p
    theta0 = np.full(model.parameters.p, np.nan)
    if config.prior.source == "urdf":
        theta0[:p0] = rigid.nominal
        what = f"the inertials of {config.model.urdf.name}"
    else:
        source, _, pick = config.prior.source.partition("#")
        path = Path(source)
        d = read_mapping(path, "prior.source parameters file")
        if "methods" in d:  # a parameters.yaml/json of a previous fit: "file#method" or its first fitted method
            fitted = [m for m, e in d["methods"].items() if "parameters" in e]
            if not fitted or (pick and pick not in fitted):
                raise DataError(f"prior.source {path}: no fitted method {pick or ''!r}; fitted methods: {fitted}")
            d = d["methods"][pick or fitted[0]]
        try:
            values = {str(e["name"]): float(e["value"]) for e in d.get("parameters", [])}
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"prior.source {path}: 'parameters' must be a list of {{name, value}} with numeric "
                            f"values; {type(exc).__name__}: {exc}") from None
        missing = [n for n in rigid.parameters.names if n not in values]
        if missing:
            raise DataError(f"prior.source {path}: no values for parameters {missing}")
        theta0 = np.array([values.get(n, np.nan) for n in model.parameters.names])
        what = f"the parameters in {path}"
    if model is not rigid:
        weights = torque_weights(problem)
        for b in model.parameters.blocks:
            idx = np.array(b.indices)
            if idx[0] < p0:
                continue
            floor = 1e-3 / np.sqrt(weights[idx])
            src = np.where(np.isnan(theta0[idx]), ols_theta[idx] if ols_theta is not None else floor, theta0[idx])
            theta0[idx] = np.maximum(src, floor)
        what += ("; joint terms it lacks (a URDF has none) from the fit, each at least 1e-3 × the value that alone "
                 "would explain its joint's measured torque")
    return theta0, what
