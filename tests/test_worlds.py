"""World generators, ground-truth maps (PGM + YAML round trip) and collision-free route loops."""

import mujoco
import numpy as np
import pytest

from jaxquad.io import load_map, save_map
from jaxquad.sim.routes import plan_loop
from jaxquad.sim.worlds import World, box_distances, box_signed_distance, make_world, occupancy_map, world_xml


@pytest.fixture(scope="module", params=["house", "warehouse"])
def world(request):
    return make_world(request.param, 3)


def test_seeded_and_fixed_box_count(world):
    again = make_world(world.kind, 3)
    np.testing.assert_array_equal(world.center, again.center)
    other = make_world(world.kind, 4)
    assert other.n_boxes == world.n_boxes
    assert not np.allclose(other.center, world.center)
    # Walls rise above any body-mounted camera.
    assert np.max(world.center[:, 2] + world.half[:, 2]) >= 2.5
    assert np.all(world.center[:, 2] - world.half[:, 2] >= -1e-6)  # standing on the floor
    with pytest.raises(ValueError, match="unknown world kind"):
        make_world("castle", 0)


def test_map_matches_mujoco_geometry(world):
    # Independent reference: a vertical mj_ray down onto every sampled cell centre hits a box
    # (not the floor) exactly where the map says occupied.
    occ = occupancy_map(world)
    m = mujoco.MjModel.from_xml_string(world_xml(world))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    floor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    rng = np.random.default_rng(0)
    rows = rng.integers(0, occ.grid.shape[0], 3000)
    cols = rng.integers(0, occ.grid.shape[1], 3000)
    xy = occ.cell_centers()[rows, cols]
    geomid = np.zeros(1, np.int32)
    for (x, y), g in zip(xy, occ.grid[rows, cols]):
        mujoco.mj_ray(m, d, np.array([x, y, 10.0]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geomid)
        if g >= 0:  # inside the outer walls
            assert (geomid[0] != floor) == (g == 100), (x, y)


def test_map_round_trip(world, tmp_path):
    occ = occupancy_map(world)
    assert set(np.unique(occ.grid)) == {-1, 0, 100}
    save_map(tmp_path / "map.yaml", occ)
    back = load_map(tmp_path / "map.yaml")
    np.testing.assert_array_equal(back.grid, occ.grid)
    assert back.resolution == occ.resolution and back.origin == occ.origin
    # PGM convention: the first image row is the top of the map; free 254, occupied 0, unknown 205.
    raw = (tmp_path / "map.pgm").read_bytes()
    rows, cols = occ.grid.shape
    pixels = np.frombuffer(raw[-rows * cols :], np.uint8).reshape(rows, cols)
    expect = np.select([occ.grid[::-1] == 0, occ.grid[::-1] == 100], [254, 0], 205)
    np.testing.assert_array_equal(pixels, expect)


def test_route_loop_is_collision_free(world):
    radius = 0.35
    loop = plan_loop(world, robot_radius=radius, n_waypoints=96)
    assert loop.shape == (96, 2)
    closed = np.vstack([loop, loop[:1]])
    s = np.linspace(0.0, 1.0, 40)[:, None]
    pts = np.concatenate([a + s * (b - a) for a, b in zip(closed[:-1], closed[1:])])
    # Analytic distance to the boxes themselves, not the grid the planner used.
    assert box_signed_distance(world, pts).min() >= radius
    xmin, ymin, xmax, ymax = world.bounds
    assert np.all((pts[:, 0] > xmin) & (pts[:, 0] < xmax) & (pts[:, 1] > ymin) & (pts[:, 1] < ymax))
    # The loop passes near every anchor (through every room / aisle).
    for a in world.anchors:
        assert np.min(np.linalg.norm(pts - a, axis=1)) < 1.0
    length = np.sum(np.linalg.norm(np.diff(closed, axis=0), axis=1))
    assert length > (8.0 if world.kind == "house" else 30.0)


def test_box_distances_per_box_against_closed_forms():
    """A box turned 90 deg (its half extents swap in the world) and an axis-aligned one: the point's distance to
    each, outside to a face, outside to a corner, and inside; the nearest equals `box_signed_distance`."""
    center = np.array([[0.0, 0.0, 0.5], [4.0, 0.0, 0.5]])
    half = np.array([[1.0, 0.5, 0.5], [0.5, 0.5, 0.5]])
    world = World("house", 0, center, half, np.array([np.pi / 2, 0.0]), (-2.0, -2.0, 6.0, 2.0), np.zeros((0, 2)))
    xy = np.array([[0.0, 1.5], [1.0, 2.0], [3.9, 0.2], [2.0, 0.0]])
    expected = np.array([
        [0.5, np.hypot(3.5, 1.0)],  # above the turned box's end (world y extent 1); off box 1's corner (3.5, 0.5)
        [np.hypot(0.5, 1.0), np.hypot(2.5, 1.5)],  # off the turned box's corner (0.5, 1)
        [3.4, -0.3],  # inside box 1, 0.3 m from its top face
        [1.5, 1.5],  # between both: 1.5 m from each face
    ])  # fmt: skip
    np.testing.assert_allclose(box_distances(world, xy), expected, atol=1e-12)
    np.testing.assert_allclose(box_signed_distance(world, xy), expected.min(axis=1), atol=1e-12)
