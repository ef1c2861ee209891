"""Write the DFKI double-pendulum runs as ROS bags (sensor_msgs/JointState on /joint_states, one bag per run),
for trying ``dualid inspect`` and ``dualid fit`` on bags (docs/real-robot.md, "From a ROS bag").

    python examples/dfki/to_bag.py OUT_DIR [--storage mcap|sqlite3|ros1]

Each row becomes one message stamped with the row's time (rounded to the nanosecond) after a fixed epoch; the
joints are listed as a robot driver might list them (Joint2 first).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

DATA = Path(__file__).resolve().parent / "data"
EPOCH = 1_660_000_000 * 10**9  # [ns] 2022-08-08, about when the runs were recorded
MSGTYPE = "sensor_msgs/msg/JointState"


def write_run(csv: Path, out: Path, storage: str) -> Path:
    ros1 = storage == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    Time, Header, JointState = (ts.types[t] for t in ("builtin_interfaces/msg/Time", "std_msgs/msg/Header", MSGTYPE))
    df = pd.read_csv(csv)
    path = out / (f"{csv.stem}.bag" if ros1 else csv.stem)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=plugin)
    with writer:
        conn = writer.add_connection("/joint_states", MSGTYPE, typestore=ts)
        for k, r in enumerate(df.itertuples()):
            ns = EPOCH + int(round(r.time * 1e9))
            header = Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9), frame_id="", **({"seq": k} if ros1 else {}))
            msg = JointState(header, ["Joint2", "Joint1"], np.array([r.pos_meas2, r.pos_meas1]),
                             np.array([r.vel_meas2, r.vel_meas1]), np.array([r.tau_meas2, r.tau_meas1]))
            writer.write(conn, ns, ts.serialize_ros1(msg, MSGTYPE) if ros1 else ts.serialize_cdr(msg, MSGTYPE))
    return path


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--storage", choices=("mcap", "sqlite3", "ros1"), default="mcap")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for csv in sorted(DATA.glob("trajectory_0*.csv")):
        print(write_run(csv, args.out, args.storage))
