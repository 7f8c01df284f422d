"""The settings of an exploration run (`ExploreConfig`: its variants, defaults and checks) and its result."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from jaxquad import slam
from jaxquad.explore import loop as xl
from jaxquad.nav.fleet import REPLAN_TICKS

VARIANTS = {"full": ("leg", "stabilized", "preintegrated"), "baseline": ("visual", "baseline", "off")}
SCAN_RANGE = 8.0  # m, the scans' range limit (the depth camera's); scan matching reads up to match_max_range
# m/s: prior std of each robot's leg-odometry sideways bias, which the full variant's SLAM estimates from its matches
# (`jaxquad.slam.leg_bias`). The Badger's drifts 2.5-3.5 mm/s at exploration's pace: 100 warehouse runs, 240 s,
# lost 19 -> 6. The Go2's (0.1-0.5 mm/s) lies under the estimate's spread: not estimated (README, exploration).
LEG_BIAS_SIDEWAYS = {"badger": 0.01}


def leg_bias_sideways(robot: str, value: float | None) -> float:
    """m/s: `value`, or the robot's default (`LEG_BIAS_SIDEWAYS`, else 0: not estimated) when None."""
    return LEG_BIAS_SIDEWAYS.get(robot, 0.0) if value is None else float(value)


@dataclasses.dataclass(frozen=True)
class ExploreConfig:
    robot: str = "go2"
    world: str = "house"
    n_robots: int = 2
    seconds: float = 60.0  # simulated time of the run
    variant: str = "full"  # or "baseline"
    seed: int = 0  # world, starts, robot variation and noise
    style: str = "aggressive"  # gait style (calm or aggressive)
    samples: int = 256  # MPPI samples
    horizon: int = 30  # MPPI steps (of one control tick each)
    chunk_ticks: int = 50  # control ticks per compiled chunk (a multiple of REPLAN_TICKS)
    slam_params: str | None = None  # SLAM parameter file (None: jaxquad/slam/slam.yaml)
    clearance: float = 0.75  # m from every box for the starts (a robot turning in place sweeps ~0.4 m)
    map_range: float = 4.0  # m: longer readings are no-returns for the map (depth noise, 1 % of z^2, is 16 cm at 4 m)
    # m: readings from map_range up to this mark no wall but clear the map along their ray, stopping three noise std
    # short of the reading (`kernels.occupancy`; the SLAM file's occupancy_clear_margin); in place of the file's
    # occupancy_clear_range, at most SCAN_RANGE; 0 (or at most map_range): not beyond map_range.
    # 100 Go2 runs, H200, 0 -> 8 m: warehouse 900 s runs at 95 % 47 -> 56 (of the clear cells 56 -> 70), lost 13 ->
    # 16; house 600 s 78 -> 75 (92 -> 93), coverage at 2 min 0.795 -> 0.813 (README, exploration).
    map_clear_range: float = SCAN_RANGE
    # The map's miss probability (a cell a ray crosses), in place of the SLAM file's: at 0.3 a cell is free after two
    # crossing scans (0.35 needs three), and cells seen from few nodes near the walls become free. 100 Go2 runs in the
    # house: coverage 0.896 -> 0.919, runs with 95 % of the clear cells 29 -> 57 (README, exploration).
    map_miss_probability: float = 0.3
    # Cells (0-1): a return marks the map cell this far beyond it along the ray, in place of the SLAM file's
    # `occupancy_hit_offset_cells` (half a cell). The cell a box's face passes through is free in the true map when its
    # centre lies in front of the face; a whole cell beyond the reading leaves it to the ray's free evidence also when
    # the face is met obliquely, and under pose error moves the scatter of returns into the box. 100 runs per robot in
    # the house, 600 s, runs at 95 %: Go2 1 / 44 / 71, Badger 4 (half) / 22 at offsets 0 / half / whole (README).
    map_hit_offset_cells: float = 1.0
    # The full variant's SLAM takes heading priors from the walls' directions (`kernels.wall_heading`), in place of the
    # SLAM file's `wall_heading`; the baseline's never does. 100 Go2 runs, H200: warehouse 240 s lost 11 -> 3, SLAM
    # position error at 4 min 0.216 -> 0.117 m (median); house 600 s coverage 0.918 against 0.919, runs with 95 % of
    # the clear cells 57 -> 72 (README, exploration).
    wall_heading: bool = True
    # m added to the footprint's covering disks in the costmap (the planner's and MPPI's inscribed radius), against
    # the SLAM pose's error (median 0.05 m Go2, 0.12 m Badger) and a map whose faces lie up to a cell inside the boxes
    # (the hit offset above). 100 runs per robot in the house, 600 s, 0.1 -> 0.15: collided + lost Go2 14 -> 3,
    # Badger 48 -> 23; runs at 95 % Go2 84 -> 78, Badger 22 -> 24 (README, exploration).
    footprint_padding: float = 0.15
    # m the footprint's outline points are moved out in the controller's check against lethal and unknown cells
    # (`kernels.critics.obstacle`): the costmap inflates no unknown cell, and the robots' collisions with the speed
    # options were with box faces their maps held unknown (README, exploration); 0: the outline itself.
    outline_padding: float = 0.0
    # m/s: prior std of the leg odometry's sideways velocity bias, which the SLAM estimates from its scan matches and
    # takes out of its leg edges (`jaxquad.slam.leg_bias`), in place of the SLAM file's leg_bias_std_sideways; 0: not
    # estimated; None: the robot's default (`LEG_BIAS_SIDEWAYS`).
    leg_bias_sideways: float | None = None
    # The full variant's loop-closure consistency gate (chi-square, 3 dof), in place of the SLAM file's
    # loop_consistency_chi2 (16.27, the 99.9 % point); the baseline keeps the file's. 100 Badger runs, H200, 16.27 ->
    # 7.81 (the 95 % point): house 600 s lost 10 -> 1, runs at 95 % 48 -> 61; warehouse 900 s lost 35 -> 31, runs at
    # 95 % 50 -> 45 (README, exploration). The file keeps 16.27: an odometry whose drift its covariance understates
    # (a heading-rate bias) has its correct closures refused at 7.81 (tests/test_slam_online.py's loop).
    loop_consistency_chi2: float = 7.81
    spin_rate: float = 0.6  # rad/s, turning in place without a goal
    finish_time: float = 12.0  # s without a goal before exploration counts as finished (one turn and more)
    # Obstacles under the camera's scan plane (a pallet lower than the camera), marked from the depth image's points
    # below it in the full variant's costmap (`kernels.low_obstacles`); off, and always in the baseline: the costmap is
    # the SLAM map's alone. 100 Go2 runs in the warehouse, H200: collided 14 -> 0 in 240 s (README, exploration).
    low_obstacles: bool = True
    # Once no reachable frontier is left, walk to where one out of reach lies in plain view and look at it
    # (`nav.explore`, `kernels.view_goals`); the baseline variant's explorer never does (explore_lite's). 100 runs per
    # robot in the house, 600 s, H200, their first version: runs at 95 % Go2 65 -> 71, Badger 18 -> 25 (README).
    view_goals: bool = True
    # m/s: the controller's forward speed limit (MPPI's vx); the paper's DWB limit 0.26 m/s by default. The
    # aggressive gait walks up to 1 m/s.
    max_speed: float = 0.26
    # m/s: the forward limit while the robot stands within the costmap's inflation radius (0.7 m) of a known
    # obstacle, or on an unknown cell (`loop.near_obstacle_limit`); None: `max_speed` everywhere.
    near_obstacle_speed: float | None = None
    # per m of a frontier cluster's size, against 1 per m of its path cost (`kernels.frontiers`): 0 picks the nearest
    # frontier, the paper's choice; explore_lite's defaults (potential_scale 3, gain_scale 1) are 1/3.
    frontier_gain: float = 0.0
    # s without an accepted loop closure before the robot drives back to a place mapped a minute or more ago to close
    # one (active loop closing, `jaxquad.nav.revisit`); 0: never.
    revisit_after: float = 0.0
    contacts: str = "truth"  # the estimator's contact source
    band_height: int = 1  # scan band rows
    band_reduce: str = "median"  # each ray's range from its band: "median" or the paper's "min" (kernels.scan)
    randomize: bool = True  # per-robot masses, friction, motors and noise levels
    trace_robots: int = 8  # robots whose paths are kept in the result
    devices: int | None = None  # devices the robots are split over (`jaxquad.parallel.mesh`); None: all local ones

    def __post_init__(self):
        if self.variant not in VARIANTS:
            raise ValueError(f"variant must be one of {sorted(VARIANTS)}, got {self.variant!r}")
        for name in ("n_robots", "samples", "horizon", "chunk_ticks", "band_height", "trace_robots"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("seconds", "spin_rate", "finish_time", "map_range"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        for name in ("max_speed", "near_obstacle_speed"):  # None: max_speed everywhere
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value}")
        for name in ("frontier_gain", "revisit_after", "footprint_padding", "outline_padding", "map_clear_range"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {getattr(self, name)}")
        bias = leg_bias_sideways(self.robot, self.leg_bias_sideways)
        if not (math.isfinite(bias) and bias >= 0):
            raise ValueError(f"leg_bias_sideways must be a finite number >= 0, got {self.leg_bias_sideways}")
        if not (math.isfinite(self.loop_consistency_chi2) and self.loop_consistency_chi2 > 0):
            raise ValueError(f"loop_consistency_chi2 must be a finite number > 0, got {self.loop_consistency_chi2}")
        if not 0.0 < self.map_miss_probability < 0.5:
            raise ValueError(f"map_miss_probability must lie in (0, 0.5), got {self.map_miss_probability}")
        if not 0.0 <= self.map_hit_offset_cells <= 1.0:
            raise ValueError(f"map_hit_offset_cells must lie in [0, 1], got {self.map_hit_offset_cells}")
        if self.chunk_ticks % REPLAN_TICKS:
            raise ValueError(f"chunk_ticks must be a multiple of {REPLAN_TICKS}, got {self.chunk_ticks}")
        self.slam_values()  # reads and checks the SLAM file now, before any heavy work

    def loop_config(self) -> xl.ExploreLoopConfig:
        odometry, scans, lo = VARIANTS[self.variant]
        return xl.ExploreLoopConfig(
            odometry=odometry,
            scans=scans,
            lo_constraints=lo,
            band_height=self.band_height,
            band_reduce=self.band_reduce,
            contacts=self.contacts,
            low_obstacles=self.low_obstacles and self.variant == "full",
        )

    def slam_values(self) -> dict:
        """The SLAM parameters, with node slots for a node every `minimum_time_interval` of the run, the map's
        range `map_range` (at most the longest reading the SLAM file reads), clearing to `map_clear_range`, its miss
        probability `map_miss_probability`, its hit offset `map_hit_offset_cells`, and wall-heading priors for the
        full variant when `wall_heading`, the sideways leg-odometry bias's prior `leg_bias_sideways`, and the full
        variant's loop-closure gate `loop_consistency_chi2`."""
        values = slam.load_params(self.slam_params)
        if not values["occupancy_clamp_min_probability"] < self.map_miss_probability:
            source = self.slam_params or slam.params.DEFAULTS_FILE
            raise ValueError(
                f"params file {source}: occupancy_clamp_min_probability ({values['occupancy_clamp_min_probability']}) "
                f"must lie below map_miss_probability ({self.map_miss_probability})"
            )
        nodes = math.ceil(self.seconds / max(values["minimum_time_interval"], 0.1)) + 2
        nodes = max(values["node_capacity"] if self.slam_params else 0, nodes)
        full = self.variant == "full"
        return values | {
            "node_capacity": nodes,
            "occupancy_hit_offset_cells": self.map_hit_offset_cells,
            "max_laser_range": min(slam.map_max_range(values), self.map_range),
            "occupancy_clear_range": min(self.map_clear_range, SCAN_RANGE),
            "occupancy_miss_probability": self.map_miss_probability,
            "wall_heading": int(self.wall_heading and full),
            # the baseline's SLAM has no leg edges to correct
            "leg_bias_std_sideways": leg_bias_sideways(self.robot, self.leg_bias_sideways) * full,
            "loop_consistency_chi2": self.loop_consistency_chi2 if full else values["loop_consistency_chi2"],
        }


@dataclasses.dataclass
class ExploreResult:
    """A finished run, NumPy (N robots, T ticks)."""

    config: ExploreConfig
    world: object  # sim.worlds.World (ground truth)
    truth: object  # OccupancyMap: the world's true map, on the cells of the robots' maps
    reachable: np.ndarray  # (H, W) bool: true free cells connected to the starts, `metrics.narrow_gaps` left out
    # (coverage's denominator)
    clear: np.ndarray  # (H, W) bool: the reachable cells whose whole square is off every box (coverage_clear's)
    maps: np.ndarray  # (N, H, W) int8: each robot's final SLAM map (-1 unknown, 0..100)
    low: np.ndarray  # (N, H, W) bool: the obstacles under the scan plane each robot marked ((N, 0, 0) when off)
    starts: np.ndarray  # (N, 3) x y yaw
    outcome: np.ndarray  # (N,) loop.OUTCOMES codes
    end_t: np.ndarray  # (N,) s when the run ended (NaN: running at the end)
    distance: np.ndarray  # (N,) m walked
    nodes: np.ndarray  # (N,) SLAM nodes
    loops: np.ndarray  # (N,) loop closures accepted
    revisits: np.ndarray  # (N,) revisits begun (`ExploreConfig.revisit_after`)
    revisits_closed: np.ndarray  # (N,) revisits that ended with a loop closure
    t: np.ndarray  # (T,) s
    coverage: np.ndarray  # (T, N)
    error: np.ndarray  # (T, N) m, SLAM position error
    active: np.ndarray  # (T, N)
    revisiting: np.ndarray  # (T, N) the goal was a revisit
    viewing: np.ndarray  # (T, N) the goal was a view goal
    loop_closed: np.ndarray  # (T, N) the SLAM accepted a loop closure on the tick
    loop_chi2: np.ndarray  # (T, N) consistency chi-square of a loop candidate past the match tests (NaN: none)
    lo_bias: np.ndarray  # (N, 2) m/s: the SLAM's last estimate of the leg odometry's velocity bias, base frame
    true_pose: np.ndarray  # (T, n_trace, 3)
    pose: np.ndarray  # (T, n_trace, 3) SLAM pose
    goal: np.ndarray  # (T, n_trace, 3) the frontier or view goal (or revisited node), x y yaw
    mode: np.ndarray  # (T, n_trace) int8: what commanded the robot (loop.MODES)
    compile_s: float
    run_s: float  # wall time of the chunks and of copying their outputs to the host, compilation excluded
    chunk_s: np.ndarray  # (K,) that wall time per chunk, s, over all sittings
    sim_s: float
