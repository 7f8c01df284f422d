"""A closed loop run over a fleet, its robots split over devices: what `navigate` and `explore` share.

A loop is a pair of pure single-robot functions, `init(params, inputs, qpos0, key) -> state` and
`tick(params, state, inputs) -> (state, out)`, whose inputs carry a `replan` flag. `loop_functions`
vmaps them over the robots and jits `init` and `chunk` (a `lax.scan` of `n_ticks` ticks, the flag set
every `replan_ticks`), with the robots split over a device mesh (`jaxquad.parallel`: states at axis 0,
the time-major outputs (T, N, ...) at axis 1); `compile_chunk` compiles a chunk once per process for each
set of argument shapes. `place_robots` pads the robots to a multiple of the
devices with copies of the last (computed and dropped) and puts every argument on the mesh.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxquad import parallel


def loop_functions(init, tick, input_axes, mesh):
    """Jitted (init, chunk) of a fleet; `input_axes(inputs)` gives the inputs' vmap axes (a prefix pytree:
    0 for per-robot leaves, None for shared ones). `chunk` donates its states."""

    def fleet_init(params, inputs, qpos0, keys):
        ax = (None, input_axes(inputs), 0, 0)
        return parallel.shard_batched(jax.vmap(init, in_axes=ax), mesh, ax, 0)(params, inputs, qpos0, keys)

    def chunk(params, states, inputs, n_ticks: int, replan_ticks: int):
        def run(params, states, inputs):
            def body(s, i):
                at_i = eqx.tree_at(lambda x: x.replan, inputs, i % replan_ticks == 0)
                return jax.vmap(tick, in_axes=(None, 0, input_axes(at_i)))(params, s, at_i)

            return jax.lax.scan(body, states, jnp.arange(n_ticks))

        ax = (None, 0, input_axes(inputs))
        return parallel.shard_batched(run, mesh, ax, (0, 1))(params, states, inputs)

    return jax.jit(fleet_init), jax.jit(chunk, static_argnames=("n_ticks", "replan_ticks"), donate_argnums=(1,))


# (chunk, argument structure, shapes, types and placement, n_ticks, replan_ticks) -> compiled chunk.
_COMPILED: dict = {}


def compile_chunk(chunk, params, states, inputs, n_ticks: int, replan_ticks: int):
    """The compiled `chunk` for these arguments, reused by later runs with arguments of the same structure,
    shapes and placement (the values may differ)."""
    leaves, treedef = jax.tree.flatten((params, states, inputs))
    sig = tuple((np.shape(x), getattr(x, "dtype", type(x)), getattr(x, "sharding", None)) for x in leaves)
    key = (chunk, treedef, sig, n_ticks, replan_ticks)
    if key not in _COMPILED:
        _COMPILED[key] = chunk.lower(params, states, inputs, n_ticks=n_ticks, replan_ticks=replan_ticks).compile()
    return _COMPILED[key]


def start_qpos(robot, starts: np.ndarray) -> np.ndarray:
    """(N, nq) the robot's home posture with its base at the planar starts (N, 3) x y yaw."""
    qpos0 = np.tile(robot.qpos_home, (len(starts), 1))
    a = robot.base_qpos_adr
    qpos0[:, a : a + 2] = starts[:, :2]
    zero = np.zeros(len(starts))
    qpos0[:, a + 3 : a + 7] = np.stack([np.cos(starts[:, 2] / 2), zero, zero, np.sin(starts[:, 2] / 2)], 1)
    return qpos0


def place_robots(mesh, params, inputs, input_axes, qpos0: np.ndarray, seed: int):
    """(params, inputs, qpos0, keys) on the mesh: the robots (and their random keys, one per robot from
    `seed`) padded to a multiple of the devices, the parameters replicated."""
    n = len(qpos0)
    keys = jax.random.split(jax.random.key(seed), n)
    ax = (input_axes(inputs), 0, 0)
    robots = parallel.pad((inputs, jnp.asarray(qpos0, jnp.float32), keys), parallel.padded_size(n, mesh), ax)
    return (parallel.place(params, mesh, None), *parallel.place(robots, mesh, ax))


def keep_first(out, n_trace: int, fields: tuple[str, ...]):
    """A chunk's outputs (a dataclass of time-major (T, N, ...) arrays) on the host, with `fields` kept for
    the first `n_trace` robots only (sliced on the device: only what is kept is copied)."""
    return jax.device_get(dataclasses.replace(out, **{f: getattr(out, f)[:, :n_trace] for f in fields}))
