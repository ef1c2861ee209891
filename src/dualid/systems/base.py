"""A simulated system as the studies see it: model, training and test runs, truth and a prior.

Each system module registers a factory ``make(seed, noise, size) -> SystemData`` under its name.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from dualid.data.trajectory import Trajectory
from dualid.errors import ConfigError
from dualid.model.base import Model

Noise = Literal["realistic", "ideal", "none"]  # ideal: i.i.d. Gaussian force noise only; none: exact data
Size = Literal["default", "small"]  # small: a few short runs, for tests and smoke runs


@dataclass(frozen=True, eq=False)
class SystemData:
    name: str
    model: Model
    train: tuple[Trajectory, ...]
    test: tuple[Trajectory, ...]
    theta_true: np.ndarray  # (p,) the parameters the data were simulated with
    theta_nominal: np.ndarray  # (p,) a CAD-like prior, deliberately off the truth, physically consistent
    low_data_samples: int  # training samples kept in the low-data case (paper: 20 Crazyflie, 40 LandSalp)
    slowest_period: float  # [s] period of the slowest excitation; scores search shifts within ±T/72
    shape_coordinates: tuple[str, ...]  # the internal (shape) coordinates the paper highlights
    gamma: float = 0.1  # prior weight of the regularized baselines, per equation (γ·N·n; see RegularizedWLS)
    description: str = ""


Factory = Callable[..., SystemData]
_REGISTRY: dict[str, str] = {
    "pan-tilt": "dualid.systems.pan_tilt",
    "crazyflie": "dualid.systems.crazyflie",
    "landsalp": "dualid.systems.landsalp",
}


def system_names() -> tuple[str, ...]:
    return tuple(_REGISTRY)


def make_system(name: str, seed: int = 0, noise: Noise = "realistic", size: Size = "default", **kw) -> SystemData:
    """The simulated data set of a named system (each module defines ``make(seed, noise, size, **kw)``)."""
    import importlib

    if name not in _REGISTRY:
        raise ConfigError(f"unknown system {name!r}; expected one of {sorted(_REGISTRY)}")
    module = importlib.import_module(_REGISTRY[name])
    return module.make(seed=seed, noise=noise, size=size, **kw)
