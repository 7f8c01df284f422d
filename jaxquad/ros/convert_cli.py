"""`jaxquad convert BAG --topics topics.yaml --robot NAME --out log.npz`: a robot log from a ROS bag.

The bag's kind comes from its path: a `.bag` file is ROS 1; a folder with metadata.yaml, or a
`.mcap` / `.db3` file, is ROS 2. The topics file is described in jaxquad.ros.topics; examples lie
in jaxquad/ros/examples/.
"""

from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", help="ROS 1 .bag file, or ROS 2 bag folder / .mcap / .db3 file")
    parser.add_argument("--topics", required=True, help="topics file (YAML) mapping bag topics to log roles")
    parser.add_argument(
        "--robot", required=True, help="robot name (go2, badger) or path of its MJCF; sets the joint order"
    )
    parser.add_argument("--out", required=True, help="output robot log (.npz)")


def run(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from jaxquad.ros.convert import convert

    log = convert(args.bag, args.topics, args.robot, args.out)
    t = np.asarray(log["t"])
    brief = {
        "out": str(args.out),
        "samples": int(t.size),
        "duration_s": float(t[-1]),
        "keys": sorted(log),
        "depth_frames": len(log.get("depth_t", [])),
    }
    print(json.dumps(brief, indent=2))
    return 0
