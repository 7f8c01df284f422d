"""The online SLAM's pytrees: static structure (`SlamSpec`), tunable numbers (`SlamParams`), one scan's
inputs (`SlamInputs`), the fixed-capacity state (`SlamState`, made by `init`) and one scan's output
(`SlamOutput`). `jaxquad.slam.online` steps them."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from jaxquad.kernels.bias_filter import BiasFilter, bias_filter_init
from jaxquad.kernels.loop_closure import LoopParams, LoopSpec
from jaxquad.kernels.occupancy import GridSpec, OccupancyGrid, OccupancyParams, init_grid
from jaxquad.kernels.posegraph import PoseGraph, SolverParams
from jaxquad.kernels.scan_grid import MatchParams, MatchSpec
from jaxquad.kernels.wall_heading import HeadingParams, HeadingSpec

LO_CONSTRAINTS = ("off", "velocity", "preintegrated")
EDGE_MATCH, EDGE_ODOMETRY, EDGE_LEG, EDGE_LOOP, EDGE_HEADING = 0, 1, 2, 3, 4  # what each edge slot holds


class SlamSpec(eqx.Module):
    """Static structure: capacities, search sizes, the map's geometry and the constraint kind."""

    grid: GridSpec = eqx.field(static=True)
    nodes: int = eqx.field(static=True, default=1024)  # node capacity; 3 edge slots each (4 with wall_heading)
    buffer: int = eqx.field(static=True, default=70)  # running-buffer scans (slam_toolbox's scan_buffer_size)
    match: MatchSpec = eqx.field(static=True, default_factory=MatchSpec)
    loop: LoopSpec = eqx.field(static=True, default_factory=LoopSpec)
    lo_constraints: str = eqx.field(static=True, default="preintegrated")
    refresh_map: bool = eqx.field(static=True, default=True)
    wall_heading: bool = eqx.field(static=True, default=False)  # heading priors from wall directions
    heading: HeadingSpec = eqx.field(static=True, default_factory=HeadingSpec)

    def __check_init__(self):
        if self.lo_constraints not in LO_CONSTRAINTS:
            raise ValueError(f"lo_constraints must be one of {LO_CONSTRAINTS}, got {self.lo_constraints!r}")

    @property
    def edges(self) -> int:
        return (4 if self.wall_heading else 3) * self.nodes


def _f(x) -> Array:
    return jnp.asarray(x, jnp.float32)


