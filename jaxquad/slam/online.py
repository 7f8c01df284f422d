"""Online 2D graph SLAM with leg-odometry constraints (Karto / slam_toolbox style), one robot per call.

    state = init(spec, params, bearings)                 # jaxquad.slam.state: the pytrees and init
    state, out = step(spec, params, state, inputs)      # once per scan, in time order
    state = finish(spec, params, state)                  # last optimization and map

Everything lives in fixed-capacity arrays (`SlamSpec.nodes` node slots, 3 edge slots per node, 4 with wall-heading
priors), so `step` jits once, runs inside `lax.scan` and `vmap`s over a fleet. Nodes hold base poses (x, y, theta)
in the map frame, which is the odometry frame at the first scan.

Per scan (`SlamInputs`): the odometry pose predicts the base pose from the last node. A node is
added on the first scan of each `min_interval`-long slot of the clock (t // min_interval changes)
when the robot has moved `min_travel` m or turned `min_rotation` rad since the last node (the first
usable scan is always a node): slam_toolbox's time and travel thresholds, with the time one on a
shared clock so that the robots of a fleet add their nodes on the same scans (see
`kernels.control_flow.run_if`). A new node's scan is matched (`kernels.scan_match`, the exact
multi-resolution correlative search) against the running buffer: the last `SlamSpec.buffer` nodes
within `buffer_distance` m, smeared into one likelihood grid. The match gives an edge from the last
node (its covariance rotated into the node's frame); a response under `link_min_response` gives the
odometry step instead, with `odom_fallback_std`, and so does a match whose pose lies farther from the odometry's
prediction than `match_odometry_gate` (a chi-square, with a motion model of the step, `odometry_step_std`, plus the
match's covariance times `match_cov_scale`; off by default): a scan matched 9 deg off, where the wheels turned by
less than a degree, would otherwise carry its turn into every later pose until a loop closes.

Leg-odometry constraints (`SlamSpec.lo_constraints`), one more edge from the last node:
  off            none: the node is where the scan matched (Karto's behaviour).
  velocity       the authors' form: the earlier node's leg-odometry twist (vx, vy, omega) times the
                 time between the nodes (< `velocity_max_dt` s), information inv(diag(velocity_cov))
                 not scaled by time. As a g2o edge its error is the authors' residual with the
                 translation rotated into node i's frame: the same cost with an isotropic x-y covariance.
  preintegrated  ours: the leg-odometry pose change between the two node stamps, with the covariance
                 propagated from the twist covariance at each scan: Sigma <- Ad(D^-1) Sigma Ad(D^-1)^T +
                 Q dt correlation, D the scan-to-scan change, Q the (vx, vy, omega) covariance, the twist
                 error taken as white noise with `lo_correlation_s` of correlation time.
Match covariances (the response spread, Karto's way) are multiplied by `match_cov_scale`: on simulated
depth-camera scans (noise 1 % of z^2) the match-only chain erred 12.5 cm / 1.6 deg rms per node where the
spread claimed 3 cm / 1 deg. The scale weighs matches against leg odometry only: without leg-odometry
edges every edge scales alike and the optimum is unchanged.
With a constraint the new node's pose is the optimum of the match edge (Cauchy-robust, width
`solver.robust_width` in chi-square units) and the leg-odometry edge, the last node held: a scan
that matches far from where the legs say the robot went is overruled instead of yanking the path.

Then the loop-closure search (`kernels.loop_closure`) runs for the new node. A candidate that passes its response
and ambiguity tests must also agree with the graph: its innovation (the measured pose of node j in node i's frame
against the graph's) has a chi-square, with the covariance of the graph's chain from i to j (each node's link and
leg-odometry information, compounded, and filtered by the wall-heading priors when there are any:
`jaxquad.slam.consistency`) plus the match's, of at most `loop_max_chi2`. A narrow depth-camera scan (~87 deg) that
sees one wall or a room like another can match confidently metres away from where the robot is; without the test
that one edge, weighted by its response spread, drags the whole graph. An accepted closure adds its edge and the
whole graph is optimized (`kernels.posegraph`, node 0 fixed). Match links are Cauchy-robust and loop edges plain by
default (`robust_links`, `robust_loops`; laser logs swap them: there the links are the only chain). The occupancy
map takes every node's scan at its node's pose; after an optimization it is redrawn from all nodes
(`SlamSpec.refresh_map`; a fleet may clear that and call `refresh_map` itself).

With `SlamSpec.wall_heading` a new node's heading is also measured against the map's wall directions before
its scan enters the map, and a heading-only edge from node 0 keeps the measurement (`jaxquad.slam.heading`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxquad.kernels.control_flow import run_if
from jaxquad.kernels.lie import se2, xy_theta
from jaxquad.kernels.loop_closure import find_loop_closure
from jaxquad.kernels.posegraph import ROBUST_CAUCHY, ROBUST_NONE, PoseGraph, optimize
from jaxquad.kernels.scan_grid import likelihood_grid, world_points
from jaxquad.kernels.scan_match import match_scan
from jaxquad.slam import heading as wall_heading
from jaxquad.slam import leg_bias
from jaxquad.slam.consistency import loop_chi2
from jaxquad.slam.mapping import _compose, _insert, _sensor, refresh_map
from jaxquad.slam.state import (
    EDGE_HEADING,
    EDGE_LEG,
    EDGE_LOOP,
    EDGE_MATCH,
    EDGE_ODOMETRY,
    SlamInputs,
    SlamOutput,
    SlamParams,
    SlamSpec,
    SlamState,
)


def _base(params: SlamParams, sensor: Float[Array, "3"]) -> Float[Array, "3"]:
    return xy_theta(se2(sensor) @ se2(params.T_base_laser).inverse())


# Std floor of an odometry step (m, m, rad) in the match's odometry test: a robot standing still reads some noise.
ODOMETRY_STEP_FLOOR = 1e-3


def _between(a: Float[Array, "3"], b: Float[Array, "3"]) -> Float[Array, "3"]:
    return xy_theta(se2(a).inverse() @ se2(b))


def _rotate_cov(theta: Float[Array, ""], cov_world: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    """A (x, y world, theta) covariance as the right perturbation of a pose with heading theta."""
    c, s = jnp.cos(theta), jnp.sin(theta)
    R = jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return R.T @ cov_world @ R


def _to_base_cov(params: SlamParams, cov_sensor: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    """Right-perturbation covariance of a sensor pose -> of its base pose (T_base = T_sensor L^-1)."""
    A = se2(params.T_base_laser).adjoint()
    return A @ cov_sensor @ A.T


def _information(cov: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    cov = 0.5 * (cov + cov.T) + 1e-9 * jnp.eye(3)
    return jnp.linalg.inv(cov)


def _add_edge(state: SlamState, i, j, z, info, robust, kind, keep) -> SlamState:
    k = state.n_edges
    g = state.graph
    g = eqx.tree_at(
        lambda g: (g.edge_i, g.edge_j, g.measurement, g.information, g.edge_mask, g.robust),
        g,
        (
            g.edge_i.at[k].set(jnp.where(keep, i, g.edge_i[k])),
            g.edge_j.at[k].set(jnp.where(keep, j, g.edge_j[k])),
            g.measurement.at[k].set(jnp.where(keep, z, g.measurement[k])),
            g.information.at[k].set(jnp.where(keep, info, g.information[k])),
            g.edge_mask.at[k].set(keep | g.edge_mask[k]),
            g.robust.at[k].set(jnp.where(keep, robust, g.robust[k])),
        ),
    )
    kinds = state.edge_kind.at[k].set(jnp.where(keep, kind, state.edge_kind[k]))
    return eqx.tree_at(lambda s: (s.graph, s.n_edges, s.edge_kind), state, (g, k + keep.astype(jnp.int32), kinds))


def _match_buffer(spec: SlamSpec, params: SlamParams, state: SlamState, pred: Float[Array, "3"], inp: SlamInputs):
    """Correlative match of the scan against the running buffer around the predicted base pose."""
    K = min(spec.buffer, spec.nodes)
    idx = state.n_nodes - 1 - jnp.arange(K)
    ok = idx >= 0
    idx = jnp.clip(idx, 0)
    near = jnp.linalg.norm(state.graph.poses[idx, :2] - pred[:2], axis=-1) <= params.buffer_distance
    use = ok & near & state.graph.node_mask[idx]
    sensor = _sensor(params, state.graph.poses[idx])
    pts, mask = world_points(params.match, sensor, state.ranges[idx], state.bearings, state.valid[idx] & use[:, None])
    prior = _sensor(params, pred)
    grid = likelihood_grid(spec.match, params.match, prior[:2], pts, mask)
    res = match_scan(spec.match, params.match, grid, prior, inp.ranges, state.bearings, inp.valid)
    good = jnp.any(mask) & (res.response >= params.link_min_response) & jnp.all(jnp.isfinite(res.pose))
    cov = _to_base_cov(params, _rotate_cov(res.pose[2], res.covariance)) * params.match_cov_scale
    return _base(params, res.pose), cov, res.response, good


def _fuse(params: SlamParams, x_i, z_match, info_match, z_leg, info_leg) -> Float[Array, "3"]:
    """The new node's pose from its match edge (Cauchy) and leg-odometry edge, node i held."""
    z = jnp.stack([z_match, z_leg])
    g = PoseGraph(
        poses=jnp.stack([x_i, _compose(x_i, z_match)]),
        node_mask=jnp.ones(2, bool),
        fixed=jnp.array([True, False]),
        edge_i=jnp.zeros(2, jnp.int32),
        edge_j=jnp.ones(2, jnp.int32),
        measurement=z,
        information=jnp.stack([info_match, info_leg]),
        edge_mask=jnp.ones(2, bool),
        robust=jnp.array([ROBUST_CAUCHY, ROBUST_NONE], jnp.int32),
    )
    out, _ = optimize(g, params.solver)
    return out.poses[1]


