"""Optimizing a g2o graph end to end: build the padded `PoseGraph`, compile, solve, time both."""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxquad.io.g2o import G2oGraph
from jaxquad.kernels.posegraph import SolverParams, optimize
from jaxquad.slam.graph import build_graph

_optimize = jax.jit(optimize)


def g2o_pose_graph(g2o: G2oGraph, robust: str = "none", robust_edges: str = "closures", dtype=None):
    """The `PoseGraph` of a g2o file: FIX vertices fixed (the first vertex if none), the robust kernel
    on loop closures (edges whose endpoints are not consecutive in file order) or on all edges."""
    ij = g2o.edge_index()
    kinds = np.full(len(ij), robust, object)
    if robust_edges == "closures":
        kinds[np.abs(ij[:, 1] - ij[:, 0]) == 1] = "none"
    return build_graph(
        g2o.poses,
        ij[:, 0],
        ij[:, 1],
        g2o.measurement,
        g2o.information,
        fixed=g2o.fixed_mask(),
        robust=kinds,
        dtype=dtype,
    )


def optimize_g2o(
    g2o: G2oGraph,
    *,
    robust: str = "none",
    robust_width: float = 1.0,
    robust_edges: str = "closures",
    max_iterations: int = 100,
) -> tuple[G2oGraph, dict, dict]:
    """(optimized graph, solve info as plain numbers, {"compile_s", "solve_s"}). Runs in the current
    dtype setting (call inside `jax.enable_x64(True)` for float64, as the CLI does)."""
    graph = g2o_pose_graph(g2o, robust, robust_edges)
    params = SolverParams(max_iterations=jnp.asarray(max_iterations), robust_width=jnp.asarray(robust_width))
    t0 = time.perf_counter()
    compiled = _optimize.lower(graph, params).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    out, info = jax.block_until_ready(compiled(graph, params))
    solve_s = time.perf_counter() - t0
    summary = {
        "initial_chi2": float(info.initial_chi2),
        "final_chi2": float(info.final_chi2),
        "iterations": int(info.iterations),
        "cg_iterations": int(info.cg_iterations),
        "converged": bool(info.converged),
    }
    if robust != "none":
        summary["initial_robust_cost"] = float(info.initial_cost)
        summary["final_robust_cost"] = float(info.final_cost)
    optimized = dataclasses.replace(g2o, poses=np.asarray(out.poses, np.float64))
    return optimized, summary, {"solve_s": solve_s, "compile_s": compile_s}
