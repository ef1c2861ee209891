"""Regenerate the drag example: swimmer.urdf and simulated logs of a 4-link swimmer (dualid.systems.swimmer).

    python examples/drag/make_data.py [--seed 0] [--out examples/drag]

Writes swimmer.urdf, train_0..2.csv (20 s each, random joint excitation) and test_swim/turn/fast.csv
(15 s travelling-wave gaits), logged at 50 Hz: time, base pose (x, y, theta) from motion capture,
12-bit joint encoders, velocities, and efforts (zero on the passive base; joint torques with noise and
a gain error). Then:  dualid fit --config examples/drag/drag.yaml --out results/drag
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from dualid.model.drag import DragModel
from dualid.model.drag_spec import DragSpec
from dualid.systems import swimmer as sw

RATE = 50.0  # [Hz] log rate
TRAIN_SECONDS, TEST_SECONDS = 20.0, 15.0
COLUMNS = ("x", "y", "theta") + sw.JOINTS


def write_run(path: Path, log: dict) -> None:
    table = {"time": log["t"]}
    for k, c in enumerate(COLUMNS):
        table[f"{c}_pos"] = log["q"][:, k]
        table[f"{c}_vel"] = log["v"][:, k]
        table[f"{c}_eff"] = log["tau"][:, k]
    pd.DataFrame(table).to_csv(path, index=False, float_format="%.7g")


def make(out: Path, seed: int = 0, effects: sw.TrueEffects = sw.TrueEffects(), exact: bool = False) -> dict[str, Path]:
    """Write the example into ``out``; ``effects``: what the true system has beyond the model; ``exact``: the
    exact states and efforts (no sensor noise)."""
    out.mkdir(parents=True, exist_ok=True)
    urdf = out / "swimmer.urdf"
    urdf.write_text(sw.swimmer_urdf())
    model = DragModel.from_urdf(urdf, DragSpec.from_dict(sw.TRUE_DRAG))
    true = sw.TrueSwimmer(model, model.nominal, effects)
    rng = np.random.default_rng(seed)
    written = {"swimmer.urdf": urdf}
    runs = [(f"train_{k}", sw.excitation(rng), TRAIN_SECONDS) for k in range(3)]
    runs += [(f"test_{g}", sw.gait(g), TEST_SECONDS) for g in ("swim", "turn", "fast")]
    for name, reference, seconds in runs:
        t, q, v, tau = sw.simulate(true, reference, seconds, RATE)
        path = out / f"{name}.csv"
        write_run(path, {"t": t, "q": q, "v": v, "tau": tau} if exact else sw.measure(t, q, v, tau, rng))
        written[path.name] = path
    return written


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent)
    args = parser.parse_args()
    for name in make(args.out, args.seed):
        print("wrote", args.out / name)