def _leg_edge(spec: SlamSpec, params: SlamParams, state: SlamState, last, inp: SlamInputs):
    """(measurement, information, usable) of the leg-odometry edge from node `last` to the new node."""
    if spec.lo_constraints == "velocity":
        dt = inp.t - state.node_t[last]
        z = state.node_twist[last] * dt
        ok = state.node_lo_valid[last] & (dt > 0) & (dt < params.velocity_max_dt)
        return z, jnp.diag(1.0 / params.velocity_cov), ok & jnp.all(jnp.isfinite(z))
    z, cov = leg_bias.correct_edge(state, _between(state.node_lo[last], inp.lo_pose), state.lo_cov)
    ok = state.node_lo_valid[last] & state.lo_ok & inp.lo_valid & jnp.all(jnp.isfinite(z))
    return z, _information(cov), ok & jnp.all(jnp.isfinite(cov))


def _match_odometry_chi2(params: SlamParams, pred, T_step, matched, cov_match) -> Float[Array, ""]:
    """Chi-square (3 dof) of the matched pose in the frame of the odometry's prediction `pred`: the odometry step
    `T_step` since the last node has the std `odometry_step_std` . (d, d, |dtheta|), d its length, plus
    `ODOMETRY_STEP_FLOOR`; the match adds its covariance as `_match_buffer` gives it (times `match_cov_scale`, in
    the matched pose's frame, which differs from the prediction's by the residual's heading)."""
    a, b, c = params.odometry_step_std
    d = jnp.hypot(T_step[0], T_step[1])
    std = jnp.stack([a * d, a * d, b * d + c * jnp.abs(T_step[2])]) + ODOMETRY_STEP_FLOOR
    r = _between(pred, matched)
    S = jnp.diag(std**2) + cov_match
    return r @ jnp.linalg.solve(0.5 * (S + S.T), r)


