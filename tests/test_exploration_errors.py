"""experiments/exploration_errors.py on traces written by experiments/exploration.py --traces: the summary
against values built into synthetic traces (loop candidates included), and the file round trip."""

from types import SimpleNamespace

import numpy as np
import pytest
from _experiments import load
from scipy.stats import chi2 as chi2_distribution
from scipy.stats import norm

from jaxquad.explore import OUTCOMES

errors, exploration = load("exploration_errors"), load("exploration")

T = np.arange(1, 1250) * 0.096  # tick end times, the last at 119.904 s: the 2nd minute's sample is a tick short


def _traces():
    n = 3
    t = T.astype(np.float32)
    err = (0.001 * np.arange(len(t))[:, None] * np.array([1.0, 2.0, 3.0])).astype(np.float32)  # 1, 2, 3 mm a tick
    err[500, 1] += 0.2  # run 1 jumps once by 0.2 m (and back)
    active = np.ones((len(t), n), bool)
    end = np.full(n, np.nan)
    end[1] = t[800]  # run 1 lost at 76.9 s: its tick 800 is its last active one
    active[801:, 1] = False
    true_pose = np.zeros((len(t), n, 3), np.float32)
    true_pose[..., 2] = np.pi - 0.01  # headings across the +-pi seam: off by 0.02 rad x (1, 2, 3), not 2 pi - ...
    pose = true_pose.copy()
    pose[..., 2] = -np.pi + 0.01 * np.array([1.0, 3.0, 5.0])
    pose[800, 1, 2] = -np.pi + 0.05  # run 1's last tick: 0.06 rad off
    pose[801:, 1, 2] = 0.0  # after its end run 1's trace is garbage, which the summary must not read
    outcome = np.array([OUTCOMES.index("running"), OUTCOMES.index("lost"), OUTCOMES.index("collided")])
    return dict(t=t, error=err, active=active, outcome=outcome, end_t=end, pose=pose, true_pose=true_pose)


def test_summary_medians_lost_runs_and_the_random_walk():
    s = errors.summarize(_traces(), yaw_walk=np.deg2rad(0.2))
    assert s["runs"] == 3 and s["lost"] == 1
    m1, m2 = s["per_minute"]
    # Minute 1: tick 625 ends at 60.0 s, all three runs active: the median is run 1's 2 mm x 624.
    assert m1["t_s"] == pytest.approx(60.0, abs=1e-4) and m1["active_runs"] == 3
    assert m1["position_error_median_m"] == pytest.approx(0.002 * 624, rel=1e-5)
    assert m1["heading_error_median_deg"] == pytest.approx(np.degrees(0.04), abs=1e-3)
    # Minute 2: the last sample, 119.904 s; run 1 ended: the median of runs 0 and 2 (1 and 3 mm x 1248).
    assert m2["t_s"] == pytest.approx(119.904, abs=1e-4) and m2["active_runs"] == 2
    assert m2["position_error_median_m"] == pytest.approx(0.002 * 1248, rel=1e-5)
    assert m2["heading_error_median_deg"] == pytest.approx(np.degrees(0.04), abs=1e-3)
    (run,) = s["lost_runs"]
    assert run["run"] == 1 and run["end_s"] == pytest.approx(T[800], rel=1e-6)
    assert run["largest_tick_change_m"] == pytest.approx(0.202, rel=1e-4)
    assert run["final_heading_error_deg"] == pytest.approx(np.degrees(0.06), abs=1e-3)


def test_yaw_walk_median_against_sampling():
    rng = np.random.default_rng(0)
    z = rng.standard_normal(2_000_000)
    walk = np.deg2rad(0.2)
    assert errors.yaw_walk_median(walk, 60.0, randomize=False) == pytest.approx(norm.ppf(0.75) * walk * np.sqrt(60))
    mixed = np.median(np.abs(rng.uniform(0.5, 1.5, z.size) * z)) * walk * np.sqrt(60)  # sim.fleet's draw
    assert errors.yaw_walk_median(walk, 60.0) == pytest.approx(mixed, rel=2e-3)


