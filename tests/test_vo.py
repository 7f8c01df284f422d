"""Visual odometry over frames (jaxquad.vo): known motion, degenerate scenes, restarts, vmap."""

from __future__ import annotations

import dataclasses
import functools
import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation
from test_icp import CORRIDOR, R_WORLD_CAM0, ROOM, K, _pose, _render

from jaxquad.vo import VoInputs, VoParams, run

T_BASE_CAM = np.eye(4)
T_BASE_CAM[:3, :3], T_BASE_CAM[:3, 3] = (
    R_WORLD_CAM0,
    [0.3, 0.0, 0.05],
)  # looking forward, base at yaw 0


def _params(coupling: str) -> VoParams:
    p = VoParams.default(K, T_BASE_CAM, coupling)
    # 40 x 30 noise-free images have 1/16 of the camera's pixels: no smoothing (see test_icp.RAW) and the
    # translation prior's weight scaled by 1/16, so that it weighs against the points as on the camera.
    icp = dataclasses.replace(p.icp, smooth_radius=0, trans_prior_weight=p.icp.trans_prior_weight / 16)
    return dataclasses.replace(p, icp=icp, min_inliers=jnp.asarray(50.0), iterations=(4, 6))


@functools.cache
def _run(coupling: str):
    return jax.jit(jax.vmap(functools.partial(run, _params(coupling))))


def _sequence(T_world_base: list[np.ndarray], boxes, floor=0.0, blank=()) -> VoInputs:
    depth = [
        np.zeros((30, 40), np.float32) if k in blank else np.asarray(_render(T @ T_BASE_CAM, boxes, floor))
        for k, T in enumerate(T_world_base)
    ]
    R = [np.eye(3)] + [
        T_BASE_CAM[:3, :3].T @ (a[:3, :3].T @ b[:3, :3]) @ T_BASE_CAM[:3, :3]
        for a, b in itertools.pairwise(T_world_base)
    ]
    f = lambda x: jnp.asarray(np.stack(x), jnp.float32)
    return VoInputs(depth=f(depth), R_prev_cur_gyro=f(R), T_world_base_leg=f(T_world_base))


def _walk(n: int, rng) -> list[np.ndarray]:
    """Base poses of a robot walking forward 4 cm per frame and turning, with a little noise."""
    out = [_pose([0, 0, 0], [0.0, 0.0, 0.3])]
    for _ in range(n - 1):
        out.append(
            out[-1]
            @ _pose(
                [0.0, 0.0, 0.02] + rng.normal(0, 0.005, 3),
                [0.04, 0.0, 0.0] + rng.normal(0, 0.005, 3),
            )
        )
    return out


def _stack(*seqs: VoInputs) -> VoInputs:
    return jax.tree.map(lambda *x: jnp.stack(x), *seqs)


def test_known_motion_is_recovered_and_leg_errors_are_corrected():
    rng = np.random.default_rng(0)
    truth = _walk(6, rng)
    exact = _sequence(truth, ROOM)
    # The leg odometry overestimates every step by 20 % of a 4 cm step: the depth alignment corrects it.
    legs = [truth[0]]
    for a, b in itertools.pairwise(truth):
        d = np.linalg.inv(a) @ b
        d[:3, 3] *= 1.2
        legs.append(legs[-1] @ d)
    biased = eqx.tree_at(lambda x: x.T_world_base_leg, exact, jnp.asarray(np.stack(legs), jnp.float32))
    out = _run("guess+restart")(_stack(exact, biased))
    assert not np.any(np.asarray(out.tracking_lost))
    for r in range(2):
        for k, T in enumerate(truth):
            got = np.asarray(out.T_world_base[r, k], np.float64)
            assert np.linalg.norm(got[:3, 3] - T[:3, 3]) < 5e-3, (r, k)
            assert np.linalg.norm(Rotation.from_matrix(got[:3, :3].T @ T[:3, :3]).as_rotvec()) < 3e-3
    assert np.linalg.norm(legs[-1][:3, 3] - truth[-1][:3, 3]) > 0.03  # the leg odometry alone is off
    info = np.asarray(out.information[0, -1], np.float64)
    assert np.all(np.linalg.eigvalsh(info) > 0)  # a covariance exists


