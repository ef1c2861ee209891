"""Change detection on the innovations of a recursive fit: a windowed χ² test.

Before a batch updates the fit, its innovations r_i = τ_i − Y_i θ̂ (θ̂ from the samples before it) are normalised by
the running innovation covariance Ŝ (exponentially forgotten, time constant ``memory`` samples, updated only while no
alarm is raised):

    z = Σ_{i in window} r_iᵀ Ŝ⁻¹ r_i  ~  χ²(n·w)   while the data agree with the model,

for a window of w samples (consecutive, non-overlapping). The alarm is z above the (1 − α) quantile of χ²(n·w), so
on data without a change a window alarms with probability α, i.e. at a rate of α·f_s/w per second for samples at
f_s Hz (``false_alarm_rate``). An alarming window starts an alarm *event*: the fit's memory is shortened
(``RecursiveFit``), the test pauses while the fit re-converges and Ŝ is learnt afresh (``hold``, ``warmup``). The χ² law assumes independent Gaussian innovations with covariance Ŝ: correlated
noise or model error that the fit has not absorbed raise z, so the false-alarm rate is measured, not only stated.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.stats import chi2

from dualid.errors import ConfigError


@dataclass
class ChiSquareDetector:
    """Windowed χ² test of normalised innovations (module doc). ``warmup``: samples from which Ŝ is learnt before the
    first test; ``hold``: samples after the start of an alarm event that are neither tested nor learnt from (the fit
    re-converges), after which Ŝ is learnt afresh from ``warmup`` samples: a change of the system can change the
    innovations' covariance too (on an arm with noisy accelerations it is Σ_τ + M Σ_a M, and a payload changes M)."""

    n: int
    window: int = 50
    alpha: float = 1e-6
    memory: float = 5000.0
    warmup: int = 1000
    hold: int = 2000
    S: np.ndarray | None = None  # running innovation covariance (n, n)
    _count: int = field(default=0, repr=False)
    _seen: int = field(default=0, repr=False)
    _blind_until: int = field(default=0, repr=False)  # windows ending at or before this sample are skipped
    _learn_until: int = field(default=0, repr=False)  # ... and up to this one only learnt from
    _pending: list = field(default_factory=list, repr=False)  # the current window's innovations

    def __post_init__(self) -> None:
        if not (isinstance(self.window, (int, np.integer)) and self.window >= 1):
            raise ConfigError(f"ChiSquareDetector: window must be a positive integer, got {self.window!r}")
        if not 0.0 < self.alpha < 1.0:
            raise ConfigError(f"ChiSquareDetector: alpha must be in (0, 1), got {self.alpha!r}")
        if not self.memory >= self.window:
            raise ConfigError(f"ChiSquareDetector: memory must be ≥ the window ({self.window}), got {self.memory!r}")
        self.threshold = float(chi2.isf(self.alpha, self.n * self.window))
        self._learn_until = self.warmup

    def false_alarm_rate(self, rate_hz: float) -> float:
        """Alarming windows per second expected on data without a change, at ``rate_hz`` samples per second."""
        return self.alpha * rate_hz / self.window

    def push(self, r: np.ndarray) -> list[tuple[int, float, bool]]:
        """Feed innovations r (B, n); returns (sample index at the window's end, z, new event) per tested window."""
        out = []
        for row in np.atleast_2d(r):
            self._seen += 1
            self._pending.append(row)
            if len(self._pending) < self.window:
                continue
            block = np.asarray(self._pending)
            self._pending = []
            out += self._test(block)
        return out

    def _test(self, block: np.ndarray) -> list[tuple[int, float, bool]]:
        if self._seen <= self._blind_until:
            return []
        outer = block.T @ block / len(block)
        if self.S is None or self._seen <= self._learn_until:
            self._learn(outer, len(block))
            return []
        L = np.linalg.cholesky(self.S + 1e-12 * np.trace(self.S) / self.n * np.eye(self.n))
        w = np.linalg.solve(L, block.T)
        z = float(np.sum(w * w))
        if z > self.threshold:  # an event: skip `hold` samples, then learn Ŝ afresh
            self._blind_until = self._seen + self.hold
            self._learn_until = self._blind_until + self.warmup
            self.S = None
            return [(self._seen - 1, z, True)]
        self._learn(outer, len(block))
        return [(self._seen - 1, z, False)]

    def _learn(self, outer: np.ndarray, count: int) -> None:
        if self.S is None:
            self.S, self._count = outer, count
            return
        total = self._count + count
        keep = min(total, self.memory)  # a running mean until `memory` samples, then exponential forgetting
        self.S = ((keep - count) * self.S + count * outer) / keep
        self._count = total