def test_traces_round_trip_and_bad_files(tmp_path):
    d = _traces()
    config = SimpleNamespace(robot="go2", world="warehouse", variant="full", seed=0, randomize=False)
    extra = dict(coverage=d["error"], distance=np.ones(3), nodes=np.ones(3), loops=np.zeros(3), starts=np.zeros((3, 3)))
    extra |= dict(goal=d["pose"] + 1.0, mode=np.full(d["error"].shape, 5, np.int8))
    extra |= dict(revisits=np.array([0, 2, 1]), revisits_closed=np.array([0, 1, 1]), revisiting=d["error"] > 0.2)
    extra["viewing"] = d["error"] > 0.3
    extra |= dict(loop_closed=np.zeros(d["error"].shape, bool), loop_chi2=np.full(d["error"].shape, np.nan))
    extra["lo_bias"] = np.array([[0.0, -0.0025], [0.0, 0.0004], [0.0, 0.0]])
    maps = np.random.default_rng(1).integers(-1, 101, (3, 4, 5)).astype(np.int8)
    truth = SimpleNamespace(grid=maps[0], origin=(-1.0, -2.0, 0.0), resolution=0.05)
    extra |= dict(maps=maps, reachable=maps[1] < 20, clear=maps[2] < 20, truth=truth)
    result = SimpleNamespace(config=config, **d, **extra)
    exploration.save_traces(tmp_path / "cell.npz", result)
    back = errors.load(tmp_path / "cell.npz")
    np.testing.assert_array_equal(back["pose"], d["pose"])
    np.testing.assert_array_equal(back["goal"], extra["goal"])
    assert back["mode"].dtype == np.int8 and np.all(back["mode"] == 5)
    np.testing.assert_array_equal(back["revisiting"], d["error"] > 0.2)
    np.testing.assert_array_equal(back["viewing"], d["error"] > 0.3)
    np.testing.assert_array_equal(back["revisits"], [0, 2, 1])
    np.testing.assert_array_equal(back["lo_bias"], extra["lo_bias"])
    np.testing.assert_array_equal(back["maps"], maps)
    np.testing.assert_array_equal(back["true_map"], maps[0])
    assert back["reachable"].dtype == bool and np.array_equal(back["clear"], maps[2] < 20)
    assert list(back["map_origin"]) == [-1.0, -2.0, 0.0] and float(back["map_resolution"]) == 0.05
    assert str(back["world"]) == "warehouse" and int(back["seed"]) == 0 and not bool(back["randomize"])
    errors.plot(back, np.deg2rad(0.2), tmp_path / "errors.png")
    assert (tmp_path / "errors.png").stat().st_size > 0

    np.savez(tmp_path / "other.npz", t=d["t"])
    with pytest.raises(SystemExit, match="lacks error"):
        errors.load(tmp_path / "other.npz")
    (tmp_path / "broken.npz").write_text("not a zip")
    with pytest.raises(SystemExit, match="cannot read"):
        errors.load(tmp_path / "broken.npz")
    np.save(tmp_path / "bare.npy", d["t"])
    with pytest.raises(SystemExit, match="cannot read"):
        errors.load(tmp_path / "bare.npy")
    np.savez(tmp_path / "some_paths.npz", **(d | {"pose": d["pose"][:, :1], "true_pose": d["true_pose"][:, :1]}))
    with pytest.raises(SystemExit, match="every run's path"):
        errors.load(tmp_path / "some_paths.npz")


