"""Checks of logs that catch what would otherwise become silently wrong results.

Errors (DataError) where the data cannot be right: duplicated column names in a CSV header (a reader
could rename or drop one, and the wrong column would be fitted), time stamps that repeat or go back, every
effort and wrench zero (a fit would return a robot without mass as the exact answer).
Warnings (DualidWarning, through Python's ``warnings``; a fit records them in its report) where the
data are probably but not certainly wrong: a median time step too long for a robot log (time in
ms read as s?), a logged velocity whose size disagrees with dq/dt, one joint's effort zero throughout.
``resample`` refuses to interpolate across a gap (``check_gaps``) or to invent most of a run's
samples (``check_upsampling``).
"""

from __future__ import annotations

import csv
import warnings
from pathlib import Path

import numpy as np

from dualid.errors import DataError, DualidWarning

MAX_GAP_STEPS = 20.0  # a step longer than this many median steps is a gap (resample refuses to bridge it)
MAX_UPSAMPLING = 20.0  # resample refuses rates that invent more than this many samples per logged one
SLOW_LOG_STEP = 0.1  # [s] a median step longer than this is unusual for a robot log (time in ms?)
MAX_MAGNITUDE = 1e12  # no robot logs a position, velocity or effort beyond this in SI units
VELOCITY_RATIO = 3.0  # warn when RMS(logged v) / RMS(dq/dt) is beyond [1/3, 3] for a joint


def csv_header(path: Path) -> list[str]:
    """The column names of a CSV file's first line; DataError if a name appears twice."""
    with open(path, newline="") as f:
        header = next(csv.reader(f), [])
    names = [h.strip() for h in header]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        cols = {n: [k for k, h in enumerate(names) if h == n] for n in dup}
        raise DataError(
            f"{path}: column names appear more than once in the header: {cols} (name: 0-based positions); "
            "rename them so each column is addressed unambiguously"
        )
    return names


def check_time(path, t_raw: np.ndarray, t: np.ndarray, column: str) -> None:
    """Time stamps strictly increasing (DataError naming the rows), and a warning when the median step
    is long for a robot log (t in seconds, t_raw as logged)."""
    dt = np.diff(t)
    if np.any(dt == 0):
        k = int(np.argmax(dt == 0))
        raise DataError(
            f"{path}: time column {column!r} repeats a time stamp: rows {k} and {k + 1} both have {t_raw[k]}; "
            f"{int(np.sum(dt == 0))} repeated stamps in all (drop duplicated rows first)"
        )
    if np.any(dt < 0):
        k = int(np.argmax(dt < 0))
        raise DataError(
            f"{path}: time column {column!r} must be strictly increasing; "
            f"row {k} has {t_raw[k]} and row {k + 1} has {t_raw[k + 1]} (time goes back)"
        )
    med = float(np.median(dt))
    if med > SLOW_LOG_STEP:
        warnings.warn(
            f"{path}: the median time step is {med:.4g} s ({1 / med:.3g} Hz), slow for a robot log; if time is "
            "logged in ms or µs, set the column map's units: {time: ms}", DualidWarning, stacklevel=3)


def check_velocity(path, t: np.ndarray, q: np.ndarray, v: np.ndarray, joints) -> None:
    """Warn when the logged velocity's size disagrees with dq/dt (wrong unit, wrong column, time unit)."""
    dq = np.gradient(q, t, axis=0)
    for j, name in enumerate(joints):
        rms_v, rms_dq = float(np.sqrt(np.mean(v[:, j] ** 2))), float(np.sqrt(np.mean(dq[:, j] ** 2)))
        if rms_dq == 0 and rms_v == 0:
            continue
        ratio = np.inf if rms_dq == 0 else rms_v / rms_dq
        if not 1 / VELOCITY_RATIO <= ratio <= VELOCITY_RATIO:
            warnings.warn(
                f"{path}: joint {name!r}: the logged velocity is {ratio:.3g} × dq/dt in RMS ({rms_v:.4g} vs "
                f"{rms_dq:.4g}); check the velocity column, its unit and the time unit", DualidWarning, stacklevel=3)


def check_gaps(t: np.ndarray, what: str = "resample") -> None:
    """DataError when one step is longer than MAX_GAP_STEPS median steps (interpolation would invent it)."""
    dt = np.diff(t)
    med = float(np.median(dt))
    k = int(np.argmax(dt))
    if dt[k] > MAX_GAP_STEPS * med:
        raise DataError(
            f"{what}: a gap of {dt[k]:.4g} s ({dt[k] / med:.0f} median steps of {med:.4g} s) between rows {k} and "
            f"{k + 1} (t = {t[k]:.6g} s and {t[k + 1]:.6g} s); refusing to interpolate across it: split the log "
            "there or trim to one side"
        )


def check_upsampling(t: np.ndarray, rate: float) -> None:
    """DataError when resampling at ``rate`` would invent more than MAX_UPSAMPLING samples per logged one."""
    med = float(np.median(np.diff(t)))
    factor = med * rate
    if factor > MAX_UPSAMPLING:
        raise DataError(
            f"resample: the log's median step is {med:.4g} s ({1 / med:.3g} Hz), {factor:.0f} × the step at "
            f"{rate:g} Hz: {factor:.0f} samples would be invented per logged one. Is time logged in ms? set the "
            "column map's units: {time: ms}; otherwise resample at a rate near the log's own"
        )


def check_magnitude(path, name: str, x: np.ndarray) -> None:
    """DataError when a channel (in SI units) exceeds MAX_MAGNITUDE: a unit or scaling error, and
    numbers that large overflow the squares of a least-squares fit."""
    peak = float(np.max(np.abs(x))) if x.size else 0.0
    if peak > MAX_MAGNITUDE:
        raise DataError(f"{path}: column {name!r} reaches {peak:.3g} in SI units; more than {MAX_MAGNITUDE:.0e} is not a "
                        "robot measurement (check its unit and scaling)")


def check_effort(path, tau: np.ndarray, wrench: np.ndarray | None, columns, floating: bool) -> None:
    """DataError when every generalized force and external wrench is 0 in every row (nothing to identify: the
    fit's exact answer would be a massless robot); a warning for each mapped effort column that is 0 throughout."""
    named = [c for c in columns if c is not None]
    if not np.any(tau) and (wrench is None or not np.any(wrench)):
        if floating and wrench is None:
            raise DataError(
                f"{path}: every generalized force is 0: the floating base has no wrench section (columns.wrenches) and "
                f"{'the joints have no effort columns' if not named else 'the effort columns ' + str(named) + ' are 0'}; "
                "a free body's motion without the forces on it determines no mass. Map the external wrenches")
        raise DataError(f"{path}: every effort{' and wrench' * (wrench is not None)} column is 0 in every row "
                        f"({', '.join(map(str, named)) or 'no effort columns'}): nothing to identify (efforts not logged?)")
    offset = tau.shape[1] - len(columns)  # a floating base's 6 coordinates come first
    for k, c in enumerate(columns):
        if c is not None and not np.any(tau[:, offset + k]):
            warnings.warn(f"{path}: effort column {c!r} is 0 in every row (an unactuated joint? then leave its effort "
                          "out of the column map; or the effort was not logged)", DualidWarning, stacklevel=3)


def check_efforts(paths, runs, cmap) -> None:
    """``check_effort`` for each run (loaded with the column map ``cmap``)."""
    for path, run in zip(paths, runs):
        check_effort(path, run.tau, run.wrench, [j.effort for j in cmap.joints], cmap.base is not None)
