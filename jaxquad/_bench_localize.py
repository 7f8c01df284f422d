"""Localization section of `jaxquad bench`: one AMCL update (omnidirectional motion sampling,
likelihood field of `--loc-beams` beams, recovery averages, low-variance resampling) for R robots x
P particles, `vmap`ped over robots, on a 20 m x 20 m map at 0.05 m (400 x 400 cells).

Every timed call updates: each robot has used a scan already and its odometry has moved 0.3 m and
0.1 rad since. Scans have 160 columns (the simulated depth camera's width) subsampled to the beam
count, ranges uniform in 0.3-9 m (readings beyond the 8 m maximum are skipped, as on the robot).
"""

from __future__ import annotations

import argparse


def add_arguments(parser) -> None:
    parser.add_argument(
        "--loc-robots",
        type=int,
        nargs="+",
        default=[1, 64],
        metavar="R",
        help="robots per localization update (default: 1 64; 4096 on a GPU)",
    )
    parser.add_argument(
        "--loc-particles", type=int, default=2000, metavar="P", help="particles per robot (default 2000)"
    )
    parser.add_argument("--loc-beams", type=int, default=60, metavar="B", help="beams per scan (default 60)")


def _map(rng):
    import numpy as np

    grid = np.zeros((400, 400), np.int8)
    grid[:3], grid[-3:], grid[:, :3], grid[:, -3:] = 100, 100, 100, 100
    for _ in range(40):  # random rooms' walls and furniture
        r, c = rng.integers(10, 380, 2)
        h, w = rng.integers(3, 60, 2)
        grid[r : r + h, c : c + w] = 100
    return grid


def update_inputs(robots: int, particles: int, beams: int, seed: int = 0):
    """(params, field, states, inputs) of one update for `robots` robots (leading axis)."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxquad.kernels import AmclInputs, AmclParams, amcl_init, likelihood_field

    rng = np.random.default_rng(seed)
    field = likelihood_field(_map(rng), 0.05, (0.0, 0.0), 2.0)
    params = AmclParams.paper(n_beams=beams)
    keys = jax.random.split(jax.random.PRNGKey(seed), (2, robots))
    start = jnp.asarray(np.column_stack([rng.uniform(2, 18, (robots, 2)), rng.uniform(-3, 3, robots)]), jnp.float32)
    states = jax.vmap(lambda p, k: amcl_init(params, field, p, k, particles))(start, keys[0])
    states = eqx.tree_at(lambda s: s.started, states, jnp.ones(robots, bool))
    inputs = AmclInputs(
        odom=jnp.tile(jnp.array([0.3, 0.0, 0.1]), (robots, 1)),
        ranges=jnp.asarray(rng.uniform(0.3, 9.0, (robots, 160)), jnp.float32),
        bearings=jnp.tile(jnp.linspace(-0.76, 0.76, 160), (robots, 1)),
        key=keys[1],
    )
    return params, field, states, inputs


def run(args: argparse.Namespace) -> dict:
    import jax

    from jaxquad.bench import time_jitted
    from jaxquad.kernels import amcl_step

    robots = getattr(args, "loc_robots", [1, 64])
    particles, beams = getattr(args, "loc_particles", 2000), getattr(args, "loc_beams", 60)
    if min(robots) < 1 or particles < 1 or beams < 1:
        raise ValueError(
            f"--loc-robots, --loc-particles and --loc-beams must be >= 1, got {robots}, {particles}, {beams}"
        )
    step = jax.jit(jax.vmap(amcl_step, in_axes=(None, None, 0, 0)))
    rows = []
    for r in robots:
        params, field, states, inputs = update_inputs(r, particles, beams)
        compile_s, run_ms = time_jitted(step, params, field, states, inputs, repeats=getattr(args, "repeats", 20))
        if not bool(step(params, field, states, inputs)[1].updated.all()):
            raise RuntimeError("benchmark inputs did not trigger an update")
        rows.append(
            {
                "kernel": "amcl update",
                "robots": r,
                "particles": particles,
                "beams": beams,
                "compile_s": compile_s,
                "run_ms": run_ms,
                "beam_evals_per_s": r * particles * beams / (run_ms * 1e-3),
            }
        )
    return {"rows": rows}