def test_map_summary_by_outcome_and_against_the_slam_error():
    from jaxquad.io.maps import OccupancyMap
    from jaxquad.metrics import map_scores

    truth = np.full((30, 30), -1, np.int8)
    truth[3:27, 3:27] = 100
    truth[4:26, 4:26] = 0
    truth[12:16, 12:16] = 100
    half = truth.copy()
    half[:, :15] = np.where(half[:, :15] == 100, 0, half[:, :15])  # the left half's walls missed
    shifted = np.roll(truth, 2, axis=0)  # two cells off: beyond the one-cell tolerance
    maps = np.stack([truth, half, shifted, np.full_like(truth, -1)])
    ticks = 20
    error = np.tile(np.array([0.01, 0.05, 0.10, 0.60], np.float32), (ticks, 1))
    outcome = np.array([OUTCOMES.index(o) for o in ("explored", "explored", "explored", "lost")])
    d = dict(maps=maps, true_map=truth, map_origin=np.array([0.0, 0.0, 0.0]), map_resolution=np.float64(0.05),
             error=error, active=np.ones((ticks, 4), bool), outcome=outcome)  # fmt: skip
    got = errors.map_summary(d)
    occ = lambda g: OccupancyMap(g, 0.05, (0.0, 0.0, 0.0))  # noqa: E731
    iou = [map_scores(occ(m), occ(truth)).iou for m in maps[:3]]
    assert iou[0] == 1.0 and iou[0] > iou[1] > 0 and iou[2] < 1
    explored, lost = got["per_outcome"]["explored"], got["per_outcome"]["lost"]
    assert explored["runs"] == 3 and explored["iou_median"] == pytest.approx(np.median(iou))
    assert explored["iou_p90"] == pytest.approx(np.percentile(iou, 90)) and explored["recall_median"] <= 1.0
    # An empty map: IoU and recall 0, and no precision (it has no occupied cell).
    assert lost == {"runs": 1, "iou_median": 0.0, "iou_p10": 0.0, "iou_p90": 0.0, "precision_median": None,
                    "recall_median": 0.0}  # fmt: skip
    r = got["explored_iou_vs_median_error_correlation"]
    assert r == pytest.approx(np.corrcoef(iou, [0.01, 0.05, 0.10])[0, 1]) and r < 0
    assert "running" not in got["per_outcome"]


def test_trace_ticks_keep_every_kth_tick_and_the_last():
    idx = exploration.trace_ticks(T, 0.96)  # 10 ticks of 0.096 s
    np.testing.assert_array_equal(idx, np.append(np.arange(9, len(T), 10), len(T) - 1))
    np.testing.assert_array_equal(exploration.trace_ticks(T, 0.0), np.arange(len(T)))
    np.testing.assert_array_equal(exploration.trace_ticks(T, 0.04), np.arange(len(T)))  # under a tick: every tick
    np.testing.assert_array_equal(exploration.trace_ticks(T[:20], 0.96), [9, 19])  # the last tick already kept
    np.testing.assert_array_equal(exploration.trace_ticks(T[:1], 5.0), [0])


def test_thinned_traces_keep_the_series_at_the_kept_ticks_and_every_map(tmp_path):
    d = _traces()
    config = SimpleNamespace(robot="go2", world="house", variant="full", seed=3, randomize=True)
    extra = dict(coverage=d["error"] / 10, distance=np.ones(3), nodes=np.ones(3), loops=np.zeros(3))
    extra |= dict(revisits=np.zeros(3, int), revisits_closed=np.zeros(3, int), revisiting=d["error"] < 0)
    extra["viewing"] = d["error"] < 0
    extra |= dict(loop_closed=np.zeros(d["error"].shape, bool), loop_chi2=np.full(d["error"].shape, np.nan))
    extra |= dict(starts=np.zeros((3, 3)), goal=d["pose"] + 1.0, mode=np.full(d["error"].shape, 2, np.int8))
    extra["lo_bias"] = np.zeros((3, 2))
    maps = np.random.default_rng(2).integers(-1, 101, (3, 4, 5)).astype(np.int8)
    truth = SimpleNamespace(grid=maps[0], origin=(0.0, 0.0, 0.0), resolution=0.05)
    extra |= dict(maps=maps, reachable=maps[1] < 20, clear=maps[2] < 20, truth=truth)
    exploration.save_traces(tmp_path / "cell.npz", SimpleNamespace(config=config, **d, **extra), every_s=0.96)
    back = errors.load(tmp_path / "cell.npz")
    k = np.append(np.arange(9, len(T), 10), len(T) - 1)
    for name in ("t", "error", "active", "pose", "true_pose"):
        np.testing.assert_array_equal(back[name], d[name][k])
    np.testing.assert_array_equal(back["coverage"], extra["coverage"][k])
    np.testing.assert_array_equal(back["goal"], extra["goal"][k])
    np.testing.assert_array_equal(back["maps"], maps)
    np.testing.assert_array_equal(back["end_t"], d["end_t"])
    s = errors.summarize(back, yaw_walk=np.deg2rad(0.2))
    assert s["sample_s"] == pytest.approx(0.96, rel=1e-5)
    (run,) = s["lost_runs"]  # run 1's last active tick, 800, is no kept one: its last kept sample is tick 799
    assert run["run"] == 1 and run["final_heading_error_deg"] == pytest.approx(np.degrees(0.04), abs=1e-3)
    assert s["per_minute"][0]["t_s"] <= 60.0 and s["per_minute"][0]["active_runs"] == 3


