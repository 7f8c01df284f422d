"""SLAM parameters from a YAML file: the package's documented defaults (`slam.yaml`) overridden by the
user's file, every value checked (a known key, a finite number in range) with one-line errors naming
the file and key; `slam_config` turns them into the online SLAM's static spec and traced params."""

from __future__ import annotations

import math
import os
from pathlib import Path

import jax.numpy as jnp

from jaxquad.kernels.loop_closure import LoopParams, LoopSpec
from jaxquad.kernels.occupancy import GridSpec, OccupancyParams
from jaxquad.kernels.posegraph import SolverParams
from jaxquad.kernels.scan_grid import MatchParams, MatchSpec, cells_for_range
from jaxquad.kernels.wall_heading import HeadingParams
from jaxquad.slam.state import SlamParams, SlamSpec

DEFAULTS_FILE = Path(__file__).with_name("slam.yaml")
LASER_FILE = Path(__file__).with_name("laser.yaml")  # overrides of slam.yaml for 2D laser logs
_SWITCHES = (  # 0 or 1
    "robust_match_links",
    "robust_loop_edges",
    "wall_heading",
    "wall_heading_gate_with_r",
    "wall_heading_in_loop_test",
    "loop_consistency_graph",
)
_INTEGER = (
    "scan_buffer_size",
    "loop_match_minimum_chain_size",
    "loop_chain_scans",
    "node_capacity",
    "solver_max_iterations",
    *_SWITCHES,
)
_FRACTION = (
    "link_match_minimum_response_fine",
    "loop_match_minimum_response_coarse",
    "loop_match_minimum_response_fine",
    "loop_ambiguity_ratio",
    "occupancy_hit_offset_cells",
    "wall_heading_min_quality",
)
_MAY_BE_ZERO = (
    "minimum_travel_distance",
    "minimum_travel_heading",
    "minimum_time_interval",
    "link_match_minimum_response_fine",
    "loop_match_minimum_response_coarse",
    "loop_match_minimum_response_fine",
    "loop_minimum_travel",
    "loop_match_minimum_chain_distance",
    "loop_ambiguity_distance",
    "link_match_odometry_gate_chi2",
    "odometry_step_std_xy",
    "odometry_step_std_yaw_per_m",
    "odometry_step_std_yaw",
    *_SWITCHES,
    "wall_heading_min_quality",
    "wall_heading_variance_scale",
    "wall_heading_halves_tolerance",
    "occupancy_hit_offset_cells",
    "occupancy_clear_range",
    "occupancy_clear_margin",
    "leg_bias_mean_forward",
    "leg_bias_mean_sideways",
    "leg_bias_std_forward",
    "leg_bias_std_sideways",
    "leg_bias_random_walk",
)
_SIGNED = ("leg_bias_mean_forward", "leg_bias_mean_sideways")


def _read(path: Path) -> dict:
    import yaml

    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        line = getattr(getattr(e, "problem_mark", None), "line", None)
        raise ValueError(
            f"params file {path}: not valid YAML" + (f" (line {line + 1})" if line is not None else "")
        ) from None
    raw = {} if raw is None else raw
    if not isinstance(raw, dict):
        raise ValueError(f"params file {path}: expected a mapping of SLAM parameters")
    return raw


