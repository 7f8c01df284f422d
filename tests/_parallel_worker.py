"""Runs in a subprocess of tests/test_parallel.py, where the device count (XLA_FLAGS) or the process
group (JAXQUAD_* variables) is set before JAX starts: `python _parallel_worker.py SCENARIO OUT.npz`.

grid:  grid-search counts on 1 and on 2 devices (a grid size that is not a multiple of the chunk),
       and a vmapped function with time-major output split over 2 devices.
fleet: a 3-robot fleet (padding to 4 on 2 devices) simulated on 1 and on 2 devices, and the 1-device
       log estimated on 1 and on 2 devices.
navigate: a 3-robot navigation closed loop (padding to 4 on 2 devices) for one 0.96 s chunk, on 1 and on 2
       devices.
multiprocess: one of two processes: the grid on the devices of both, and a time-major (T, N) array
       split over its robot axis gathered piece by piece; process 0 writes OUT.
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
    res |= {
        "time_major_in": x,
        "d2_time_major": np.asarray(y),
        "d2_shard_shapes": np.array([s.data.shape for s in y.addressable_shards]),
    }
    np.savez(out, **res)


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
    mesh = parallel.mesh()
    x = np.arange(7 * 4 * 3, dtype=np.float32).reshape(7, 4, 3)  # (T, N, 3), N split over the processes
    parallel.GATHER_PIECE_BYTES = 100  # several pieces along T
    res["gathered"] = parallel.gather(parallel.place(x, mesh, 1))
    res["expected"] = x
    if parallel.is_main():
        np.savez(out, **res)


def navigate(out: str) -> None:
    from jaxquad.nav.fleet import NavConfig
    from jaxquad.nav.fleet import navigate as run

    res = {}
    for d in (1, 2):
        cfg = NavConfig(
            n_robots=3, n_goals=1, particles=64, samples=16, horizon=5, chunk_ticks=10, max_seconds=0.5, devices=d
        )
        r = run(cfg)
        res |= {f"d{d}_{k}": np.asarray(getattr(r, k)) for k in ("outcome", "loc_error", "true_pose", "pose", "t")}
    np.savez(out, **res)


if __name__ == "__main__":
    scenarios = {"grid": grid, "fleet": fleet, "navigate": navigate, "multiprocess": multiprocess}
    scenarios[sys.argv[1]](*sys.argv[2:])