def _add_node(spec: SlamSpec, params: SlamParams, state: SlamState, pred, T_step, inp: SlamInputs):
    j, last = state.n_nodes, jnp.maximum(state.n_nodes - 1, 0)
    first = j == 0
    matched, cov_match, response, good = _match_buffer(spec, params, state, pred, inp)
    x_last = state.graph.poses[last]
    # (a first node has no buffer to match, so `good` is already False there; a NaN chi-square refuses nothing)
    good = good & ~(_match_odometry_chi2(params, pred, T_step, matched, cov_match) > params.match_odometry_gate)
    fallback = _information(jnp.diag(params.odom_fallback_std**2))
    z_link = jnp.where(good, _between(x_last, matched), _between(x_last, pred))
    info_link = jnp.where(good, _information(cov_match), fallback)
    pose = jnp.where(good, matched, pred)
    info_step = info_link  # the node's links as one information, for the loop-closure test
    if spec.lo_constraints != "off":
        z_leg, info_leg, leg_ok = _leg_edge(spec, params, state, last, inp)
        leg_ok = leg_ok & ~first
        fused = _fuse(params, x_last, z_link, info_link, jnp.where(leg_ok, z_leg, 0.0), info_leg)
        pose = jnp.where(leg_ok, fused, pose)
        info_step = info_step + jnp.where(leg_ok, info_leg, 0.0)
    pose = jnp.where(first, pred, pose)
    if spec.lo_constraints == "preintegrated":
        dt = inp.t - state.node_t[last]
        bias = leg_bias.node_update(params, state, x_last, pose, z_leg, leg_ok, matched, cov_match, good, dt, first)
        state = eqx.tree_at(lambda s: (s.lo_bias, s.lo_bias_jac), state, (bias, jnp.zeros((2, 2))))
    cov_step = jnp.where(first, 0.0, jnp.linalg.inv(info_step))
    heading_error = jnp.asarray(jnp.nan)
    if spec.wall_heading:
        pose, var, local, measured, info_h, h_used, heading_error = wall_heading.update(
            spec, params, state, pose, cov_step[2, 2], inp, first
        )
        z_h = _between(state.graph.poses[0], measured)  # the prior's information is on its heading alone
        state = eqx.tree_at(
            lambda s: (s.node_heading_var, s.node_heading_info, s.node_directions),
            state,
            (
                state.node_heading_var.at[j].set(var),
                state.node_heading_info.at[j].set(jnp.where(h_used, info_h[2, 2], 0.0)),
                state.node_directions.at[j].set(local),
            ),
        )

    g = state.graph
    g = eqx.tree_at(lambda g: (g.poses, g.node_mask), g, (g.poses.at[j].set(pose), g.node_mask.at[j].set(True)))
    state = eqx.tree_at(
        lambda s: (
            s.graph,
            s.n_nodes,
            s.node_t,
            s.node_odom,
            s.node_lo,
            s.node_lo_valid,
            s.node_twist,
            s.node_cov,
            s.ranges,
            s.valid,
            s.lo_cov,
            s.lo_ok,
        ),
        state,
        (
            g,
            j + 1,
            state.node_t.at[j].set(inp.t),
            state.node_odom.at[j].set(inp.odom),
            state.node_lo.at[j].set(inp.lo_pose),
            state.node_lo_valid.at[j].set(inp.lo_valid),
            state.node_twist.at[j].set(inp.lo_twist),
            state.node_cov.at[j].set(cov_step),
            state.ranges.at[j].set(inp.ranges),
            state.valid.at[j].set(inp.valid),
            jnp.zeros((3, 3)),
            inp.lo_valid,
        ),
    )
    link_kind = jnp.where(good, EDGE_MATCH, EDGE_ODOMETRY)
    link_robust = jnp.where(good & params.robust_links, ROBUST_CAUCHY, ROBUST_NONE)
    state = _add_edge(state, last, j, z_link, info_link, link_robust, link_kind, ~first)
    if spec.lo_constraints != "off":
        state = _add_edge(state, last, j, z_leg, info_leg, ROBUST_NONE, EDGE_LEG, leg_ok)
    if spec.wall_heading:
        state = _add_edge(state, jnp.zeros_like(j), j, z_h, info_h, ROBUST_NONE, EDGE_HEADING, h_used)
    grid = _insert(spec, params, state.grid, pose, inp.ranges, inp.valid, state.bearings)
    state = eqx.tree_at(lambda s: s.grid, state, grid)
    return *_close_loop(spec, params, state, j, jnp.where(first, jnp.nan, response)), heading_error