def test_loop_candidates_kept_at_every_tick_and_the_closures_that_jumped(tmp_path):
    """Loop candidates on ticks that thinned traces drop: each kept with its error before and after; a lost run's
    largest closure and the closures that moved an error by more than 0.3 m found among them."""
    d = _traces()
    d["error"][700:801, 1] += 0.5  # run 1's closure at tick 700 moves its error by 0.502 m
    chi2 = np.full(d["error"].shape, np.nan)
    closed = np.zeros(d["error"].shape, bool)
    for tick, run, value, accepted in ((100, 0, 2.0, True), (500, 1, 9.0, True), (700, 1, 12.0, True),
                                       (300, 2, 40.0, False)):  # fmt: skip
        chi2[tick, run], closed[tick, run] = value, accepted
    config = SimpleNamespace(robot="go2", world="warehouse", variant="full", seed=0, randomize=True)
    extra = dict(coverage=d["error"] / 10, distance=np.ones(3), nodes=np.ones(3), loops=np.array([1, 2, 0]))
    extra |= dict(revisits=np.zeros(3, int), revisits_closed=np.zeros(3, int), revisiting=d["error"] < 0)
    extra["viewing"] = d["error"] < 0
    extra |= dict(starts=np.zeros((3, 3)), goal=d["pose"], mode=np.zeros(d["error"].shape, np.int8))
    extra["lo_bias"] = np.zeros((3, 2))
    maps = np.zeros((3, 4, 5), np.int8)
    truth = SimpleNamespace(grid=maps[0], origin=(0.0, 0.0, 0.0), resolution=0.05)
    extra |= dict(maps=maps, reachable=maps[1] < 20, clear=maps[2] < 20, truth=truth)
    extra |= dict(loop_chi2=chi2, loop_closed=closed)
    exploration.save_traces(tmp_path / "cell.npz", SimpleNamespace(config=config, **d, **extra), every_s=0.96)
    back = errors.load(tmp_path / "cell.npz")
    assert back["t"].size < 200  # thinned: ticks 100, 300, 500 and 700 are not among the kept ones
    order = np.argsort(back["loop_t"])
    np.testing.assert_array_equal(back["loop_run"][order], [0, 2, 1, 1])
    np.testing.assert_array_equal(back["loop_chi2"][order], [2.0, 40.0, 9.0, 12.0])
    np.testing.assert_array_equal(back["loop_accepted"][order], [True, False, True, True])
    np.testing.assert_allclose(back["loop_t"][order], T[[100, 300, 500, 700]], rtol=1e-6)
    np.testing.assert_allclose(back["loop_error_before_m"][order], d["error"][[99, 299, 499, 699], [0, 2, 1, 1]])
    np.testing.assert_allclose(back["loop_error_after_m"][order], d["error"][[100, 300, 500, 700], [0, 2, 1, 1]])

    s = errors.summarize(back, yaw_walk=np.deg2rad(0.2))
    loops = s["loops"]
    assert (loops["accepted"], loops["refused"], loops["jumps"], loops["jump_runs"]) == (3, 1, 1, [1])
    assert loops["jump_chi2"] == [12.0, 12.0, 12.0]
    assert loops["accepted_chi2"] == pytest.approx([5.5, 8.3])  # the median and 90th percentile of 2 and 9
    (run,) = s["lost_runs"]
    big = run["largest_closure"]  # of run 1's two closures, the one that moved its error by 0.502 m
    assert big["chi2"] == 12.0 and big["t_s"] == pytest.approx(T[700], rel=1e-6)
    assert big["error_after_m"] - big["error_before_m"] == pytest.approx(0.502, abs=1e-5)
    # run 1's error was already past 0.5 m at both closures: neither carried it across; it had no refused candidate
    assert run["closure_across_lost"] is None and run["refused_closures"] == 0 and s["lost_across_by_closure"] == 0


