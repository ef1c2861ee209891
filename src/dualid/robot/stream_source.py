"""Logs (CSV, Parquet, NPZ or ROS bags) as a chunked source for a streamed fit (``dualid fit-stream``): read and
preprocessed as ``dualid fit`` reads them (column map or bag topics, preprocessing, external wrenches folded into
τ), then handed to the estimator chunk by chunk. The logs are read whole: only the regressor is built per chunk."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dualid.data.tables import reading_once
from dualid.model.rigid_body import RigidBodyModel
from dualid.robot.fit import choose_preprocessing, column_map, load_runs
from dualid.robot.inputs import check_floating
from dualid.streaming import ArraySource


def log_source(rigid: RigidBodyModel, paths, columns=None, preprocessing=None, chunk: int = 65536) -> ArraySource:
    """The preprocessed runs of ``paths`` stacked into one ArraySource."""
    paths = [Path(p) for p in paths]
    joints = tuple(rigid.coordinates)
    with reading_once():
        cmap = column_map(columns, joints, paths[0])
        check_floating(len(rigid.base_coordinates) > 0, cmap)
        steps, _ = choose_preprocessing(preprocessing, paths[0], cmap, joints)
        runs = load_runs(paths, cmap, joints, steps, rigid)
    stack = lambda key: np.concatenate([getattr(r, key) for r in runs])
    return ArraySource(stack("q"), stack("v"), stack("a"), stack("tau"), chunk=chunk)
