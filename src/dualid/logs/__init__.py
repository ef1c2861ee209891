"""Robot logs in (CSV/Parquet/NPZ through a column map) and data sets on disk."""

from dualid.logs.dataset import load_dataset, save_dataset
from dualid.logs.io import ColumnMap, JointColumns, load_log, load_logs

__all__ = ["ColumnMap", "JointColumns", "load_log", "load_logs", "save_dataset", "load_dataset"]