def test_the_closure_that_carried_a_lost_runs_error_across_the_limit():
    """Of a run's accepted closures, the last one taking its error from under 0.5 m to 0.5 m or more; refused ones,
    other runs' and falls back under the limit do not count."""
    events = [  # (t, run, chi2, accepted, before, after)
        (10.0, 0, 3.0, True, 0.10, 0.55),  # across: the first of run 0's two
        (20.0, 0, 40.0, False, 0.30, 0.70),  # refused
        (30.0, 0, 5.0, True, 0.40, 0.60),  # across again, later: this one
        (35.0, 0, 2.0, True, 0.60, 0.45),  # back under: not across
        (40.0, 1, 6.0, True, 0.20, 0.90),  # another run's
        (50.0, 2, 1.0, True, 0.45, 0.49),  # stays under
    ]
    t, run, chi2, accepted, before, after = (np.array(c) for c in zip(*events))
    d = dict(loop_t=t, loop_run=run, loop_chi2=chi2, loop_accepted=accepted, loop_error_before_m=before,
             loop_error_after_m=after)  # fmt: skip
    assert errors._closure_across_lost(d, 0) == {"t_s": 30.0, "chi2": 5.0, "error_before_m": 0.4, "error_after_m": 0.6}
    assert errors._closure_across_lost(d, 1)["t_s"] == 40.0 and errors._closure_across_lost(d, 2) is None


def test_accepted_closures_by_chi_square_band():
    """Each accepted closure counted in the band its chi-square falls in (lower edge included), as raising or lowering
    its run's error by more than 5 cm or neither; refused candidates and untraced errors after left out."""
    events = [  # (run, chi2, accepted, before, after)
        (0, 0.5, True, 0.10, 0.02),  # [0, 2.37): lowered
        (1, 2.37, True, 0.10, 0.12),  # [2.37, 6.25), on its lower edge: moved 2 cm, neither
        (1, 5.0, True, 0.10, 0.30),  # [2.37, 6.25): raised
        (2, 5.0, False, 0.10, 0.90),  # refused: not counted
        (2, 9.0, True, 0.45, 0.60),  # [7.81, 11.34): raised, and across 0.5 m
        (0, 16.0, True, 0.20, np.nan),  # [11.34, gate): counted, its change unknown
    ]
    run, chi2, accepted, before, after = (np.array(c) for c in zip(*events))
    d = dict(loop_run=run, loop_chi2=chi2, loop_accepted=accepted, loop_error_before_m=before,
             loop_error_after_m=after)  # fmt: skip
    bands = errors.chi2_bands(d)
    assert [(b["chi2_from"], b["chi2_to"]) for b in bands] == [
        (0.0, 2.37), (2.37, 6.25), (6.25, 7.81), (7.81, 11.34), (11.34, None)
    ]  # fmt: skip
    rows = [(b["accepted"], b["runs"], b["raised"], b["lowered"], b["carried_across_lost"]) for b in bands]
    assert rows == [(1, 1, 0, 1, 0), (2, 1, 1, 0, 0), (0, 0, 0, 0, 0), (1, 1, 1, 0, 1), (1, 1, 0, 0, 0)]
    means = [b["mean_change_m"] for b in bands]
    assert means[0] == pytest.approx(-0.08) and means[1] == pytest.approx(0.11) and means[3] == pytest.approx(0.15)
    assert means[2] is None and means[4] is None
    # the bands' edges are the chi-square distribution's points for 3 degrees of freedom
    np.testing.assert_allclose(errors.CHI2_BANDS[1:], chi2_distribution.ppf([0.5, 0.9, 0.95, 0.99], 3), atol=0.005)


