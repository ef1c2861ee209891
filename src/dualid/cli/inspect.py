"""``dualid inspect``: what a ROS bag holds, and a starter fit config that reads it."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from dualid.cli.app import FLAG, app


def _summary_lines(summary) -> list[str]:
    rows = [("topic", "type", "messages", "rate [Hz]", "duration [s]")]
    rows += [(t.topic, t.msgtype, str(t.count), f"{t.rate:.4g}", f"{t.duration:.4g}") for t in summary.topics]
    widths = [max(len(r[k]) for r in rows) for k in range(5)]
    count = f"{len(summary.topics)} topic{'' if len(summary.topics) == 1 else 's'}"
    out = [f"{summary.path}: {summary.kind}, {summary.duration:.4g} s, {count}"]
    for k, r in enumerate(rows):
        out.append("  " + "  ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths))))
        t = summary.topics[k - 1] if k else None
        if t is not None and t.joints:
            out.append(f"    joints: {', '.join(t.joints)}" + ("" if t.velocity else " (no velocities)"))
        if t is not None and t.frames:
            out.append(f"    frames: {', '.join(t.frames)}")
    return out


@app.command()
def inspect(
    bag: Path = typer.Argument(..., help="a ROS 1 .bag file or a rosbag2 folder (sqlite3 or MCAP)"),
    model: Optional[Path] = typer.Option(None, "--model", help="the robot's URDF, written into the starter config"),
    list_topics: bool = typer.Option(False, "--list-topics", metavar=FLAG, help="the topics only, no starter config"),
) -> None:
    """Print a bag's topics (message types, counts, rates, durations, joint names and frames) as YAML comments,
    then a starter fit config reading its joint states, base and wrenches:
    dualid inspect run.bag --model robot.urdf > fit.yaml; dualid fit --config fit.yaml --out results"""
    import yaml

    from dualid.data.bag_inspect import bag_summary
    from dualid.data.bags import is_bag
    from dualid.errors import DataError, MissingFileError
    from dualid.robot.inputs import starter_config

    if not bag.exists():
        raise MissingFileError(f"bag not found: {bag}")
    if not is_bag(bag):
        raise DataError(f"{bag}: not a ROS bag (expected a .bag file, a rosbag2 folder with metadata.yaml, or its "
                        ".db3/.mcap file)")
    summary = bag_summary(bag)
    lines = [f"# {line}" for line in _summary_lines(summary)]
    if not list_topics:
        lines += ["#", f"# starter config: dualid inspect {bag} --model ROBOT.urdf > fit.yaml; "
                       "dualid fit --config fit.yaml --out results"]
        lines += yaml.safe_dump(starter_config(summary, model), sort_keys=False).splitlines()
    typer.echo("\n".join(lines))
