"""Runs in a subprocess of tests/test_parallel.py, where the device count (XLA_FLAGS) or the process
group (JAXQUAD_* variables) is set before JAX starts: `python _parallel_worker.py SCENARIO OUT.npz`.

grid:  grid-search counts on 1 and on 2 devices (a grid size that is not a multiple of the chunk),
       a vmapped function with time-major output split over 2 devices, and a toy closed loop
       (`jaxquad.nav.fleet_loop`: per-robot and shared inputs, random keys, the replan flag) of 3 robots
       on 1 and on 2 devices.
fleet: a 3-robot fleet (padding to 4 on 2 devices) simulated on 1 and on 2 devices, and the 1-device
       log estimated on 1 and on 2 devices.
multiprocess: one of two processes: the grid and the SLAM on the devices of both, and a time-major (T, N)
       array split over its robot axis gathered piece by piece; process 0 writes OUT.
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np


def grid_problem(n_robots: int = 3, samples: int = 40, seed: int = 0):
    """Observer inputs of a robot standing still (p constant) whose feet take random forces: the
    momentum balance dp/dt = tau_bar + J^T f gives tau_bar = -J^T f (+ noise)."""
    from jaxquad.estimate.tune import ContactTruth, GridSpec, ObserverInputs
    from jaxquad.kernels import ObserverParams

    rng = np.random.default_rng(seed)
    nj, feet = 12, 4
    J = rng.normal(0.0, 0.3, (n_robots, samples, feet, nj))
    force = np.clip(rng.normal(20.0, 25.0, (n_robots, samples, feet)), 0.0, None)
    tau_bar = -np.einsum("ntfj,ntf->ntj", J, force) + rng.normal(0.0, 0.5, (n_robots, samples, nj))
    p = np.zeros((n_robots, samples, nj))
    dt = np.full((n_robots, samples), 0.004)
    dt[:, 0] = np.nan
    restart = np.zeros((n_robots, samples), bool)
    restart[:, 0] = True
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    inputs = ObserverInputs(
        p=f32(p), tau_bar=f32(tau_bar), J_z=f32(J), dt=f32(dt), restart=jnp.asarray(restart), axes="z"
    )
    truth = ContactTruth(
        contact=jnp.asarray(force > 5.0), force_z=f32(force), valid=jnp.ones((n_robots, samples), bool)
    )
    spec = GridSpec.default((3, 2, 1, 2, 1))  # 12 configurations
    return spec.params(ObserverParams.paper(feet, "mixed")), inputs, truth


def _counts(devices):
    from jaxquad.estimate.tune import grid_counts

    counts = grid_counts(*grid_problem(), chunk=5, devices=devices)
    return {k: np.asarray(getattr(counts, k)) for k in ("tp", "fp", "fn", "force_sq", "samples")}


def grid(out: str) -> None:
    from jaxquad import parallel

    res = {f"d{d}_{k}": v for d in (1, 2) for k, v in _counts(d).items()}
    mesh = parallel.mesh(2)
    x = np.arange(20, dtype=np.float32).reshape(4, 5)  # 4 robots x 5 samples
    y = jax.jit(parallel.shard_batched(jax.vmap(jnp.cumsum, out_axes=1), mesh, (0,), 1))(parallel.place(x, mesh))
    res |= _toy_loop()
    res |= {
        "time_major_in": x,
        "d2_time_major": np.asarray(y),
        "d2_shard_shapes": np.array([s.data.shape for s in y.addressable_shards]),
    }
    np.savez(out, **res)


def _toy_loop() -> dict:
    """state = qpos0 * scale + noise(key); each tick adds `shared`, halved on ticks without the replan flag."""
    import equinox as eqx

    from jaxquad import parallel
    from jaxquad.nav.fleet_loop import loop_functions, place_robots

    class Inputs(eqx.Module):
        scale: jax.Array  # per robot
        shared: jax.Array
        replan: jax.Array

    def init(params, inputs, qpos0, key):
        return qpos0 * inputs.scale + params * jax.random.normal(key, qpos0.shape)

    def tick(params, state, inputs):
        state = state + inputs.shared * jnp.where(inputs.replan, 1.0, 0.5)
        return state, state.sum()

    axes = lambda inputs: Inputs(0, None, None)  # noqa: E731
    inputs = Inputs(jnp.array([1.0, 2.0, 3.0]), jnp.array([0.1, -0.2]), jnp.asarray(True))
    qpos0 = np.arange(6, dtype=np.float32).reshape(3, 2)
    res = {}
    for d in (1, 2):
        mesh = parallel.mesh(d)
        fleet_init, chunk = loop_functions(init, tick, axes, mesh)
        params, placed, q, keys = place_robots(mesh, jnp.asarray(0.01), inputs, axes, qpos0, seed=5)
        states = fleet_init(params, placed, q, keys)
        res[f"toy_d{d}_init"] = np.asarray(states)[:3]
        states, out = chunk(params, states, placed, n_ticks=6, replan_ticks=3)
        res[f"toy_d{d}_final"], res[f"toy_d{d}_out"] = np.asarray(states)[:3], np.asarray(out)[:, :3]
        res[f"toy_d{d}_shards"] = np.array([s.data.shape[0] for s in states.addressable_shards])
    return res


FLEET_KEYS = ("q", "acc", "gt_pose", "gt_force", "depth", "fallen")
ESTIMATE_KEYS = ("p_world_base", "v_base", "contact")


def _fleet_config(devices):
    from jaxquad.sim import FleetConfig

    return FleetConfig(n_robots=3, n_worlds=2, seed=1, width=16, height=12, frames_per_chunk=4, devices=devices)


def _estimate(log, devices) -> dict:
    from jaxquad.estimate.run import estimate_log

    _, _, est = estimate_log(log, "truth", devices=devices)
    return {f"est_{k}": np.asarray(getattr(est, k)) for k in ESTIMATE_KEYS}


def fleet(out: str) -> None:
    from jaxquad.sim import rollout

    res, logs = {}, {}
    for d in (1, 2):
        logs[d] = rollout(_fleet_config(d), 0.25, progress=False)
        res |= {f"d{d}_{k}": np.asarray(logs[d][k]) for k in FLEET_KEYS}
    for d in (1, 2):  # the same log on 1 and 2 devices
        res |= {f"d{d}_{k}": v for k, v in _estimate(logs[1], d).items()}
    np.savez(out, **res)


def multiprocess(out: str) -> None:
    from jaxquad import parallel

    parallel.initialize()
    assert jax.process_count() == 2 and jax.device_count() == 2, (jax.process_count(), jax.device_count())
    res = {f"grid_{k}": v for k, v in _counts(None).items()}
    res |= {f"slam_{k}": v for k, v in slam_run(None).items()}
    mesh = parallel.mesh()
    x = np.arange(7 * 4 * 3, dtype=np.float32).reshape(7, 4, 3)  # (T, N, 3), N split over the processes
    parallel.GATHER_PIECE_BYTES = 100  # several pieces along T
    res["gathered"] = parallel.gather(parallel.place(x, mesh, 1))
    res["expected"] = x
    if parallel.is_main():
        np.savez(out, **res)


def slam_run(devices) -> dict:
    """Online SLAM of 3 robots (padded to 4 on 2 devices) along drifting odometry in a NumPy-cast box world
    (also run on this process's one device by the tests, as the reference)."""
    from _laser2d import box, cast

    from jaxquad.kernels.scan_grid import MatchSpec, cells_for_range
    from jaxquad.slam import SlamParams, SlamSpec, final_poses, grid_spec, run_fleet

    world = np.concatenate([box(-4, -3, 4, 3), box(-1.0, -0.6, 1.0, 0.6), box(2.5, -3.0, 3.0, -2.2)])
    bearings = np.linspace(-np.pi, np.pi, 90, endpoint=False)
    S, dt = 40, 0.1
    s = np.linspace(0.0, 1.0, S)
    truth = np.stack([[-2.5 + 4.0 * s, -1.8 + 0.2 * r + 0 * s, 0.3 * s + 0.1 * r] for r in range(3)])
    truth = truth.transpose(0, 2, 1)  # (3 robots, S, 3)
    drift = np.array([1.04, 1.04, 1.0])
    odom = truth[:, :1] + (truth - truth[:, :1]) * drift  # 4 % scale error on x and y
    twist = np.gradient(truth, dt, axis=1)
    x = {
        "t": np.arange(S) * dt,
        "odom": odom,
        "ranges": np.stack([[cast(world, p, bearings, 5.0) for p in robot] for robot in truth]),
        "bearings": bearings,
        "T_base_laser": np.zeros(3),
        "valid": np.ones((3, S), bool),
        "lo_twist": twist,
        "lo_twist_cov": np.broadcast_to(np.diag([0.01, 0.01, 4e-4]), (3, S, 3, 3)),
        "lo_valid": np.ones((3, S), bool),
    }
    spec = SlamSpec(
        grid=grid_spec((-5.0, -4.0, 5.0, 4.0), 0.1, 5.0),
        nodes=24,
        buffer=8,
        match=MatchSpec(cells=cells_for_range(3.0, 0.01, 50)),
        lo_constraints="preintegrated",
    )
    state, outs, _ = run_fleet(spec, SlamParams(), x, devices=devices)
    return {
        "final": final_poses(state, outs),
        "online": np.asarray(outs.pose),
        "n_nodes": np.asarray(state.n_nodes),
        "log_odds": np.asarray(state.grid.log_odds),
    }


if __name__ == "__main__":
    scenarios = {
        "grid": grid,
        "fleet": fleet,
        "multiprocess": multiprocess,
    }
    scenarios[sys.argv[1]](*sys.argv[2:])
