"""A planar position and the leg odometry's velocity bias as one linear Kalman filter.

State x = [p, b]: p the robot's position in the map frame (m), b a bias of the leg odometry's planar
velocity in the base frame (m/s), constant but for a slow random walk. Between two scan-matched poses
the leg odometry reports a displacement d_world (rotated into the map frame); the bias adds G b to it,
G = R(theta) H with H = integral of R(psi(t)) dt over the interval (s; psi the heading change since the
interval began, theta the heading at its start):

    p_k = p_(k-1) + d_world - G b_(k-1) + w,   w ~ N(0, Q)
    b_k = b_(k-1) + u,                         u ~ N(0, diag(walk_var))

and a scan match measures p_k with covariance R. One match cannot tell a bias of a few mm/s from its own
noise (a few cm against a few mm over half a second); a run of them can, because the bias grows the
position error steadily and the filter keeps the correlation between the two. A match whose innovation
fails the chi-square gate is not used (a wrong match must not teach the filter a bias).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.kernels._small_linalg import spd_solve


class BiasFilter(eqx.Module):
    x: Float[Array, "4"]  # p (m, map frame), b (m/s, base frame)
    P: Float[Array, "4 4"]

    @property
    def bias(self) -> Float[Array, "2"]:
        return self.x[2:]


def bias_filter_init(p: Float[Array, "2"], bias_mean: Float[Array, "2"], bias_std: Float[Array, "2"]) -> BiasFilter:
    """A filter at position p, known exactly, with a bias of mean bias_mean and standard deviations bias_std (m/s,
    per axis; an axis of std 0 keeps its mean: a known bias)."""
    P = jnp.diag(jnp.concatenate([jnp.zeros(2), jnp.square(bias_std)]))
    return BiasFilter(x=jnp.concatenate([p, bias_mean.astype(p.dtype)]), P=P.astype(p.dtype))


def bias_predict(
    f: BiasFilter,
    d_world: Float[Array, "2"],
    G: Float[Array, "2 2"],
    Q: Float[Array, "2 2"],
    walk_var: Float[Array, "2"],
) -> BiasFilter:
    """The filter after a leg-odometry displacement d_world (m) with bias sensitivity G (s) and noise Q (m^2);
    the bias's components walk by walk_var ((m/s)^2 each)."""
    F = jnp.block([[jnp.eye(2), -G], [jnp.zeros((2, 2)), jnp.eye(2)]])
    x = jnp.concatenate([f.x[:2] + d_world - G @ f.x[2:], f.x[2:]])
    P = F @ f.P @ F.T + jnp.block([[Q, jnp.zeros((2, 2))], [jnp.zeros((2, 2)), jnp.diag(walk_var)]])
    return BiasFilter(x=x, P=0.5 * (P + P.T))


def bias_update(
    f: BiasFilter, m: Float[Array, "2"], R: Float[Array, "2 2"], gate_chi2: Float[Array, ""], use: Bool[Array, ""]
) -> tuple[BiasFilter, Float[Array, ""], Bool[Array, ""]]:
    """(filter, chi2, used): the filter after a position measurement m (m) of covariance R (m^2) when `use` and
    its innovation's chi-square (2 dof) is at most gate_chi2; else unchanged."""
    y = m - f.x[:2]
    S = f.P[:2, :2] + R
    chi2 = y @ spd_solve(S, y)
    used = use & (chi2 <= gate_chi2) & jnp.all(jnp.isfinite(y)) & jnp.all(jnp.isfinite(R))
    K = spd_solve(S, f.P[:2, :]).T  # P H^T S^-1 with H = [I 0]; S and P symmetric
    I_KH = jnp.eye(4) - jnp.concatenate([K, jnp.zeros((4, 2))], axis=1)
    P = I_KH @ f.P @ I_KH.T + K @ R @ K.T  # Joseph form: symmetric and positive in float32
    new = BiasFilter(x=f.x + K @ jnp.where(jnp.isfinite(y), y, 0.0), P=0.5 * (P + P.T))
    return BiasFilter(x=jnp.where(used, new.x, f.x), P=jnp.where(used, new.P, f.P)), chi2, used