class SlamParams(eqx.Module):
    """Tunable numbers (traced leaves; sweeps never recompile). Defaults: the paper's SLAM settings."""

    match: MatchParams = eqx.field(default_factory=MatchParams)
    loop: LoopParams = eqx.field(default_factory=LoopParams)
    occupancy: OccupancyParams = eqx.field(default_factory=OccupancyParams)
    solver: SolverParams = eqx.field(default_factory=lambda: SolverParams(robust_width=jnp.asarray(3.0)))
    robust_links: Bool[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(True))  # Cauchy match links
    robust_loops: Bool[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(False))  # Cauchy loop edges
    T_base_laser: Float[Array, "3"] = eqx.field(default_factory=lambda: jnp.zeros(3))  # x, y (m), theta (rad)
    min_travel: Float[Array, ""] = eqx.field(default_factory=lambda: _f(0.1))  # m
    min_rotation: Float[Array, ""] = eqx.field(default_factory=lambda: _f(0.02))  # rad
    min_interval: Float[Array, ""] = eqx.field(default_factory=lambda: _f(0.5))  # s
    buffer_distance: Float[Array, ""] = eqx.field(default_factory=lambda: _f(20.0))  # m
    link_min_response: Float[Array, ""] = eqx.field(default_factory=lambda: _f(0.1))
    match_cov_scale: Float[Array, ""] = eqx.field(default_factory=lambda: _f(10.0))  # multiplies match covariances
    # a match farther than this chi-square (3 dof) from the odometry's prediction is replaced by the odometry step,
    # whose std is odometry_step_std . (d, d, |dtheta|) for a step of length d (m/m, rad/m, rad/rad), plus 1 mm and
    # 1 mrad; the match's covariance enters times match_cov_scale
    match_odometry_gate: Float[Array, ""] = eqx.field(default_factory=lambda: _f(jnp.inf))
    odometry_step_std: Float[Array, "3"] = eqx.field(default_factory=lambda: _f([0.02, 0.01, 0.02]))
    odom_fallback_std: Float[Array, "3"] = eqx.field(default_factory=lambda: _f([0.05, 0.05, 0.05]))  # m, m, rad
    velocity_cov: Float[Array, "3"] = eqx.field(default_factory=lambda: _f([0.1, 0.1, 0.05]))  # (m/s)^2, (rad/s)^2
    velocity_max_dt: Float[Array, ""] = eqx.field(default_factory=lambda: _f(5.0))  # s
    lo_correlation_s: Float[Array, ""] = eqx.field(default_factory=lambda: _f(0.1))  # s
    loop_max_chi2: Float[Array, ""] = eqx.field(default_factory=lambda: _f(16.27))  # chi-square, 3 dof
    heading: HeadingParams = eqx.field(default_factory=HeadingParams)  # wall directions (SlamSpec.wall_heading)
    heading_variance_scale: Float[Array, ""] = eqx.field(default_factory=lambda: _f(100.0))  # rad^2 x weight
    heading_min_std: Float[Array, ""] = eqx.field(default_factory=lambda: _f(0.0087))  # rad
    heading_min_quality: Float[Array, ""] = eqx.field(default_factory=lambda: _f(0.5))  # correlation quality, 0-1
    heading_max_chi2: Float[Array, ""] = eqx.field(default_factory=lambda: _f(10.83))  # chi-square, 1 dof
    heading_gate_with_r: Bool[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(False))  # R in the gate too
    heading_halves_tolerance: Float[Array, ""] = eqx.field(default_factory=lambda: _f(0.0))  # rad; 0: no test
    # the loop test's chain filtered by the wall-heading priors (jaxquad.slam.consistency)
    loop_chain_priors: Bool[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(True))
    # the loop test's covariance from the whole graph's information in place of the chain (jaxquad.slam.consistency)
    loop_graph_covariance: Bool[Array, ""] = eqx.field(default_factory=lambda: jnp.asarray(False))
    # the leg odometry's velocity bias (jaxquad.slam.leg_bias): prior mean and std per base axis, forward and sideways
    # (m/s; std 0: that axis not estimated, its mean taken out as it is), its random walk (m/s per sqrt(s)) and the
    # chi-square gate (2 dof) of the matches
    lo_bias_mean: Float[Array, "2"] = eqx.field(default_factory=lambda: _f([0.0, 0.0]))
    lo_bias_std: Float[Array, "2"] = eqx.field(default_factory=lambda: _f([0.0, 0.0]))
    lo_bias_walk: Float[Array, ""] = eqx.field(default_factory=lambda: _f(1e-4))
    lo_bias_gate: Float[Array, ""] = eqx.field(default_factory=lambda: _f(9.21))


class SlamInputs(eqx.Module):
    """One scan with its odometry and (optional) leg odometry (leading axes B: robots, scans, when stacked)."""

    t: Float[Array, "*B"]  # s
    odom: Float[Array, "*B 3"]  # odometry pose of the base x, y (m), theta (rad)
    ranges: Float[Array, "*B b"]  # m; +inf: no return; NaN: invalid
    valid: Bool[Array, "*B b"]
    lo_pose: Float[Array, "*B 3"]  # leg-odometry pose of the base (its own frame)
    lo_twist: Float[Array, "*B 3"]  # leg-odometry vx, vy (m/s, base frame), yaw rate (rad/s)
    lo_twist_cov: Float[Array, "*B 3 3"]  # covariance of lo_twist
    lo_valid: Bool[Array, "*B"]  # leg odometry available at this scan


