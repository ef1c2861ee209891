"""The uncertainty step of ``fit_robot``: 95 % intervals of the base parameters for every method.

The covariance is dualid.estimators.uncertainty's sandwich H⁻¹BH⁻¹ with the gradients summed over
contiguous segments of the training runs (BLOCKS_PER_PARAMETER × the number of base parameters in all,
at least MIN_BLOCKS, split evenly over the runs), so residuals correlated over less than a segment
(filtering, unmodelled slow effects) do not shrink the intervals the way one-sample blocks would.
Active constraints are detected and recorded; the intervals are those of the unconstrained local fit.

Per parameter (parameters.yaml's ``std_error``): the standard error of its base parameter when the
parameter is a base parameter on its own (β = θ_k); "not identifiable" when the data determine it only
in a combination (see the base parameters) or not at all.
"""

from __future__ import annotations

import numpy as np

from dualid.errors import DualidError
from dualid.estimators.result import IdentificationResult
from dualid.estimators.uncertainty import BaseUncertainty, base_uncertainty, run_segments
from dualid.identifiability import BaseParameters
from dualid.problem import IdentificationProblem

NOT_IDENTIFIABLE = "not identifiable"
BLOCKS_PER_PARAMETER = 10
MIN_BLOCKS = 100


def training_blocks(lengths: list[int], rank: int) -> list[np.ndarray]:
    """Contiguous segments of the training runs (their lengths in samples, in the problem's order)."""
    total = max(BLOCKS_PER_PARAMETER * rank, MIN_BLOCKS)
    return run_segments(lengths, int(np.ceil(total / max(len(lengths), 1))))


def method_uncertainty(problem: IdentificationProblem, result: IdentificationResult, estimator,
                       base: BaseParameters, lengths: list[int]) -> tuple[BaseUncertainty | None, str]:
    """(the base parameters' uncertainty, "") or (None, why it could not be computed): recorded, not fatal."""
    try:
        return base_uncertainty(problem, result, estimator, base, blocks=training_blocks(lengths, base.rank)), ""
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