def _close_loop(spec: SlamSpec, params: SlamParams, state: SlamState, j, response):
    g = state.graph
    cand = find_loop_closure(
        spec.loop, params.loop, _sensor(params, g.poses), state.ranges, state.valid, state.bearings, g.node_mask, j
    )
    L = se2(params.T_base_laser)
    z = xy_theta(L @ se2(cand.T_i_j) @ L.inverse())
    cov_z = _to_base_cov(params, cand.covariance) * params.match_cov_scale
    chi2 = loop_chi2(spec, params, state, cand.i, j, z, cov_z, cand.accept)
    accept = cand.accept & (chi2 <= params.loop_max_chi2)
    robust = jnp.where(params.robust_loops, ROBUST_CAUCHY, ROBUST_NONE)
    state = _add_edge(state, cand.i, j, z, _information(cov_z), robust, EDGE_LOOP, accept)
    # Robots without a closure run no solver iteration (the loop's trip count is 0), also under vmap.
    trips = jnp.where(accept, params.solver.max_iterations, 0)
    solver = eqx.tree_at(lambda s: s.max_iterations, params.solver, trips)
    graph, _ = optimize(state.graph, solver)
    state = eqx.tree_at(
        lambda s: (s.graph, s.loops, s.map_stale),
        state,
        (graph, state.loops + accept.astype(state.loops.dtype), state.map_stale | accept),
    )
    if spec.lo_constraints == "preintegrated":
        state = leg_bias.reanchor(state, j, accept)
    return state, response, accept, jnp.where(accept, cand.i, -1), jnp.where(cand.accept, chi2, jnp.nan)