def load_params(path: str | os.PathLike | None = None, laser: bool = False) -> dict:
    """The values of slam.yaml, for a 2D laser log (`laser`) overridden by laser.yaml, then by the
    file at `path` (checked)."""
    values = _read(DEFAULTS_FILE)
    source = DEFAULTS_FILE
    if laser:
        values |= _read(LASER_FILE)
        source = LASER_FILE
    if path is not None:
        source = Path(path)
        if not source.is_file():
            raise FileNotFoundError(f"params file not found: {source}")
        user = _read(source)
        unknown = sorted(set(user) - set(values))
        if unknown:
            raise ValueError(f"params file {source}: unknown key(s) {unknown}; known: {sorted(values)}")
        values |= user
    for key, v in values.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"params file {source}: {key} must be a finite number, got {v!r}")
        if key in _INTEGER:
            if v != int(v):
                raise ValueError(f"params file {source}: {key} must be an integer, got {v!r}")
            values[key] = int(v)
        if (v < 0 and key not in _SIGNED) or (v == 0 and key not in _MAY_BE_ZERO) or (key in _FRACTION and v > 1):
            raise ValueError(f"params file {source}: {key} = {v!r} is out of range")
    for key in _SWITCHES:
        if values[key] not in (0, 1):
            raise ValueError(f"params file {source}: {key} must be 0 or 1, got {values[key]!r}")
    if not (0.5 < values["occupancy_hit_probability"] < 1.0 and 0.0 < values["occupancy_miss_probability"] < 0.5):
        raise ValueError(
            f"params file {source}: occupancy_hit_probability must lie in (0.5, 1) and occupancy_miss_probability"
            " in (0, 0.5)"
        )
    if not (
        0.0 < values["occupancy_clamp_min_probability"] < values["occupancy_miss_probability"]
        and values["occupancy_hit_probability"] < values["occupancy_clamp_max_probability"] < 1.0
    ):
        raise ValueError(
            f"params file {source}: occupancy_clamp_min_probability must lie in (0, occupancy_miss_probability) and"
            " occupancy_clamp_max_probability in (occupancy_hit_probability, 1)"
        )
    if values["loop_chain_scans"] < 1 or values["coarse_angle_resolution"] > values["coarse_search_angle_offset"]:
        raise ValueError(f"params file {source}: coarse_angle_resolution must not exceed coarse_search_angle_offset")
    return values


def map_max_range(values: dict) -> float:
    """m: the longest reading the map reads: `max_laser_range`, or `occupancy_clear_range` beyond it (the map
    grids' traversal length)."""
    return max(values["max_laser_range"], values["occupancy_clear_range"])


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


