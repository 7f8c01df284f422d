"""Fleets and sweeps across devices and processes: one batch axis (robots, or configurations of a
sweep) split over a 1-D device mesh, every device running the one-device program on its own block.

Devices: `mesh(n)` takes the first n devices (default all of them: every local device, or in a
multi-process run every device of every process). A batch whose size is not a multiple of the
device count is padded with copies of its last element (`pad`): they are computed and dropped
(`unpad`), so every real element gets the numbers it gets on one device.

Programs: `shard_batched(fn, mesh, in_axes, out_axes)` pins a batched (vmapped) function's
arguments and results to the batch split; XLA's partitioner gives each device its block with no
communication, so the compiled per-device program is the one-device program at 1/n of the batch,
and XLA's memory analysis of it is per device. Axes follow `vmap`'s `in_axes`: an int is the batch
axis of every leaf below it (time-major fleet outputs (T, N, ...) have it at 1), None marks a leaf
shared by all (replicated).

Processes: `initialize()` starts `jax.distributed` when JAXQUAD_NUM_PROCESSES > 1 is set, with
JAXQUAD_COORDINATOR (host:port of process 0) and JAXQUAD_PROCESS_ID (0 .. n-1); which accelerators a
process uses is set as usual (CUDA_VISIBLE_DEVICES, or JAX_LOCAL_DEVICE_IDS). Every process runs the
same command on the same inputs; `gather` brings results into host memory (a collective: every
process calls it) and `is_main()` (process 0) writes them. CPU processes talk through gloo.
"""

from __future__ import annotations

import functools
import math
import os

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

__all__ = ["BATCH", "gather", "initialize", "is_main", "mesh", "pad", "padded_size", "place", "shard_batched", "unpad"]

BATCH = "batch"  # the mesh's one axis name
GATHER_PIECE_BYTES = 1 << 28  # a multi-process gather replicates pieces of at most this size on every device
BARRIER_S = 3600.0  # how long processes wait for each other before a collective
_ENV = ("JAXQUAD_COORDINATOR", "JAXQUAD_NUM_PROCESSES", "JAXQUAD_PROCESS_ID")
_state = {"initialized": False, "barriers": 0}


def initialize() -> None:
    """Start `jax.distributed` from the JAXQUAD_* environment variables, once, when they ask for more
    than one process (it must come before any JAX computation; `mesh` calls it)."""
    if _state["initialized"] or int(os.environ.get("JAXQUAD_NUM_PROCESSES") or 1) <= 1:
        return
    missing = [k for k in _ENV if not os.environ.get(k)]
    if missing:
        raise ValueError(f"a multi-process run needs {', '.join(_ENV)}; missing {', '.join(missing)}")
    n, pid = int(os.environ["JAXQUAD_NUM_PROCESSES"]), int(os.environ["JAXQUAD_PROCESS_ID"])
    if not 0 <= pid < n:
        raise ValueError(f"JAXQUAD_PROCESS_ID must lie in [0, {n}), got {pid}")
    jax.config.update("jax_cpu_collectives_implementation", "gloo")  # CPU processes only; GPUs use NCCL
    jax.distributed.initialize(os.environ["JAXQUAD_COORDINATOR"], n, pid)
    _state["initialized"] = True


def is_main() -> bool:
    """True in process 0 (the one that writes results), and in a one-process run."""
    return jax.process_index() == 0


def mesh(devices: int | None = None) -> Mesh:
    """1-D mesh (axis `BATCH`) over the first `devices` devices (None: all; in a multi-process run
    all of them, since every process must hold a part)."""
    initialize()
    available = jax.devices()
    n = len(available) if devices is None else int(devices)
    if not 1 <= n <= len(available):
        raise ValueError(f"--devices must lie in [1, {len(available)}] (the devices this run sees), got {n}")
    if jax.process_count() > 1 and n != len(available):
        raise ValueError(f"a {jax.process_count()}-process run uses all {len(available)} devices; got --devices {n}")
    return Mesh(np.array(available[:n]), (BATCH,))


def padded_size(n: int, mesh: Mesh) -> int:
    """Smallest multiple of the mesh's device count that holds `n` elements."""
    return math.ceil(n / mesh.size) * mesh.size


def _axes_map(fn, axes, tree):
    """fn(axis, leaf) over `tree`, with `axes` a prefix of it (ints or None, as vmap's in_axes)."""
    return jax.tree.map(lambda a, sub: jax.tree.map(lambda x: fn(a, x), sub), axes, tree, is_leaf=lambda a: a is None)


