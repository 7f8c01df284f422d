"""`jaxquad export DIR --bag OUT [--format mcap|sqlite3|ros1]`: results as a ROS bag for RViz/Foxglove.

DIR is the output folder of `jaxquad estimate` or any folder of TUM trajectories, scans and maps;
the topics written are listed in jaxquad.ros.export.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dir", help="results folder (TUM trajectories, <name>_scans.npz, map YAML + PGM)")
    parser.add_argument("--bag", required=True, help="output bag: a .bag file for ros1, else a ROS 2 bag folder")
    parser.add_argument(
        "--format",
        choices=("mcap", "sqlite3", "ros1"),
        default="mcap",
        help="bag format: ROS 2 mcap, ROS 2 sqlite3 or ROS 1 (default: mcap)",
    )
    parser.add_argument("--frame", default="odom", help="world frame of trajectories and maps (default: odom)")


def run(args: argparse.Namespace) -> int:
    import json

    from jaxquad.ros.export import export

    print(json.dumps(export(args.dir, args.bag, args.format, args.frame), indent=2))
    return 0
