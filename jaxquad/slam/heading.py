"""Wall-direction heading priors for the online SLAM (`SlamSpec.wall_heading`), one new node at a time.

The graph's heading otherwise drifts with the leg odometry's (the IMU's yaw, a random walk) between loop closures,
and in a hall of long aisles closures are few. Each new node's scan is measured against the map's wall directions
(`kernels.wall_heading`): the map's direction spectrum is the sum of the node scans' spectra, each kept in its
node's frame and turned by the node's current heading (`map_spectrum`), so loop closures that move the nodes move
their directions with them. A measurement is used when its quality reaches `heading_min_quality` and it agrees with
the node's heading as known: error^2 / (P + `heading_min_std`^2) at most `heading_max_chi2`. R is left out of that
test (`heading_gate_with_r` puts it back): a measurement's large errors are wrong associations, not noise. A box
turned a few degrees off the walls, seen where the map has no direction of its own, is lined up with the nearest
mapped wall direction; a scan with few straight returns claims a wide R, and with R in the test such a match, 4-10
deg off, passed and turned the heading. On 64 scripted 300 s warehouse walks (`experiments/heading_replay.py`) the
heading passed 4 deg in 9 runs with this gate, 15 with R in it and 28 without priors.

The gate cannot see a wrong association that lies within the heading's own uncertainty, and the same box seen
from consecutive nodes pulls the heading the same way each time. With `heading_halves_tolerance` > 0 the scan is
also measured in two halves, its straight returns split at their median range (`kernels.wall_heading.
halves_disagreement`): a box in front of a wall is measured by the near half and the wall by the far one, and a
scan whose halves disagree by more than the tolerance is not used. At the true poses of 8 scripted 300 s warehouse
walks (`experiments/heading_association.py`) a tolerance of 2 deg left out 14 % of the measurements and cut those
more than 4 deg off from 157 to 83 (of 3,375).

R, the measurement's variance, is `heading_variance_scale` over the scan's summed direction weights (its
walls' information) plus `heading_min_std`^2. The returns' fits overlap and the walls' faces are not ideal
lines, so the weights overstate the information: on simulated depth scans (noise 1 % of r^2; warehouse and
house, 1- and 5-row bands, at the true poses) the error times the square root of the summed weights had an
rms of 5.4-7.0 rad: a scale of 50 would give a mean chi-square of 0.6-1.0. The default, 100, allows for
consecutive nodes' measurements sharing their walls' errors: on 8 Go2 route walks of 300 s in the warehouse
(1-row scans, loop closures off) the final position error was 0.26 m with 100 and 0.32 m with 50.

P, the variance of a node's heading in the map frame, grows from the last node's by the new node's link variance
and shrinks with each measurement used, as a scalar Kalman filter would; the node's heading moves by the gain
P / (P + R) times the error, and the measurement enters the graph as an edge from node 0 (held fixed) with
information on the heading alone, so later optimizations keep it. Loop closures leave P as it was (an upper
bound). Each node keeps its P (`node_heading_var`) and its prior's 1/R (`node_heading_info`, 0 where none was
used), which the loop-closure test's chain filter reads (`jaxquad.slam.consistency`).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.kernels.control_flow import run_if
from jaxquad.kernels.lie import wrap_angle
from jaxquad.kernels.wall_heading import (
    direction_spectrum,
    halves_disagreement,
    measure_heading,
    rotate_spectrum,
    wall_directions,
)
from jaxquad.slam.state import SlamInputs, SlamParams, SlamSpec, SlamState

# A half of a scan measures its error with at least this quality to be compared (below, it saw too little).
HALVES_MIN_QUALITY = 0.3


def map_spectrum(spec: SlamSpec, state: SlamState) -> Float[Array, "k 2"]:
    """The map's wall-direction spectrum: every node's, turned by its heading now."""
    g = state.graph
    turned = rotate_spectrum(spec.heading, state.node_directions, g.poses[:, 2])
    return jnp.sum(jnp.where(g.node_mask[:, None, None], turned, 0.0), axis=0)


def update(
    spec: SlamSpec,
    params: SlamParams,
    state: SlamState,
    pose: Float[Array, "3"],
    step_var: Float[Array, ""],
    inp: SlamInputs,
    first: Bool[Array, ""],
):
    """A new node's heading corrected by the walls.

    Returns (pose, heading variance, the scan's spectrum in the base frame (the node's `node_directions`), the
    node at its measured heading and the prior's information, whether it is used, the measured error (rad, NaN
    when unused))."""
    laser = params.T_base_laser[2]
    direction, weight = wall_directions(spec.heading, params.heading, inp.ranges, state.bearings, inp.valid)
    last = jnp.maximum(state.n_nodes - 1, 0)
    var = jnp.where(first, 0.0, state.node_heading_var[last] + step_var)
    local = direction_spectrum(spec.heading, direction, weight, laser)
    scan = rotate_spectrum(spec.heading, local, pose[2])
    reference = map_spectrum(spec, state)
    meas = measure_heading(spec.heading, params.heading, scan, reference)
    # Two more measurements per node: only when the test is on.
    split = run_if(
        params.heading_halves_tolerance > 0,
        lambda _: halves_disagreement(
            spec.heading,
            params.heading,
            direction,
            weight,
            inp.ranges,
            pose[2] + laser,
            reference,
            jnp.asarray(HALVES_MIN_QUALITY, reference.dtype),
        ),
        jnp.zeros((), reference.dtype),
    )
    R = params.heading_variance_scale / jnp.maximum(jnp.sum(weight), 1e-9) + params.heading_min_std**2
    chi2 = meas.error**2 / (var + jnp.where(params.heading_gate_with_r, R, params.heading_min_std**2))
    used = (
        ~first
        & (meas.quality >= params.heading_min_quality)
        & (chi2 <= params.heading_max_chi2)
        & jnp.isfinite(meas.error)
        & jnp.isfinite(var)
        & ((params.heading_halves_tolerance <= 0) | (split <= params.heading_halves_tolerance))
    )
    gain = var / (var + R)
    measured = pose.at[2].set(wrap_angle(pose[2] - meas.error))
    pose = pose.at[2].set(wrap_angle(pose[2] - jnp.where(used, gain * meas.error, 0.0)))
    var = jnp.where(used, (1.0 - gain) * var, var)
    info = jnp.diag(jnp.array([0.0, 0.0, 1.0]) / R)
    return pose, var, local, measured, info, used, jnp.where(used, meas.error, jnp.nan)
