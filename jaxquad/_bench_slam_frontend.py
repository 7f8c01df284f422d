"""SLAM front-end section of `jaxquad bench`: correlative scan matches and likelihood-grid builds.

Scans are cast (160 beams over 360 deg, 0.3 m above the floor, ranges beyond 4 m invalid) in the
generated `house` world with the project's box caster. Each batch item has its own reference (the
grid of 8 scans taken within 0.1 m of a place on the house's route) and its own query scan, taken
up to 0.2 m and 15 deg away; the prior is the reference place. The search: +-0.3 m at 0.01 m and
+-20 deg, either exactly at 0.5 deg ("exact 0.5 deg": 81 angles, then a refinement of +-0.5 deg)
or Karto's way (exactly at 2 deg, then refined at 0.5 deg within +-2 deg). Batch 1 is the plain
single-match call; larger batches vmap it. The grid build is timed apart (a SLAM step builds one per
match, as Karto does, or reuses it between nodes).
"""

from __future__ import annotations

import argparse

_BEAMS = 160
_MAX_RANGE = 4.0  # m
_N_REF = 8  # scans in each reference grid
_SENSOR_Z = 0.3  # m


def add_arguments(parser) -> None:
    parser.add_argument(
        "--frontend-repeats", type=int, default=20, help="steady calls timed per row (median; default 20)"
    )
    parser.add_argument(
        "--frontend-candidates",
        type=int,
        default=4,
        help="coarse blocks expanded per round of the exact search (default: 4; under vmap every item runs "
        "as many rounds as the batch's worst item)",
    )
    parser.add_argument(
        "--frontend-max-rounds",
        type=int,
        default=None,
        help="cap on those rounds (default: none, every match exact; capped matches report exact = False)",
    )


