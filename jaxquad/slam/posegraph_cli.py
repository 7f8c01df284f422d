"""`jaxquad posegraph IN.g2o --out OUT.g2o`: optimize a 2D g2o pose graph (float64, CPU or GPU) and
write it back with the same ids and edges."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from jaxquad.io.atomic import check_output_file
from jaxquad.io.g2o import read_g2o, write_g2o


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("graph", help="input g2o file (VERTEX_SE2, EDGE_SE2, FIX lines)")
    parser.add_argument("--out", required=True, help="output g2o file (written atomically)")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON (default: key: value lines)")
    parser.add_argument(
        "--robust",
        choices=("none", "huber", "cauchy"),
        default="none",
        help="robust kernel on the edges chosen by --robust-edges (default: none)",
    )
    parser.add_argument(
        "--robust-width", type=float, default=1.0, help="kernel width on sqrt(e^T Omega e), unitless (default: 1.0)"
    )
    parser.add_argument(
        "--robust-edges",
        choices=("closures", "all"),
        default="closures",
        help="edges the kernel applies to: loop closures (endpoints not consecutive in the "
        "file's vertex order) or all (default: closures)",
    )
    parser.add_argument(
        "--max-iterations",
        type=int,
        default=100,
        help="Levenberg-Marquardt iterations (linear solves) at most (default: 100)",
    )


def run(args: argparse.Namespace) -> int:
    import jax
    import numpy as np

    if args.max_iterations < 1:
        raise ValueError(f"--max-iterations must be >= 1, got {args.max_iterations}")
    if not (args.robust_width > 0 and np.isfinite(args.robust_width)):
        raise ValueError(f"--robust-width must be positive, got {args.robust_width}")
    check_output_file(args.out, "--out")
    g2o = read_g2o(args.graph)
    with jax.enable_x64(True):
        from jaxquad.slam.solve import optimize_g2o

        out, info, timings = optimize_g2o(
            g2o,
            robust=args.robust,
            robust_width=args.robust_width,
            robust_edges=args.robust_edges,
            max_iterations=args.max_iterations,
        )
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    write_g2o(args.out, out)
    summary = {"n_nodes": len(g2o.ids), "n_edges": len(g2o.edge_ids), **info, **timings}
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        for k, v in summary.items():
            print(f"{k}: {v}")
    return 0
