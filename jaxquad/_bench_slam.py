"""`jaxquad bench --slam`: pose-graph optimization against GTSAM's Levenberg-Marquardt on the same
generated graphs in the same run, batched graphs, and occupancy scan insertions per second.

Single graphs run in float64 (as `jaxquad posegraph`), batched graphs and occupancy in float32. Both
optimizers start from the same odometry initial values and stop at the same relative decrease
(1e-6); chi2 is g2o's (sum e^T Omega e) evaluated by our function at each optimizer's poses. When
gtsam is not importable (e.g. on a GPU machine) its rows are left out and `gtsam` says so.
"""

from __future__ import annotations

import argparse
import time


def add_arguments(parser: argparse._ArgumentGroup) -> None:  # the bench command's group for this section
    parser.add_argument(
        "--slam-nodes",
        type=int,
        nargs="+",
        default=[1000, 3500, 10000],
        metavar="N",
        help="nodes of the single graphs timed against GTSAM (default: 1000 3500 10000)",
    )
    parser.add_argument(
        "--slam-batch",
        type=int,
        default=64,
        metavar="N",
        help="graphs optimized at once in the batched row (default: 64; 4096 on a GPU)",
    )
    parser.add_argument(
        "--slam-batch-nodes",
        type=int,
        default=500,
        metavar="N",
        help="nodes per batched graph (default: 500; ~1.3 edges per node)",
    )
    parser.add_argument(
        "--slam-robots", type=int, default=8, metavar="N", help="robots in the batched occupancy row (default: 8)"
    )


