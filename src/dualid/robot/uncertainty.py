"""The uncertainty step of ``fit_robot``: 95 % intervals of the base parameters for every method.

The covariance is dualid.evaluation.uncertainty's sandwich H⁻¹BH⁻¹ with the gradients summed over
contiguous segments of the training runs (BLOCKS_PER_PARAMETER × the number of base parameters in all,
at least MIN_BLOCKS, split evenly over the runs), so residuals correlated over less than a segment
(filtering, unmodelled slow effects) do not shrink the intervals the way one-sample blocks would.
Active constraints are detected and recorded; the intervals are those of the unconstrained local fit.

Config (``uncertainty:`` in the fit YAML): method sandwich (default) | bootstrap (refit per resample of the
blocks, seeded, failed refits counted) | none; blocks segments (default) | runs; segments_per_run (default:
the rule above); resamples (200) and seed (0) of the bootstrap.

Per parameter (parameters.yaml's ``std_error``): the standard error of its base parameter when the
parameter is a base parameter on its own (β = θ_k); "not identifiable" when the data determine it only
in a combination (see the base parameters) or not at all.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from dualid.errors import ConfigError, DualidError
from dualid.estimators.result import IdentificationResult
from dualid.evaluation.uncertainty import BaseUncertainty, base_uncertainty, bootstrap, run_segments
from dualid.identifiability import BaseParameters
from dualid.problem import IdentificationProblem

NOT_IDENTIFIABLE = "not identifiable"
BLOCKS_PER_PARAMETER = 10
MIN_BLOCKS = 100
UNCERTAINTY_KEYS = ("method", "blocks", "segments_per_run", "resamples", "seed")


@dataclass(frozen=True)
class UncertaintyConfig:
    method: str = "sandwich"  # "sandwich" | "bootstrap" | "none"
    blocks: str = "segments"  # "segments" (contiguous pieces of each run) | "runs"
    segments_per_run: int | None = None  # None: BLOCKS_PER_PARAMETER × base parameters (≥ MIN_BLOCKS) in all
    resamples: int = 200  # bootstrap only
    seed: int = 0  # bootstrap only

    def __post_init__(self) -> None:
        if self.method not in ("sandwich", "bootstrap", "none"):
            raise ConfigError(f"uncertainty.method: expected 'sandwich', 'bootstrap' or 'none', got {self.method!r}")
        if self.blocks not in ("segments", "runs"):
            raise ConfigError(f"uncertainty.blocks: expected 'segments' or 'runs', got {self.blocks!r}")
        for key, low in (("segments_per_run", 1), ("resamples", 10), ("seed", 0)):
            x = getattr(self, key)
            if x is None and key == "segments_per_run":
                continue
            if isinstance(x, bool) or not isinstance(x, (int, np.integer)) or x < low:
                raise ConfigError(f"uncertainty.{key}: expected an integer ≥ {low}, got {x!r}")

    @staticmethod
    def from_dict(d) -> "UncertaintyConfig":
        if d is None:
            return UncertaintyConfig()
        if not isinstance(d, Mapping):
            raise ConfigError(f"uncertainty: expected a mapping with keys {list(UNCERTAINTY_KEYS)}, got {d!r}")
        unknown = [k for k in d if k not in UNCERTAINTY_KEYS]
        if unknown:
            raise ConfigError(f"uncertainty: unknown keys {unknown}; known keys: {list(UNCERTAINTY_KEYS)}")
        return UncertaintyConfig(**dict(d))

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in UNCERTAINTY_KEYS}


def training_blocks(lengths: list[int], rank: int) -> list[np.ndarray]:
    """Contiguous segments of the training runs (their lengths in samples, in the problem's order)."""
    total = max(BLOCKS_PER_PARAMETER * rank, MIN_BLOCKS)
    return run_segments(lengths, int(np.ceil(total / max(len(lengths), 1))))


def method_uncertainty(problem: IdentificationProblem, result: IdentificationResult, estimator,
                       base: BaseParameters, lengths: list[int],
                       config: UncertaintyConfig = UncertaintyConfig()) -> tuple[BaseUncertainty | None, str]:
    """(the base parameters' uncertainty, "") or (None, why there is none): recorded, not fatal."""
    if config.method == "none":
        return None, "not requested (uncertainty.method: none)"
    if config.blocks == "runs":
        blocks = run_segments(lengths, 1)
    elif config.segments_per_run is not None:
        blocks = run_segments(lengths, config.segments_per_run)
    else:
        blocks = training_blocks(lengths, base.rank)
    try:
        if config.method == "bootstrap":
            return bootstrap(problem, result, estimator, base, blocks, config.resamples, config.seed), ""
        return base_uncertainty(problem, result, estimator, base, blocks=blocks), ""
    except (DualidError, np.linalg.LinAlgError) as exc:
        return None, f"{type(exc).__name__}: {exc}"


def parameter_errors(unc: BaseUncertainty | None, base: BaseParameters) -> tuple[float | str | None, ...]:
    """Per parameter: the standard error of a parameter that is a base parameter on its own, else
    NOT_IDENTIFIABLE; all None when there is no uncertainty."""
    p = base.parameters.p
    if unc is None:
        return (None,) * p
    out: list[float | str | None] = [NOT_IDENTIFIABLE] * p
    se = unc.std_error
    for row, k in enumerate(base.independent):
        if np.count_nonzero(base.C[row]) == 1:
            out[k] = float(se[row])
    return tuple(out)