@pytest.mark.parametrize(
    "step_m, heading_rad, cause",
    [(0.2, 0.06, "heading"), (0.35, 0.06, "jump"), (-0.35, 0.06, "heading"), (0.2, 0.04, "drift")],
)
def test_a_lost_runs_cause(step_m, heading_rad, cause):
    """A rise of the error by more than JUMP_M in one sample is a jump (a fall is not: a closure that brought the
    run back); else a final heading error of HEADING_DEG or more (0.06 rad is 3.4 deg, 0.04 rad 2.3) is the cause;
    else drift."""
    d = _traces()
    d["error"][500, 1] -= 0.2  # the traces' jump and back, replaced by a step that stays
    d["error"][500:, 1] += step_m
    d["pose"][800, 1, 2] = -np.pi - 0.01 + heading_rad  # true heading pi - 0.01: off by heading_rad at its end
    s = errors.summarize(d, yaw_walk=np.deg2rad(0.2))
    (run,) = s["lost_runs"]
    assert run["cause"] == cause
    assert s["lost_causes"] == {c: int(c == cause) for c in ("jump", "heading", "drift")}


def test_collided_runs_nearest_box_mode_and_view():
    """Two axis-aligned boxes; run 2 (collided) ends with the footprint's front-left corner 0.03 m inside box 1,
    read at its last active sample (later samples hold garbage)."""
    from jaxquad.explore.loop import MODES
    from jaxquad.sim.worlds import World

    d = _traces()
    center = np.array([[0.0, 5.0, 0.5], [3.0, 0.0, 0.5]])
    half = np.array([[1.0, 1.0, 0.5], [0.5, 0.5, 0.5]])
    world = World("house", 0, center, half, np.zeros(2), (-2.0, -2.0, 6.0, 8.0), np.zeros((0, 2)))
    fc, fh = np.array([-0.05, 0.0]), np.array([0.3, 0.15])
    k = 900
    d["active"][k + 1 :, 2] = False
    corner_x = 3.0 - 0.5 + 0.03  # the corner (x = base + fc + fh) 0.03 m past box 1's face at x = 2.5
    d["true_pose"][k, 2] = [corner_x - fc[0] - fh[0], 0.0, 0.0]
    d["true_pose"][k + 1 :, 2] = [0.0, 5.0, 0.0]  # inside box 0: must not be read
    d["mode"] = np.full(d["error"].shape, MODES.index("mppi"), np.int8)
    d["mode"][k, 2] = MODES.index("recovery")
    d["viewing"] = np.zeros(d["error"].shape, bool)
    d["viewing"][k, 2] = True
    s = errors.collision_summary(d, world, (fc, fh))
    (run,) = s["collided_runs"]
    assert run["run"] == 2 and run["box"] == 1 and run["box_distance_m"] == pytest.approx(-0.03, abs=1e-6)
    assert run["mode"] == "recovery" and run["viewing"] and run["slam_error_m"] == pytest.approx(0.003 * k, rel=1e-5)
    assert run["true_pose"] == pytest.approx(d["true_pose"][k, 2].tolist())
    assert s["collisions_by_box"] == {"1": 1} and "collisions_near_cells" not in s
    # with the final maps: box 1's true cells all unknown in run 2's map, box 0's occupied (out of reach)
    res, origin = 0.05, np.array([-2.0, -2.0, 0.0])
    cy, cx = np.indices((200, 200)) * res + origin[1::-1, None, None] + res / 2
    in_box = [(np.abs(cx - c[0]) < h[0]) & (np.abs(cy - c[1]) < h[1]) for c, h in zip(center, half)]
    d["true_map"] = np.where(in_box[0] | in_box[1], 100, 0).astype(np.int8)
    d["maps"] = np.repeat(d["true_map"][None], 3, axis=0)  # runs 0 and 1 hold every box: only run 2's map counts
    d["maps"][2] = np.where(in_box[1], -1, d["true_map"])
    d["map_resolution"], d["map_origin"] = np.float64(res), origin
    s = errors.collision_summary(d, world, (fc, fh))
    near = s["collided_runs"][0]["near_cells"]
    assert near["cells"] > 0 and near["unknown"] == near["cells"] and s["collisions_near_cells"] == near