def slam_config(values: dict, grid: GridSpec, lo_constraints: str, T_base_laser=(0.0, 0.0, 0.0)):
    """(SlamSpec, SlamParams) of checked `values` (from `load_params`) for a map `grid`, whose rays must reach
    `occupancy_clear_range` when it lies beyond `max_laser_range` (`map_max_range`)."""
    v = values
    if v["occupancy_clear_range"] > max(v["max_laser_range"], grid.max_range):
        raise ValueError(
            f"occupancy_clear_range {v['occupancy_clear_range']} m lies beyond the map grid's rays ({grid.max_range} "
            "m): size the grid with slam.map_max_range"
        )
    res = v["correlation_search_space_resolution"]
    window = max(1, round(v["correlation_search_space_dimension"] / 2 / res))
    deg = math.degrees
    match = MatchSpec(
        cells=cells_for_range(v["match_max_range"], res, window),
        resolution=res,
        window_cells=window,
        angle_window_deg=deg(v["coarse_search_angle_offset"]),
        angle_step_deg=deg(v["coarse_angle_resolution"]),
        fine_angle_step_deg=deg(v["fine_search_angle_offset"]),
    )
    loop_res = v["loop_search_space_resolution"]
    loop_window = max(1, round(v["loop_search_space_dimension"] / 2 / loop_res))
    coarse = MatchSpec.loop(
        cells=cells_for_range(v["match_max_range"], loop_res, loop_window),
        resolution=loop_res,
        window_cells=loop_window,
        angle_window_deg=match.angle_window_deg,
        angle_step_deg=match.angle_step_deg,
        fine_angle_step_deg=match.fine_angle_step_deg,
    )
    spec = SlamSpec(
        grid=grid,
        nodes=v["node_capacity"],
        buffer=v["scan_buffer_size"],
        match=match,
        loop=LoopSpec(coarse=coarse, fine=match, chain=v["loop_chain_scans"]),
        lo_constraints=lo_constraints,
        wall_heading=v["wall_heading"] == 1,
    )
    f = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    mp = MatchParams(smear_sigma=f(v["correlation_search_space_smear_deviation"]), range_max=f(v["match_max_range"]))
    params = SlamParams(
        match=mp,
        loop=LoopParams(
            match=mp,
            search_radius=f(v["loop_search_maximum_distance"]),
            min_chain=jnp.asarray(v["loop_match_minimum_chain_size"]),
            min_chain_distance=f(v["loop_match_minimum_chain_distance"]),
            min_travel=f(v["loop_minimum_travel"]),
            coarse_response=f(v["loop_match_minimum_response_coarse"]),
            fine_response=f(v["loop_match_minimum_response_fine"]),
            ambiguity_distance=f(v["loop_ambiguity_distance"]),
            ambiguity_ratio=f(v["loop_ambiguity_ratio"]),
            max_position_std=f(v["loop_match_maximum_std"]),
        ),
        occupancy=OccupancyParams(
            l_free=f(_logit(v["occupancy_miss_probability"])),
            l_occ=f(_logit(v["occupancy_hit_probability"])),
            range_max=f(v["max_laser_range"]),
            hit_offset=f(v["occupancy_hit_offset_cells"] * grid.resolution),
            clear_range=f(v["occupancy_clear_range"]),
            clear_margin=f(v["occupancy_clear_margin"]),
            l_min=f(_logit(v["occupancy_clamp_min_probability"])),
            l_max=f(_logit(v["occupancy_clamp_max_probability"])),
        ),
        solver=SolverParams(robust_width=f(v["robust_width"]), max_iterations=jnp.asarray(v["solver_max_iterations"])),
        T_base_laser=f(T_base_laser),
        min_travel=f(v["minimum_travel_distance"]),
        min_rotation=f(v["minimum_travel_heading"]),
        min_interval=f(v["minimum_time_interval"]),
        buffer_distance=f(v["scan_buffer_maximum_scan_distance"]),
        link_min_response=f(v["link_match_minimum_response_fine"]),
        match_cov_scale=f(v["match_covariance_scale"]),
        match_odometry_gate=f(v["link_match_odometry_gate_chi2"] or jnp.inf),
        odometry_step_std=f([v[f"odometry_step_std_{k}"] for k in ("xy", "yaw_per_m", "yaw")]),
        odom_fallback_std=f([v["odom_fallback_std_xy"], v["odom_fallback_std_xy"], v["odom_fallback_std_yaw"]]),
        velocity_cov=f([v["leg_velocity_var_xy"], v["leg_velocity_var_xy"], v["leg_velocity_var_yaw"]]),
        velocity_max_dt=f(v["leg_velocity_max_dt"]),
        lo_correlation_s=f(v["leg_correlation_time"]),
        loop_max_chi2=f(v["loop_consistency_chi2"]),
        robust_links=jnp.asarray(v["robust_match_links"] == 1),
        robust_loops=jnp.asarray(v["robust_loop_edges"] == 1),
        heading=HeadingParams(window_m=f(v["wall_heading_window"]), max_range=f(v["wall_heading_max_range"])),
        heading_variance_scale=f(v["wall_heading_variance_scale"]),
        heading_min_std=f(v["wall_heading_min_std"]),
        heading_min_quality=f(v["wall_heading_min_quality"]),
        heading_halves_tolerance=f(v["wall_heading_halves_tolerance"]),
        heading_max_chi2=f(v["wall_heading_max_chi2"]),
        heading_gate_with_r=jnp.asarray(v["wall_heading_gate_with_r"] == 1),
        loop_chain_priors=jnp.asarray(v["wall_heading_in_loop_test"] == 1),
        loop_graph_covariance=jnp.asarray(v["loop_consistency_graph"] == 1),
        lo_bias_mean=f([v["leg_bias_mean_forward"], v["leg_bias_mean_sideways"]]),
        lo_bias_std=f([v["leg_bias_std_forward"], v["leg_bias_std_sideways"]]),
        lo_bias_walk=f(v["leg_bias_random_walk"]),
        lo_bias_gate=f(v["leg_bias_gate_chi2"]),
    )
    return spec, params