def pad(tree, size: int, axes=0):
    """Pad the batch axis of every batched leaf to `size` with copies of its last element."""

    def one(axis, x):
        if axis is None or x.shape[axis] == size:
            return x
        last = jax.lax.slice_in_dim(x, x.shape[axis] - 1, x.shape[axis], axis=axis)
        reps = [1] * x.ndim
        reps[axis] = size - x.shape[axis]
        return jax.numpy.concatenate([x, jax.numpy.tile(last, reps)], axis=axis)

    return _axes_map(one, axes, tree)


def unpad(tree, n: int, axes=0):
    """The first `n` elements of the batch axis of every batched leaf (drops `pad`'s copies); with
    several processes a collective (the slice moves data between devices)."""
    cut = _axes_map(lambda a, x: a is not None and x.shape[a] != n, axes, tree)
    if any(jax.tree.leaves(cut)):
        _sync(tree)
    return _axes_map(
        lambda a, x: x if a is None or x.shape[a] == n else jax.lax.slice_in_dim(x, 0, n, axis=a), axes, tree
    )


def _spec(axis: int | None) -> P:
    return P() if axis is None else P(*([None] * axis), BATCH)


def _place_leaf(x, sharding: NamedSharding):
    if jax.process_count() == 1:
        return jax.device_put(x, sharding)
    if jax.dtypes.issubdtype(getattr(x, "dtype", None), jax.dtypes.prng_key):
        return jax.random.wrap_key_data(_place_leaf(jax.random.key_data(x), sharding), impl=jax.random.key_impl(x))
    # Each process builds its own parts from its (identical) copy; device_put's cross-process
    # equality check would also reject arrays holding NaN.
    host = np.asarray(x)
    return jax.make_array_from_callback(host.shape, sharding, lambda index: host[index])


def place(tree, mesh: Mesh, axes=0):
    """Put `tree` on the mesh: batched leaves split along their axis, the others replicated. Every
    process passes the whole (same) tree and keeps its own devices' parts."""
    return _axes_map(lambda a, x: _place_leaf(x, NamedSharding(mesh, _spec(a))), axes, tree)


def shard_batched(fn, mesh: Mesh, in_axes, out_axes):
    """`fn` (batched: it takes and returns the whole batch) with its arguments and results split over
    `mesh` along the batch axis; `in_axes` (one entry per argument) and `out_axes` say where that axis
    lies, as vmap's. XLA's partitioner then gives every device its block: a vmapped program has no
    operation across the batch, so the per-device program is the one-device program at 1/n of the
    batch. (`jax.shard_map` would say this by hand, but XLA's GPU compiler crashes on MJX's programs
    under it: jax 0.11.2, 2 H200s.) One device: `fn` itself."""
    if mesh.size == 1:
        return fn

    def constrain(tree, axes):
        return _axes_map(lambda a, x: jax.lax.with_sharding_constraint(x, NamedSharding(mesh, _spec(a))), axes, tree)

    @functools.wraps(fn)
    def batched(*args):
        return constrain(fn(*constrain(args, tuple(in_axes))), out_axes)

    return batched


def _sync(tree) -> None:
    """With several processes: wait for `tree` and then for every process, before a collective.
    CPU collectives (gloo) give up when processes arrive more than 30 s apart, which one process's
    compile or chunk can outlast; the coordination service's barrier waits up to `BARRIER_S`."""
    if jax.process_count() == 1:
        return
    from jax._src import distributed  # the barrier of the coordination service (no public wrapper)

    jax.block_until_ready(tree)
    _state["barriers"] += 1
    distributed.global_state.client.wait_at_barrier(f"jaxquad_{_state['barriers']}", int(BARRIER_S * 1000))


@functools.partial(jax.jit, static_argnums=2)
def _piece(x, start, rows: int):
    return jax.lax.dynamic_slice_in_dim(x, start, rows)


def gather(tree):
    """Every leaf as a NumPy array of its global value. With several processes this is a collective
    (every process calls it) that replicates one piece (leading-axis rows) of at most
    `GATHER_PIECE_BYTES` at a time on every device."""
    if jax.process_count() == 1:
        return jax.device_get(tree)
    from jax.experimental.multihost_utils import process_allgather

    _sync(tree)

    def one(x):
        if not isinstance(x, jax.Array) or x.is_fully_addressable:
            return np.asarray(x)
        rows = max(1, GATHER_PIECE_BYTES * x.shape[0] // max(x.nbytes, 1)) if x.ndim else 0
        if x.ndim == 0 or rows >= x.shape[0]:
            return process_allgather(x, tiled=True)
        parts = []
        for start in range(0, x.shape[0], rows):
            first = min(start, x.shape[0] - rows)  # one piece size, one compilation
            parts.append(process_allgather(_piece(x, first, rows), tiled=True)[start - first :])
        return np.concatenate(parts)

    return jax.tree.map(one, tree)
