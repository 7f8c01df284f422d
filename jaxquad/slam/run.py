"""Online SLAM over recorded inputs, for one robot or a fleet: the library calls behind `jaxquad slam`.

Inputs are a dict of arrays at the scans (leading robot axis N), as `jaxquad.estimate.laser.laser_inputs`
gives for a robot log and `laser_log_inputs` for a 2D laser log: t (S,) s, odom (N, S, 3), ranges
(N, S, B) m, bearings (B,) rad, T_base_laser (3,), valid (N, S), lo_twist (N, S, 3), lo_twist_cov
(N, S, 3, 3), lo_valid (N, S), and optionally gt (N, S, 3). The scans run through `online.step` in
chunks of one jitted `lax.scan`, `vmap`ped over the robots, which are split over the devices
(`jaxquad.parallel`; in a multi-process run every process passes the same inputs and gets every robot's
results).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxquad import parallel
from jaxquad.io.carmen import LaserLog, repeated_stamps, scan_clock, untie_stamps
from jaxquad.kernels.occupancy import GridSpec
from jaxquad.slam import online
from jaxquad.slam import state as slam_state
from jaxquad.slam.mapping import grid_spec, scan_map, scan_poses

# Scans per jitted call: long enough to amortize dispatch, short enough for a live progress bar.
CHUNK = 64


def laser_log_inputs(log: LaserLog) -> dict:
    """The SLAM inputs of a 2D laser log (one robot, no leg odometry): the odometry pose of each scan
    is the one recorded with it, else the odometry interpolated at the scan's stamp. `t` is the SLAM's
    clock (`scan_clock`), `stamp` each scan's own stamp, repeated ones spread (`untie_stamps`; for the
    trajectories written)."""
    if log.scan_odom_xytheta is not None:
        odom = log.scan_odom_xytheta
    else:
        yaw = np.unwrap(log.odom_xytheta[:, 2])
        odom = np.stack([np.interp(log.scan_t, log.odom_t, c) for c in (*log.odom_xytheta[:, :2].T, yaw)], -1)
    S = log.n_scans
    x = {
        "t": scan_clock(log.scan_t),
        "stamp": untie_stamps(log.scan_t),
        "stamps_repeated": repeated_stamps(log.scan_t),
        "odom": odom[None],
        "ranges": log.ranges[None],
        "bearings": log.bearings,
        "T_base_laser": log.T_base_laser_xytheta,
        "valid": np.ones((1, S), bool),
        "lo_twist": np.zeros((1, S, 3)),
        "lo_twist_cov": np.zeros((1, S, 3, 3)),
        "lo_valid": np.zeros((1, S), bool),
    }
    if log.gt_xytheta is not None:
        x["gt"] = log.gt_xytheta[None]
    return x


def map_grid(x: dict, resolution: float, max_range: float, margin: float = 2.0) -> GridSpec:
    """A grid covering every robot's odometry plus the laser range and `margin` m on each side
    (the map's extent is fixed before the run; drift beyond it loses only the map's edge)."""
    xy = x["odom"][..., :2].reshape(-1, 2)
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if xy.size == 0:
        raise ValueError("the input has no finite odometry pose")
    lo, hi = xy.min(0) - max_range - margin, xy.max(0) + max_range + margin
    return grid_spec((float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])), float(resolution), float(max_range))


def _inputs(x: dict, start: int, stop: int, size: int, t0: float) -> online.SlamInputs:
    """Scans start..stop of every robot, padded to `size` with scans that add nothing (NaN stamps);
    times in seconds since `t0` (`_clock_origin`)."""
    pad = size - (stop - start)

    def take(a, fill, robot_axis=True):
        a = a[:, start:stop] if robot_axis else a[start:stop]
        width = [(0, 0)] * a.ndim
        width[1 if robot_axis else 0] = (0, pad)
        return np.pad(a, width, constant_values=fill)

    n = x["odom"].shape[0]
    t = np.broadcast_to(take(np.asarray(x["t"], np.float64) - t0, np.nan, False), (n, size))
    valid = take(x["valid"], False)
    r = take(x["ranges"], np.nan)
    ok = valid[..., None] & ~np.isnan(r)
    f = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    return online.SlamInputs(
        t=f(t),
        odom=f(take(x["odom"], np.nan)),
        ranges=f(np.where(ok, r, np.nan)),
        valid=jnp.asarray(ok),
        lo_pose=f(take(x["odom"] if "lo_pose" not in x else x["lo_pose"], np.nan)),
        lo_twist=f(take(x["lo_twist"], 0.0)),
        lo_twist_cov=f(take(x["lo_twist_cov"], 0.0)),
        lo_valid=jnp.asarray(take(x["lo_valid"], False) & valid),
    )


def nodes_needed(params: online.SlamParams, x: dict) -> int:
    """The most nodes any robot's scans add (`online.count_nodes`): the node capacity that never fills.
    Each scan goes in as one beam (valid where any of its beams is), which is all the node rule reads."""
    S = x["odom"].shape[1]
    seen = np.any(x["valid"][..., None] & ~np.isnan(x["ranges"]), axis=-1, keepdims=True)  # (N, S, 1)
    one_beam = {**x, "ranges": np.where(seen, 1.0, np.nan)}
    inputs = _inputs(one_beam, 0, S, S, _clock_origin(np.asarray(x["t"], np.float64)))
    return int(np.max(jax.jit(jax.vmap(online.count_nodes, in_axes=(None, 0)))(params, inputs)))


def _clock_origin(t: np.ndarray) -> float:
    """Whole thousands of seconds (below the median stamp: a stray stamp does not move it) taken off the
    stamps before they go to float32, where a log's Unix stamps (~1.7e9 s) would round to 128 s. Whole
    thousands keep the node clock's slots where they were for intervals that divide 1000 s (the default
    0.5 s), and take nothing off a simulated log's stamps (under 1000 s)."""
    return float(1000.0 * np.floor(np.nanmedian(t) / 1000.0)) if np.any(np.isfinite(t)) else 0.0