def test_restart_uses_the_leg_odometry_pose():
    truth = _walk(5, np.random.default_rng(1))
    # Frame 2 has no valid pixel: tracking is lost there, and at frame 3 (the blank frame was the keyframe).
    seq = _sequence(truth, ROOM, blank=(2,))
    restart = _run("guess+restart")(_stack(seq))
    off = _run("off")(_stack(seq))
    for out in (restart, off):
        np.testing.assert_array_equal(np.asarray(out.tracking_lost[0]), [False, False, True, True, False])
    # guess+restart: the pose at the lost frame is the last good pose moved by the leg odometry.
    for k in (2, 3, 4):
        np.testing.assert_allclose(np.asarray(restart.T_world_base[0, k]), truth[k], atol=5e-3)
    # off (RTAB-Map's default): the last pose is held, so the motion of the lost frame is missed.
    np.testing.assert_allclose(
        np.asarray(off.T_world_base[0, 2]),
        np.asarray(off.T_world_base[0, 1]),
        atol=1e-6,
    )
    assert np.linalg.norm(np.asarray(off.T_world_base[0, 4, :3, 3]) - truth[4][:3, 3]) > 0.05


def test_corridor_is_flagged_as_degenerate():
    truth = [_pose([0, 0, 0], [0.04 * k, 0.0, 0.3]) for k in range(3)]
    out = _run("guess+restart")(_stack(_sequence(truth, CORRIDOR, floor=-100.0)))
    assert np.all(np.asarray(out.tracking_lost[0, 1:]))
    assert np.all(np.asarray(out.min_eig[0, 1:]) < float(_params("guess+restart").min_eig))
    # Lost on every frame, the pose follows the leg odometry (here exact).
    np.testing.assert_allclose(np.asarray(out.T_world_base[0, -1]), truth[-1], atol=1e-4)


def test_tilt_prior_holds_roll_and_pitch_against_a_biased_gyro():
    # The gyro reads 0.5 deg per frame too much pitch; the leg odometry's attitude (gravity) is exact. With
    # a stiff gyro prior the chained rotations follow the gyro, unless the tilt prior holds world up.
    truth = _walk(8, np.random.default_rng(2))
    seq = _sequence(truth, ROOM)
    bias = Rotation.from_rotvec([np.deg2rad(0.5), 0.0, 0.0]).as_matrix()  # about camera x: pitch
    R = np.asarray(seq.R_prev_cur_gyro, np.float64) @ bias
    R[0] = np.eye(3)
    seq = eqx.tree_at(lambda x: x.R_prev_cur_gyro, seq, jnp.asarray(R, jnp.float32))
    fn = jax.jit(jax.vmap(run, in_axes=(None, 0)))

    def tilt_error_deg(tilt_weight):
        p = _params("guess+restart")
        p = eqx.tree_at(
            lambda q: (q.icp.rot_prior_weight, q.icp.tilt_prior_weight),
            p,
            (jnp.asarray(1e7, jnp.float32), jnp.asarray(tilt_weight, jnp.float32)),
        )
        T = np.asarray(fn(p, _stack(seq)).T_world_base[0, -1], np.float64)
        up_est, up_true = T[2, :3], truth[-1][2, :3]  # world z in the base frame
        return np.degrees(np.arccos(np.clip(up_est @ up_true, -1.0, 1.0)))

    free, held = tilt_error_deg(0.0), tilt_error_deg(1e7)
    assert free > 2.0, free  # ~0.5 deg per frame accumulated
    assert held < 0.25 * free, (held, free)