def _accumulate_lo(params: SlamParams, state: SlamState, inp: SlamInputs) -> SlamState:
    """Propagate the leg-odometry covariance since the last node over this scan's interval."""
    d = _between(state.lo_prev, inp.lo_pose)
    A = se2(d).inverse().adjoint()
    dt = jnp.clip(inp.t - state.t_prev, 0.0)
    cov = A @ state.lo_cov @ A.T + inp.lo_twist_cov * (params.lo_correlation_s * dt)
    ok = state.lo_ok & inp.lo_valid & jnp.all(jnp.isfinite(d)) & jnp.all(jnp.isfinite(inp.lo_twist_cov))
    H = leg_bias.accumulate(state, inp, dt, ok)
    return eqx.tree_at(lambda s: (s.lo_cov, s.lo_ok, s.lo_bias_jac), state, (jnp.where(ok, cov, state.lo_cov), ok, H))


def _usable(inp: SlamInputs) -> Bool[Array, ""]:
    return jnp.all(jnp.isfinite(inp.odom)) & jnp.any(inp.valid & ~jnp.isnan(inp.ranges)) & jnp.isfinite(inp.t)


def _node_wanted(params: SlamParams, T_node_scan, t, t_prev, first) -> tuple[Bool[Array, ""], Bool[Array, ""]]:
    """(moved, wanted): the travel test, and whether a usable scan becomes a node (see the module docstring)."""
    moved = (jnp.linalg.norm(T_node_scan[:2]) >= params.min_travel) | (jnp.abs(T_node_scan[2]) >= params.min_rotation)
    interval = jnp.maximum(params.min_interval, 1e-9)
    new_slot = (params.min_interval <= 0) | (jnp.floor(t / interval) > jnp.floor(t_prev / interval))
    return moved, first | (moved & new_slot)


def count_nodes(params: SlamParams, inputs: SlamInputs) -> Int[Array, ""]:
    """How many nodes one robot's scans (leading axis S) add with unbounded capacity: the node rule
    alone, on the odometry and the clock (a laser log's node capacity is sized from it)."""

    def body(carry, inp):
        n, odom_last, t_prev = carry
        _, wanted = _node_wanted(params, _between(odom_last, inp.odom), inp.t, t_prev, n == 0)
        due = _usable(inp) & wanted
        return (n + due.astype(jnp.int32), jnp.where(due, inp.odom, odom_last), inp.t), None

    (n, _, _), _ = jax.lax.scan(body, (jnp.asarray(0, jnp.int32), jnp.zeros(3), jnp.asarray(0.0)), inputs)
    return n


def step(spec: SlamSpec, params: SlamParams, state: SlamState, inp: SlamInputs) -> tuple[SlamState, SlamOutput]:
    """One scan: maybe a new node (match, leg-odometry edge, loop closure, optimization), the map."""
    last = jnp.maximum(state.n_nodes - 1, 0)
    first = state.n_nodes == 0
    T_node_scan = _between(state.node_odom[last], inp.odom)
    pred = jnp.where(first, inp.odom, _compose(state.graph.poses[last], T_node_scan))
    if spec.lo_constraints == "preintegrated":
        state = _accumulate_lo(params, state, inp)

    moved, wanted = _node_wanted(params, T_node_scan, inp.t, state.t_prev, first)
    usable = _usable(inp)
    full = state.n_nodes >= spec.nodes
    due = usable & ~full & wanted

    nan = jnp.asarray(jnp.nan)
    none = (state, nan, jnp.asarray(False), jnp.asarray(-1, jnp.int32), nan, nan)
    add = lambda c: _add_node(spec, params, c[0], pred, T_node_scan, inp)  # noqa: E731
    state, response, closed, loop_node, loop_chi2, heading_error = run_if(due, add, none)
    if spec.refresh_map:
        state = refresh_map(spec, params, state)
    new = state.n_nodes - 1
    state = eqx.tree_at(
        lambda s: (s.lo_prev, s.t_prev, s.full),
        state,
        (jnp.where(inp.lo_valid, inp.lo_pose, state.lo_prev), inp.t, state.full | (usable & full & (first | moved))),
    )
    out = SlamOutput(
        pose=jnp.where(due, state.graph.poses[jnp.maximum(new, 0)], pred),
        node=new,
        T_node_scan=jnp.where(due, jnp.zeros(3), T_node_scan),
        added=due,
        response=response,
        loop_closed=closed,
        loop_node=loop_node,
        loop_chi2=loop_chi2,
        heading_error=heading_error,
    )
    return state, out


def finish(spec: SlamSpec, params: SlamParams, state: SlamState) -> SlamState:
    """The final optimization of the whole graph and the map drawn at the optimized poses."""
    graph, _ = optimize(state.graph, params.solver)
    state = eqx.tree_at(lambda s: (s.graph, s.map_stale), state, (graph, jnp.asarray(True)))
    return refresh_map(spec, params, state)
