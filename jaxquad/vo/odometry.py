"""Depth-inertial visual odometry for one robot, guided and restarted by leg odometry.

Each depth frame is aligned to a keyframe by `kernels.icp.align` (projective point-to-plane ICP,
coarse to fine, on edge-aware smoothed depth) with the gyro's integrated rotation since the previous
frame as a rotation prior and world up from the leg odometry's attitude (roll and pitch from gravity)
as a tilt prior.
The initial guess of the frame's motion depends on the coupling (static, `VoParams.coupling`):

  off            the previous frame's motion repeated, its rotation replaced by the gyro's (a
                 constant-velocity guess, as RTAB-Map's odometry makes by default); on loss,
                 restart from the last pose (RTAB-Map's default reset).
  guess          the leg odometry's motion since the previous frame is the initial guess and, with
                 weight `IcpParams.trans_prior_weight`, a translation prior (it then holds the
                 directions the geometry leaves free: corridors, open floor); on loss, as `off`.
  guess+restart  as `guess`, and on loss restart from the last good pose moved by the leg
                 odometry's motion since that frame (as the paper does).

The tilt prior (`IcpParams.tilt_prior_weight`) reads world up from the attitude of the pose given as
`T_world_base_leg` (the estimator's IMU attitude) in every coupling, `off` included: it is the IMU's
gravity, not the legs' motion.

A frame is lost when the alignment has too few inliers, a badly conditioned normal matrix (its
smallest eigenvalue per inlier below `min_eig`), or a large residual. A lost frame becomes the new
keyframe at the restart pose; a tracked frame becomes the keyframe when its overlap with the
keyframe (inliers over the keyframe's points with normals) falls below `keyframe_overlap`.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.kernels.icp import DepthLevel, IcpParams, align, depth_frame

COUPLINGS = ("off", "guess", "guess+restart")


class VoParams(eqx.Module):
    """Tunable numbers and the camera calibration (traced leaves); coupling and iteration counts
    (static: they select code)."""

    icp: IcpParams
    min_inliers: Float[Array, ""]  # fewer inliers at the finest level: lost
    min_eig: Float[Array, ""]  # smaller eigenvalue of the per-inlier normal matrix: lost (degenerate)
    max_rmse: Float[Array, ""]  # larger point-to-plane RMS residual (m): lost
    keyframe_overlap: Float[Array, ""]  # inliers / keyframe normals below this: new keyframe
    sigma_floor: Float[Array, ""]  # lower bound of the residual scale in the information, m
    K: Float[Array, "3 3"]
    T_base_camera: Float[Array, "4 4"]
    coupling: str = eqx.field(static=True, default="guess+restart")
    iterations: tuple[int, ...] = eqx.field(static=True, default=(2, 4, 6))  # Gauss-Newton steps, finest level first

    def __check_init__(self):
        if self.coupling not in COUPLINGS:
            raise ValueError(f"coupling must be one of {COUPLINGS}, got {self.coupling!r}")

    @classmethod
    def default(cls, K, T_base_camera, coupling: str = "guess+restart") -> VoParams:
        f = lambda x: jnp.asarray(x, jnp.float32)
        return cls(
            icp=IcpParams.default(),
            min_inliers=f(300.0),
            min_eig=f(2e-3),
            max_rmse=f(0.03),
            keyframe_overlap=f(0.6),
            sigma_floor=f(0.005),
            K=f(K),
            T_base_camera=f(T_base_camera),
            coupling=coupling,
        )


class VoInputs(eqx.Module):
    """One depth frame and what the other sensors say about the motion since the previous one (leading
    axes B: frames, robots, when stacked for scan or vmap)."""

    depth: Float[Array, "*B H W"]  # z-depth, m, 0 = invalid
    R_prev_cur_gyro: Float[Array, "*B 3 3"]  # camera rotation from the previous frame, integrated gyro
    T_world_base_leg: Float[Array, "*B 4 4"]  # leg-odometry pose at this frame


class VoState(eqx.Module):
    keyframe: tuple[DepthLevel, ...]
    T_world_kf: Float[Array, "4 4"]  # keyframe camera pose
    T_kf_cur: Float[Array, "4 4"]  # last frame's camera in the keyframe
    T_prev_cur: Float[Array, "4 4"]  # last frame-to-frame camera motion (the constant-velocity guess)
    T_world_base_leg: Float[Array, "4 4"]  # leg-odometry pose at the last frame
    T_world_cam_good: Float[Array, "4 4"]  # camera pose of the last tracked frame
    T_world_base_leg_good: Float[Array, "4 4"]  # leg-odometry pose at that frame


class VoOutput(eqx.Module):
    T_world_base: Float[Array, "4 4"]
    information: Float[Array, "6 6"]  # of T_kf_cur under a left perturbation (v, omega), 1/m^2, 1/rad^2
    n_inliers: Float[Array, ""]
    min_eig: Float[Array, ""]
    rmse: Float[Array, ""]  # m
    tracking_lost: Bool[Array, ""]  # the pose was restarted (see the coupling)
    new_keyframe: Bool[Array, ""]


def _inv(T: Float[Array, "4 4"]) -> Float[Array, "4 4"]:
    R, t = T[:3, :3], T[:3, 3]
    return jnp.eye(4, dtype=T.dtype).at[:3, :3].set(R.T).at[:3, 3].set(-R.T @ t)


def init(params: VoParams, depth: Float[Array, "H W"], T_world_base: Float[Array, "4 4"]) -> VoState:
    """Start at the first frame, at `T_world_base` (the leg odometry's pose there)."""
    T_world_cam = T_world_base @ params.T_base_camera
    eye = jnp.eye(4, dtype=T_world_cam.dtype)
    kf = depth_frame(depth, params.K, len(params.iterations), params.icp)
    return VoState(
        keyframe=kf,
        T_world_kf=T_world_cam,
        T_kf_cur=eye,
        T_prev_cur=eye,
        T_world_base_leg=T_world_base,
        T_world_cam_good=T_world_cam,
        T_world_base_leg_good=T_world_base,
    )


def _select(c, a, b):
    return jax.tree.map(lambda x, y: jnp.where(c, x, y), a, b)


def step(params: VoParams, state: VoState, inputs: VoInputs) -> tuple[VoState, VoOutput]:
    T_bc = params.T_base_camera
    cur = depth_frame(inputs.depth, params.K, len(params.iterations), params.icp)
    leg_prev_cur = _inv(T_bc) @ _inv(state.T_world_base_leg) @ inputs.T_world_base_leg @ T_bc
    if params.coupling == "off":
        motion = state.T_prev_cur.at[:3, :3].set(inputs.R_prev_cur_gyro)
        icp_params = eqx.tree_at(
            lambda p: p.trans_prior_weight,
            params.icp,
            jnp.zeros_like(params.icp.trans_prior_weight),
        )
    else:
        motion, icp_params = leg_prev_cur, params.icp
    T_init = state.T_kf_cur @ motion
    T_guess = T_init.at[:3, :3].set(state.T_kf_cur[:3, :3] @ inputs.R_prev_cur_gyro)
    # World up in the keyframe (its tracked pose) and in this frame (the leg odometry's attitude, whose
    # roll and pitch come from gravity): the tilt prior keeps the frame-to-frame rotations from drifting.
    up = jnp.stack([state.T_world_kf[2, :3], (inputs.T_world_base_leg[:3, :3] @ T_bc[:3, :3])[2]])
    aln = align(state.keyframe, cur, params.K, T_init, T_guess, icp_params, params.iterations, up)

    ok = jnp.all(jnp.isfinite(aln.T_ref_cur)) & jnp.isfinite(aln.min_eig)
    lost = ~ok | (aln.n_inliers < params.min_inliers) | (aln.min_eig < params.min_eig) | (aln.rmse > params.max_rmse)
    T_world_prev = state.T_world_kf @ state.T_kf_cur
    T_tracked = state.T_world_kf @ jnp.where(ok, aln.T_ref_cur, T_init)
    if params.coupling == "guess+restart":
        T_restart = (
            state.T_world_cam_good @ _inv(T_bc) @ _inv(state.T_world_base_leg_good) @ inputs.T_world_base_leg @ T_bc
        )
    else:
        T_restart = T_world_prev
    T_world_cam = jnp.where(lost, T_restart, T_tracked)
    n_kf = jnp.sum(state.keyframe[0].normal_ok.astype(aln.n_inliers.dtype))
    new_kf = lost | (aln.n_inliers < params.keyframe_overlap * n_kf)
    eye = jnp.eye(4, dtype=T_world_cam.dtype)
    new_state = VoState(
        keyframe=_select(new_kf, cur, state.keyframe),
        T_world_kf=jnp.where(new_kf, T_world_cam, state.T_world_kf),
        T_kf_cur=jnp.where(new_kf, eye, jnp.where(ok, aln.T_ref_cur, T_init)),
        T_prev_cur=jnp.where(lost, eye, _inv(T_world_prev) @ T_world_cam),
        T_world_base_leg=inputs.T_world_base_leg,
        T_world_cam_good=jnp.where(lost, state.T_world_cam_good, T_world_cam),
        T_world_base_leg_good=jnp.where(lost, state.T_world_base_leg_good, inputs.T_world_base_leg),
    )
    sigma2 = jnp.maximum(aln.rmse, params.sigma_floor) ** 2
    out = VoOutput(
        T_world_base=T_world_cam @ _inv(T_bc),
        information=aln.H_total / sigma2,
        n_inliers=aln.n_inliers,
        min_eig=aln.min_eig,
        rmse=aln.rmse,
        tracking_lost=lost,
        new_keyframe=new_kf,
    )
    return new_state, out


def run(params: VoParams, inputs: VoInputs) -> VoOutput:
    """Odometry over a sequence of frames (leading axis F) of one robot: the first frame sets the
    origin at its leg-odometry pose; outputs for every frame (the first: tracked, at that pose)."""
    first = jax.tree.map(lambda x: x[0], inputs)
    state = init(params, first.depth, first.T_world_base_leg)
    _, out = jax.lax.scan(lambda s, x: step(params, s, x), state, inputs)
    return out