class SlamState(eqx.Module):
    graph: PoseGraph  # node poses (base, map frame) and edges
    n_nodes: Int[Array, ""]
    n_edges: Int[Array, ""]
    edge_kind: Int[Array, " m"]  # EDGE_* per slot
    node_t: Float[Array, " n"]
    node_odom: Float[Array, "n 3"]
    node_lo: Float[Array, "n 3"]
    node_lo_valid: Bool[Array, " n"]
    node_twist: Float[Array, "n 3"]
    node_cov: Float[Array, "n 3 3"]  # covariance of the node's pose in the last node's frame (its links)
    ranges: Float[Array, "n b"]
    valid: Bool[Array, "n b"]
    bearings: Float[Array, " b"]
    lo_cov: Float[Array, "3 3"]  # leg-odometry covariance accumulated since the last node
    lo_prev: Float[Array, "3"]  # leg-odometry pose at the previous scan
    t_prev: Float[Array, ""]
    lo_ok: Bool[Array, ""]  # leg odometry valid at every scan since the last node
    lo_bias_jac: Float[Array, "2 2"]  # s: the leg edge's sensitivity to the velocity bias since the last node
    lo_bias: BiasFilter  # position and leg-odometry velocity bias (jaxquad.slam.leg_bias)
    grid: OccupancyGrid
    map_stale: Bool[Array, ""]  # poses moved since the map was drawn
    loops: Int[Array, ""]  # accepted loop closures
    full: Bool[Array, ""]  # node capacity reached: later scans add no node
    node_directions: Float[Array, "n_h k 2"]  # each node scan's wall-direction spectrum in its base frame
    # (kernels.wall_heading; n_h = n with SlamSpec.wall_heading, else 0)
    node_heading_var: Float[Array, " n_h"]  # rad^2: variance of the node's heading in the map frame (heading filter)
    node_heading_info: Float[Array, " n_h"]  # 1/rad^2: information of the node's wall-heading prior (0: none used)

    @property
    def headings(self) -> Int[Array, "*batch"]:
        """Accepted wall-heading priors: the nodes holding one (per robot of a batched state)."""
        return jnp.sum(self.node_heading_info > 0, axis=-1)


class SlamOutput(eqx.Module):
    pose: Float[Array, "3"]  # base pose in the map frame as estimated at this scan
    node: Int[Array, ""]  # the node this scan hangs from (-1 before the first node)
    T_node_scan: Float[Array, "3"]  # the scan's base pose in that node's frame (odometry)
    added: Bool[Array, ""]  # this scan became a node
    response: Float[Array, ""]  # scan-match response of a new node (NaN otherwise)
    loop_closed: Bool[Array, ""]
    loop_node: Int[Array, ""]  # the old node of an accepted closure (-1 otherwise)
    loop_chi2: Float[Array, ""]  # consistency chi-square of a candidate that passed the match tests (NaN otherwise)
    heading_error: Float[Array, ""]  # rad: a new node's heading error from the walls, when used (NaN otherwise)


def init(spec: SlamSpec, params: SlamParams, bearings: Float[Array, " b"]) -> SlamState:
    n, m, b = spec.nodes, spec.edges, bearings.shape[0]
    graph = PoseGraph(
        poses=jnp.zeros((n, 3)),
        node_mask=jnp.zeros(n, bool),
        fixed=jnp.arange(n) == 0,
        edge_i=jnp.zeros(m, jnp.int32),
        edge_j=jnp.zeros(m, jnp.int32),
        measurement=jnp.zeros((m, 3)),
        information=jnp.zeros((m, 3, 3)),
        edge_mask=jnp.zeros(m, bool),
        robust=jnp.zeros(m, jnp.int32),
    )
    zero_i, zero_f = jnp.asarray(0, jnp.int32), jnp.asarray(0.0)
    return SlamState(
        graph=graph,
        n_nodes=zero_i,
        n_edges=zero_i,
        edge_kind=jnp.zeros(m, jnp.int32),
        node_t=jnp.zeros(n),
        node_odom=jnp.zeros((n, 3)),
        node_lo=jnp.zeros((n, 3)),
        node_lo_valid=jnp.zeros(n, bool),
        node_twist=jnp.zeros((n, 3)),
        node_cov=jnp.zeros((n, 3, 3)),
        ranges=jnp.full((n, b), jnp.nan),
        valid=jnp.zeros((n, b), bool),
        bearings=_f(bearings),
        lo_cov=jnp.zeros((3, 3)),
        lo_prev=jnp.zeros(3),
        t_prev=zero_f,
        lo_ok=jnp.asarray(False),
        lo_bias_jac=jnp.zeros((2, 2)),
        lo_bias=bias_filter_init(jnp.zeros(2), params.lo_bias_mean, params.lo_bias_std),
        grid=init_grid(spec.grid),
        map_stale=jnp.asarray(False),
        loops=zero_i,
        full=jnp.asarray(False),
        node_directions=jnp.zeros((n if spec.wall_heading else 0, spec.heading.harmonics, 2)),
        node_heading_var=jnp.zeros(n if spec.wall_heading else 0),
        node_heading_info=jnp.zeros(n if spec.wall_heading else 0),
    )