@pytest.mark.parametrize("heading", [0.0, np.pi / 2])
def test_near_cells_count_the_wall_cells_within_reach_of_the_footprint(heading):
    """A wall of occupied cells 0.125 m beyond the front of a 0.6 x 0.2 m footprint: its cells within 0.3 m have
    centres with |lateral| <= 0.1 + sqrt(0.3^2 - 0.125^2) = 0.373 m, 14 of them (centres +-0.025 ... +-0.325), of
    which the map holds 7 unknown, 4 occupied and 3 free. Turned by 90 deg with the wall as a row, the same."""
    res, n = 0.05, 40
    truth = np.zeros((n, n), np.int8)
    known = np.full(n, 0, np.int8)
    centres = -1.0 + (np.arange(n) + 0.5) * res
    known[centres < 0] = -1
    known[(centres > 0) & (centres < 0.2)] = 100
    wall = int(round((0.425 + 1.0) / res - 0.5))  # the cell whose centre is at 0.425 m
    truth[:, wall] = 100
    maps = np.zeros((1, n, n), np.int8)
    maps[0, :, wall] = known
    if heading:  # the wall ahead along +y: a row, the lateral axis along -x
        truth, maps = truth.T.copy(), maps.transpose(0, 2, 1)[:, :, ::-1].copy()
        truth = truth[:, ::-1].copy()
    d = {"true_map": truth, "maps": maps, "map_resolution": np.float64(res), "map_origin": np.array([-1.0, -1.0, 0.0])}
    near = errors.near_cells(d, 0, (0.0, 0.0, heading), (np.zeros(2), np.array([0.3, 0.1])))
    assert near == {"cells": 14, "unknown": 7, "free": 3, "uncertain": 0, "occupied": 4}
    d["maps"][0][d["maps"][0] == 100] = 50  # occupancy 50 is neither free nor occupied
    near = errors.near_cells(d, 0, (0.0, 0.0, heading), (np.zeros(2), np.array([0.3, 0.1])))
    assert near == {"cells": 14, "unknown": 7, "free": 3, "uncertain": 4, "occupied": 0}


def test_near_cells_against_a_sampled_footprint():
    """A random map and a turned, off-centre footprint: the cells counted are those whose centre lies within NEAR_M of
    the rectangle sampled at 2 mm (its filled area, in the world frame); cells within 5 mm of that limit are left
    free in the true map, where sampling could decide either way."""
    rng = np.random.default_rng(3)
    res, n, origin = 0.05, 60, np.array([-1.5, -1.2, 0.0])
    pose, centre, half = (0.12, -0.07, 0.6), np.array([0.08, -0.02]), np.array([0.32, 0.14])
    u, v = np.meshgrid(np.arange(-half[0], half[0] + 1e-9, 0.002), np.arange(-half[1], half[1] + 1e-9, 0.002))
    c, s = np.cos(pose[2]), np.sin(pose[2])
    bx, by = u.ravel() + centre[0], v.ravel() + centre[1]
    pts = np.stack([pose[0] + c * bx - s * by, pose[1] + s * bx + c * by], axis=1)  # the rectangle in the world
    cy, cx = (np.indices((n, n)) + 0.5) * res + origin[1::-1, None, None]
    ref = np.array([np.min(np.hypot(x[:, None] - pts[:, 0], y[:, None] - pts[:, 1]), axis=1) for x, y in zip(cx, cy)])
    truth = np.where(rng.random((n, n)) < 0.5, 100, 0).astype(np.int8)
    truth[np.abs(ref - errors.NEAR_M) < 0.005] = 0
    m = rng.choice(np.array([-1, 5, 40, 90], np.int8), size=(n, n))
    d = {"true_map": truth, "maps": m[None], "map_resolution": np.float64(res), "map_origin": origin}
    hit = m[(truth == 100) & (ref <= errors.NEAR_M)]
    want = {"cells": hit.size, "unknown": (hit == -1).sum(), "free": (hit == 5).sum(), "uncertain": (hit == 40).sum(),
            "occupied": (hit == 90).sum()}  # fmt: skip
    assert errors.near_cells(d, 0, pose, (centre, half)) == {k: int(x) for k, x in want.items()}
    assert min(want.values()) > 0