def _gtsam_lm(sg):
    import gtsam
    import numpy as np

    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for k, x in enumerate(sg.initial):
        values.insert(k, gtsam.Pose2(*x))
    graph.add(gtsam.NonlinearEqualityPose2(0, gtsam.Pose2(*sg.initial[0])))
    for i, j, z, omega in zip(sg.edge_i, sg.edge_j, sg.measurement, sg.information):
        noise = gtsam.noiseModel.Gaussian.Information(omega)
        graph.add(gtsam.BetweenFactorPose2(int(i), int(j), gtsam.Pose2(*z), noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-6)
    params.setAbsoluteErrorTol(1e-9)
    params.setMaxIterations(100)
    t0 = time.perf_counter()
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = optimizer.optimize()
    wall = time.perf_counter() - t0
    poses = np.array(
        [[result.atPose2(k).x(), result.atPose2(k).y(), result.atPose2(k).theta()] for k in range(len(sg.initial))]
    )
    return poses, wall, optimizer.iterations()


def _single_graphs(sizes: list[int], gtsam_ok: bool) -> list[dict]:
    import jax
    import jax.numpy as jnp

    from jaxquad.bench import time_jitted
    from jaxquad.kernels.posegraph import SolverParams, chi2, optimize
    from jaxquad.slam.graph import build_graph
    from jaxquad.slam.synthetic import manhattan_graph

    rows = []
    fn = jax.jit(optimize)
    for n in sizes:
        sg = manhattan_graph(n, seed=n, size=max(20, int(n**0.5)))
        with jax.enable_x64(True):
            graph = build_graph(sg.initial, sg.edge_i, sg.edge_j, sg.measurement, sg.information)
            params = SolverParams()
            compile_s, run_ms = time_jitted(fn, graph, params, repeats=3, budget_s=5.0)
            _, info = fn(graph, params)
            row = {
                "case": f"manhattan {n} nodes",
                "n_edges": len(sg.edge_i),
                "compile_s": compile_s,
                "solve_s": run_ms / 1e3,
                "iterations": int(info.iterations),
                "initial_chi2": float(info.initial_chi2),
                "final_chi2": float(info.final_chi2),
            }
            if gtsam_ok:
                poses, wall, iterations = _gtsam_lm(sg)
                row.update(
                    gtsam_solve_s=wall,
                    gtsam_iterations=iterations,
                    gtsam_final_chi2=float(chi2(graph, jnp.asarray(poses))),
                )
                row["time_ratio"] = row["solve_s"] / wall
                row["chi2_rel_diff"] = row["final_chi2"] / row["gtsam_final_chi2"] - 1.0
        rows.append(row)
    return rows


def _batched_graphs(batch: int, nodes: int) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxquad.bench import time_jitted
    from jaxquad.kernels.posegraph import SolverParams, optimize
    from jaxquad.slam.graph import build_graph, stack_graphs
    from jaxquad.slam.synthetic import manhattan_graph

    # 16 distinct graphs tiled to the batch (generating thousands in Python would dominate the run).
    graphs = [manhattan_graph(nodes, seed=s) for s in range(min(16, batch))]
    m_cap = max(len(g.edge_i) for g in graphs)
    built = [
        build_graph(g.initial, g.edge_i, g.edge_j, g.measurement, g.information, edge_capacity=m_cap, dtype=jnp.float32)
        for g in graphs
    ]
    stacked = stack_graphs([built[k % len(built)] for k in range(batch)])
    fn = jax.jit(jax.vmap(optimize, in_axes=(0, None)))
    params = SolverParams()
    compile_s, run_ms = time_jitted(fn, stacked, params, repeats=5, budget_s=10.0)
    _, info = fn(stacked, params)
    # float32 against float64 on the same graphs (the distinct ones).
    with jax.enable_x64(True):
        ref = [
            float(
                jax.jit(optimize)(
                    build_graph(g.initial, g.edge_i, g.edge_j, g.measurement, g.information), SolverParams()
                )[1].final_chi2
            )
            for g in graphs[:4]
        ]
    ratio = np.asarray(info.final_chi2[: len(ref)], np.float64) / np.asarray(ref)
    return {
        "batched_case": f"{batch} graphs x {nodes} nodes (~{m_cap} edges), float32",
        "batched_compile_s": compile_s,
        "batched_run_s": run_ms / 1e3,
        "batched_graphs_per_s": batch / (run_ms / 1e3),
        "batched_converged_fraction": float(np.mean(np.asarray(info.converged))),
        "batched_max_iterations": int(np.max(np.asarray(info.iterations))),
        "batched_chi2_over_float64_max": float(ratio.max()),
    }


def _occupancy(robots: int) -> list[dict]:
    import jax
    import jax.numpy as jnp

    from jaxquad.bench import time_jitted
    from jaxquad.kernels.occupancy import GridSpec, OccupancyParams, init_grid, insert_scan, map_from_scans

    spec = GridSpec(rows=800, cols=800, resolution=0.05, origin_x=-20.0, origin_y=-20.0, max_range=20.0)
    params = OccupancyParams(range_max=jnp.asarray(20.0))
    bearings = jnp.linspace(-jnp.pi, jnp.pi, 160, endpoint=False)
    t = 50
    key = jax.random.PRNGKey(0)
    ranges = jax.random.uniform(key, (robots, t, 160), minval=0.5, maxval=25.0)  # ~20 % no-return rays
    poses = jnp.stack([jnp.linspace(-3, 3, t), jnp.zeros(t), jnp.linspace(0, 3, t)], -1)
    poses = jnp.broadcast_to(poses, (robots, t, 3))
    rows = []
    one = jax.jit(insert_scan)
    c, ms = time_jitted(one, spec, params, init_grid(spec), poses[0, 0], ranges[0, 0], bearings)
    rows.append(
        {
            "case": "insert_scan, 1 robot (160 beams, 800 x 800 cells of 0.05 m, 20 m range)",
            "compile_s": c,
            "run_ms": ms,
            "scans_per_s_per_robot": 1e3 / ms,
        }
    )
    seq = jax.jit(map_from_scans)
    c, ms = time_jitted(seq, spec, params, poses[0], ranges[0], bearings, repeats=5)
    rows.append(
        {
            "case": f"map_from_scans, 1 robot x {t} scans (lax.scan)",
            "compile_s": c,
            "run_ms": ms,
            "scans_per_s_per_robot": t * 1e3 / ms,
        }
    )
    fleet = jax.jit(jax.vmap(map_from_scans, in_axes=(None, None, 0, 0, None)))
    c, ms = time_jitted(fleet, spec, params, poses, ranges, bearings, repeats=3)
    rows.append(
        {
            "case": f"map_from_scans, {robots} robots x {t} scans (vmap)",
            "compile_s": c,
            "run_ms": ms,
            "scans_per_s_per_robot": t * 1e3 / ms,
            "scans_per_s_total": robots * t * 1e3 / ms,
        }
    )
    return rows


def run(args: argparse.Namespace) -> dict:
    import importlib.util
    import os

    for name in ("slam_batch", "slam_batch_nodes", "slam_robots"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if any(n < 20 for n in args.slam_nodes):
        raise ValueError(f"--slam-nodes must be >= 20, got {args.slam_nodes}")
    gtsam_ok = importlib.util.find_spec("gtsam") is not None
    out = {"rows": _single_graphs(args.slam_nodes, gtsam_ok)}
    out["gtsam"] = (
        "LevenbergMarquardtOptimizer, same graphs and stopping rule"
        if gtsam_ok
        else "not importable: GTSAM rows skipped"
    )
    out.update(_batched_graphs(args.slam_batch, args.slam_batch_nodes))
    out["occupancy"] = _occupancy(args.slam_robots)
    out["cpu_count"] = os.cpu_count()
    return out