def _inputs(batch: int, seed: int = 0):
    """Reference scans (batch, n_ref, beams), their poses, query scans (batch, beams), priors and true poses."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxquad.kernels import Boxes
    from jaxquad.kernels.raycast import ray_distance
    from jaxquad.sim.worlds import make_world

    world = make_world("house", 0)
    boxes = Boxes(jnp.asarray(world.center), jnp.asarray(world.half), jnp.asarray(world.yaw))
    rng = np.random.default_rng(seed)
    a = world.anchors
    k, u = rng.integers(len(a), size=batch), rng.random(batch)[:, None]
    places = a[k] + u * (a[(k + 1) % len(a)] - a[k])  # on the route's segments
    prior = np.concatenate([places, rng.uniform(-np.pi, np.pi, (batch, 1))], 1)
    ref_poses = prior[:, None, :] + rng.uniform(-1, 1, (batch, _N_REF, 3)) * [0.1, 0.1, 0.05]
    true = prior + rng.uniform(-1, 1, (batch, 3)) * [0.2, 0.2, np.deg2rad(15.0)]
    bearings = np.linspace(-np.pi, np.pi, _BEAMS, endpoint=False)

    def scan(pose):
        angle = pose[2] + bearings
        d = jnp.stack([jnp.cos(angle), jnp.sin(angle), jnp.zeros_like(angle)], -1)
        r = ray_distance(jnp.array([pose[0], pose[1], _SENSOR_Z]), d, boxes)
        return jnp.where(r <= _MAX_RANGE, r, jnp.inf)

    cast = jax.jit(jax.vmap(scan))
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    ref_ranges = cast(f32(ref_poses.reshape(-1, 3))).reshape(batch, _N_REF, _BEAMS)
    query = cast(f32(true))
    return f32(ref_poses), ref_ranges, f32(prior), query, f32(bearings), true


def _specs(candidates: int = 4, max_rounds: int | None = None) -> dict:
    from jaxquad.kernels.scan_grid import MatchSpec, cells_for_range

    cells = cells_for_range(_MAX_RANGE, 0.01, 30)
    common = dict(
        cells=cells,
        resolution=0.01,
        window_cells=30,
        angle_window_deg=20.0,
        block=16,
        candidates=candidates,
        max_rounds=max_rounds,
    )
    return {
        "exact 0.5 deg": MatchSpec(angle_step_deg=0.5, fine_angle_step_deg=0.5, **common),
        "2 deg + 0.5 deg refine": MatchSpec(angle_step_deg=2.0, fine_angle_step_deg=0.5, **common),
    }


def bench_frontend(batches=(1, 4096), repeats: int = 20, candidates: int = 4, max_rounds: int | None = None) -> dict:
    """Rows of (what, spec, batch, compile_s, run_ms, per_item_us, throughput_per_s) and match accuracy."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxquad.bench import time_jitted
    from jaxquad.kernels.scan_grid import MatchParams, likelihood_grid, world_points
    from jaxquad.kernels.scan_match import match_scan

    params = MatchParams(range_max=jnp.asarray(_MAX_RANGE))
    rows, accuracy = [], {}
    for batch in batches:
        ref_poses, ref_ranges, prior, query, bearings, true = _inputs(batch)
        for name, spec in _specs(candidates, max_rounds).items():

            def build(ref_poses, ref_ranges, prior, spec=spec, bearings=bearings):
                pts, mask = world_points(params, ref_poses, ref_ranges, bearings, jnp.isfinite(ref_ranges))
                return likelihood_grid(spec, params, prior[:2], pts, mask)

            def match(grid, prior, ranges, spec=spec, bearings=bearings):
                return match_scan(spec, params, grid, prior, ranges, bearings, jnp.isfinite(ranges))

            single = batch == 1
            build_j = jax.jit(build if single else jax.vmap(build))
            match_j = jax.jit(match if single else jax.vmap(match))
            args = (ref_poses[0], ref_ranges[0], prior[0]) if single else (ref_poses, ref_ranges, prior)
            for what in ("grid build", "scan match"):
                if what == "grid build":  # timed before its first call, so that its compile time counts
                    fn, fn_args = build_j, args
                else:
                    grid = build_j(*args)
                    fn, fn_args = match_j, (grid, prior[0], query[0]) if single else (grid, prior, query)
                compile_s, run_ms = time_jitted(fn, *fn_args, repeats=repeats)
                rows.append(
                    {
                        "what": what,
                        "spec": name,
                        "batch": batch,
                        "compile_s": round(compile_s, 3),
                        "run_ms": round(run_ms, 4),
                        "per_item_us": round(1e3 * run_ms / batch, 3),
                        "throughput_per_s": round(batch / (run_ms * 1e-3), 1),
                    }
                )
            out = match_j(*fn_args)
            pose = np.asarray(out.pose).reshape(-1, 3)
            err_xy = np.linalg.norm(pose[:, :2] - true[:, :2], axis=1)
            err_t = np.abs(np.angle(np.exp(1j * (pose[:, 2] - true[:, 2]))))
            accuracy[f"{name}, batch {batch}"] = {
                "median_err_m": round(float(np.median(err_xy)), 4),
                "p95_err_m": round(float(np.percentile(err_xy, 95)), 4),
                "median_err_deg": round(float(np.rad2deg(np.median(err_t))), 3),
                "mean_expanded_blocks": round(float(np.mean(np.asarray(out.expanded))), 1),
                "max_expanded_blocks": int(np.max(np.asarray(out.expanded))),
                "exact_fraction": round(float(np.mean(np.asarray(out.exact))), 4),
                "mean_response": round(float(np.mean(np.asarray(out.response))), 3),
            }
            del grid, out
    return {"rows": rows, "accuracy": accuracy, "beams": _BEAMS, "max_range_m": _MAX_RANGE, "reference_scans": _N_REF}


def run(args: argparse.Namespace) -> dict:
    repeats = getattr(args, "frontend_repeats", 20)
    if repeats < 1:
        raise ValueError(f"--frontend-repeats must be >= 1, got {repeats}")
    candidates = getattr(args, "frontend_candidates", 4)
    if candidates < 1:
        raise ValueError(f"--frontend-candidates must be >= 1, got {candidates}")
    max_rounds = getattr(args, "frontend_max_rounds", None)
    if max_rounds is not None and max_rounds < 1:
        raise ValueError(f"--frontend-max-rounds must be >= 1, got {max_rounds}")
    return bench_frontend(tuple(args.batch), repeats, candidates, max_rounds)
