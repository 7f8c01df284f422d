"""Route follower: a kinematic robot driven by its commands converges onto a looping route."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxquad.sim.route_follow import RouteParams, route_init, route_step

SQUARE = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0], [0.0, 3.0]], np.float32)


def _dist_to_loop(p, wp):
    """Distance from a point to the closed polyline (NumPy reference)."""
    best = np.inf
    for i in range(len(wp)):
        a, b = wp[i], wp[(i + 1) % len(wp)]
        u = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
        best = min(best, np.linalg.norm(p - (a + u * (b - a))))
    return best


def _drive(params, pose0, wp, steps, dt=0.02):
    """Integrate the body-frame commands of the follower (NumPy kinematics, holonomic base)."""
    step = jax.jit(route_step)
    state = route_init(jnp.asarray(wp), jnp.asarray(pose0[:2]))
    pose = np.array(pose0, np.float64)
    track = []
    for _ in range(steps):
        state, (cmd, valid) = step(params, state, jnp.asarray(wp), jnp.asarray(pose, jnp.float32))
        assert bool(valid)
        vx, vy, wz = np.asarray(cmd, np.float64)
        c, s = np.cos(pose[2]), np.sin(pose[2])
        pose += dt * np.array([c * vx - s * vy, s * vx + c * vy, wz])
        track.append(pose.copy())
    return np.array(track), state


def test_converges_onto_square_loop_and_laps():
    params = RouteParams.default(v_max=0.5)
    track, state = _drive(params, (1.0, -1.0, 2.5), SQUARE, 3000)  # 60 s, starting off the route
    late = track[1000:]
    dist = np.array([_dist_to_loop(p[:2], SQUARE) for p in late[::10]])
    assert dist.max() < 0.3  # corners are cut by about the look-ahead
    assert np.median(dist) < 0.05
    assert int(state.laps) >= 2  # perimeter 14 m at 0.5 m/s: a little over two laps in 60 s
    # Counter-clockwise order is followed: the heading on the first edge points along +x.
    on_first = late[(np.abs(late[:, 1]) < 0.05) & (late[:, 0] > 1.0) & (late[:, 0] < 3.0)]
    assert len(on_first) > 0 and np.all(np.cos(on_first[:, 2]) > 0.9)


def test_vmapped_matches_single_and_bad_pose_flagged():
    params = RouteParams.default()
    wp = jnp.asarray(SQUARE)
    poses = jnp.array([[1.0, 0.5, 0.0], [3.0, 2.0, 1.0], [jnp.nan, 0.0, 0.0]])
    states = jax.vmap(route_init, in_axes=(None, 0))(wp, jnp.nan_to_num(poses[:, :2]))
    new, (cmd, valid) = jax.jit(jax.vmap(route_step, in_axes=(None, 0, None, 0)))(params, states, wp, poses)
    single = jax.jit(route_step)
    for i in range(2):
        s_i = jax.tree.map(lambda x, i=i: x[i], states)
        n_i, (c_i, v_i) = single(params, s_i, wp, poses[i])
        np.testing.assert_allclose(cmd[i], c_i, atol=1e-6)
        assert bool(v_i) and int(new.target[i]) == int(n_i.target)
    assert not bool(valid[2])
    np.testing.assert_array_equal(np.asarray(cmd[2]), 0.0)
    assert int(new.target[2]) == int(states.target[2])
    assert np.all(np.abs(np.asarray(cmd[:2, 2])) <= float(params.yaw_rate_max) + 1e-6)
