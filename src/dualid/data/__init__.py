"""Data: trajectories, robot logs in (CSV/Parquet/NPZ through a column map), preprocessing, data sets."""

from dualid.data.dataset import load_dataset
from dualid.data.io import ColumnMap, JointColumns, load_log, load_logs
from dualid.data.trajectory import Trajectory

__all__ = ["ColumnMap", "JointColumns", "Trajectory", "load_dataset", "load_log", "load_logs"]