@functools.cache
def _compiled(spec: online.SlamSpec, mesh):
    """The jitted fleet functions of one spec on one device mesh (cached: compiled once per process)."""

    def one(params, state, inputs):
        return jax.lax.scan(lambda s, i: online.step(spec, params, s, i), state, inputs)

    def init(params, bearings, n: int):
        fn = lambda params, bearings: jax.vmap(lambda _: slam_state.init(spec, params, bearings))(jnp.arange(n))  # noqa: E731
        return parallel.shard_batched(fn, mesh, (None, None), 0)(params, bearings)

    chunk = parallel.shard_batched(jax.vmap(one, in_axes=(None, 0, 0)), mesh, (None, 0, 0), 0)
    finish = jax.vmap(lambda params, s: online.finish(spec, params, s), in_axes=(None, 0))
    finish = parallel.shard_batched(finish, mesh, (None, 0), 0)
    return jax.jit(init, static_argnums=2), jax.jit(chunk), jax.jit(finish)


def run_fleet(spec: online.SlamSpec, params: online.SlamParams, x: dict, progress=None, devices: int | None = None):
    """Online SLAM of every robot over all scans, then `finish`. Returns (final states, per-scan
    outputs (N, S, ...), the states before `finish`) as NumPy pytrees. progress(done, total) per chunk.
    The robots are split over `devices` devices (default all), padded to a multiple of them with
    copies of the last robot."""
    n, S = x["odom"].shape[:2]
    mesh = parallel.mesh(devices)
    n_batch = parallel.padded_size(n, mesh)
    init, chunk, finish = _compiled(spec, mesh)
    params = parallel.place(params, mesh, None)
    states = init(params, parallel.place(jnp.asarray(x["bearings"], jnp.float32), mesh, None), n_batch)
    t0 = _clock_origin(np.asarray(x["t"], np.float64))
    outs = []
    for start in range(0, S, CHUNK):
        stop = min(start + CHUNK, S)
        inputs = parallel.place(parallel.pad(_inputs(x, start, stop, CHUNK, t0), n_batch), mesh)
        states, out = chunk(params, states, inputs)
        outs.append(jax.tree.map(lambda a, k=stop - start: a[:n, :k], parallel.gather(out)))
        if progress is not None:
            progress(stop, S)
    online_states = parallel.gather(states)
    final = parallel.gather(finish(params, states))
    first = lambda tree: jax.tree.map(lambda a: np.asarray(a)[:n], tree)  # noqa: E731
    out = jax.tree.map(lambda *a: np.concatenate(a, 1), *outs)
    return first(final), out, first(online_states)


_scan_poses = jax.jit(jax.vmap(scan_poses))


@functools.cache
def _scan_maps(spec: online.SlamSpec):
    """The jitted fleet `mapping.scan_map`, returning only the grids (the rest of the state is the caller's)."""
    grid = lambda params, state, out, ranges: scan_map(spec, params, state, out, ranges).grid  # noqa: E731
    return jax.jit(jax.vmap(grid, in_axes=(None, 0, 0, 0)))


def redraw_maps(spec: online.SlamSpec, params: online.SlamParams, state, out, x: dict, robots_per_call: int = 64):
    """The final states (from `run_fleet`) with each robot's map drawn from every scan of `x` at its final pose
    (`mapping.scan_map`), instead of from the node scans alone; `robots_per_call` robots' grids at a time."""
    ranges = np.where(np.asarray(x["valid"], bool)[..., None], x["ranges"], np.nan).astype(np.float32)
    n = ranges.shape[0]
    fn = _scan_maps(spec)
    parts = []
    for a in range(0, n, robots_per_call):
        part = lambda tree, a=a: jax.tree.map(lambda v: jnp.asarray(v[a : a + robots_per_call]), tree)  # noqa: E731
        grid = fn(params, part(state), part(out), jnp.asarray(ranges[a : a + robots_per_call]))
        parts.append(jax.tree.map(np.asarray, grid))
    grid = jax.tree.map(lambda *g: np.concatenate(g), *parts)
    return eqx.tree_at(lambda s: s.grid, state, grid)


def final_poses(state, out) -> np.ndarray:
    """Every scan's pose at the final node poses (N, S, 3); NaN before a robot's first node."""
    return np.asarray(_scan_poses(jax.tree.map(jnp.asarray, state), jax.tree.map(jnp.asarray, out)))
