"""Foot contact from a generalized-momentum disturbance observer (paper Sec. III-A), for one robot.

Model and sign convention. With M vdot + C v + g = S^T tau + J^T f, where f is the ground-reaction
force acting *on* each foot, the generalized momentum p = M v obeys
    dp/dt = tau_bar + J^T f,        tau_bar = S^T tau + C^T v - g.
The paper writes -J^T f with f the force the foot exerts on the ground; the two are the same law
with f_here = -f_paper. Only the world-z component per foot is estimated, f_z (F,), so J enters
through its world-z rows J_z (F, nv). A foot pressing on the ground gives f_z > 0.

Observer (continuous time), residual r = p - p_hat:
    plain:  p_hat' = tau_bar + J_z^T f_hat + 2 b r,          f_hat' = b^2 P r
    mixed:  p_hat' = tau_bar + J_z^T f_hat + b k1(r),        f_hat' = b^2 P k2(r)
with k1(s) = sgn(s)|s|^(1/2) + s, k2(s) = sgn(s) + k1(s) elementwise, b the bandwidth (rad/s) and
P = (J_z J_z^T + lambda I)^-1 J_z the damped least-squares map from generalized coordinates to foot
z forces. In the plain observer the in-range error obeys y'' + 2b y' + b^2 y = 0 (critically damped).
The discontinuous sgn in k2 is smoothed as tanh(sharpness s); sgn(s)|s|^(1/2) in k1 is continuous
and is used as is.

Integrator: backward (implicit) Euler in the feedback terms. One step, inputs sampled at the new
time t_k, dt = t_k - t_{k-1}, h = b dt; tau_bar is taken as constant over the interval (so it should
be the torque held over the interval that ends at t_k). With s0 = p - p_hat - dt (tau_bar + J_z^T
f_hat), the new residual r and force increment df solve
    r + h k1(r) + dt J_z^T df = s0,        df = dt b^2 P k2(r),
then p_hat <- p - r, f_hat <- f_hat + df. For a given df the first equation is elementwise and
solved in closed form with s = s0 - dt J_z^T df (plain: r = s / (1 + 2h); mixed, with u = sgn(r)|r|^(1/2):
u = 2 s / (h + sqrt(h^2 + 4 (1 + h) |s|)), r = u |u|); df is then found by Newton's method on the
F equations (linear in plain mode, so one iteration is exact; 6 in mixed mode, which reach float32
precision in at most 5 over residuals from 1e-6 to 10; the iterations are unrolled). Each Newton
system is multiplied through by G = J_z J_z^T + lambda I (P = G^-1 J_z), giving the step
df <- df - delta with (G + dt^2 b^2 J_z D J_z^T) delta = G df - dt b^2 J_z k2(r), D = diag(dk2/ds) > 0:
a symmetric positive definite F x F system, solved by an unrolled LDL^T factorization without
pivoting; P itself is never formed. Why implicit: k1 has infinite slope at r = 0
and the sgn term of k2 moves f_hat by up to dt b^2 per step, so treating k2 explicitly chatters
(implicit k1, explicit k2 at b = 100 rad/s, dt = 5 ms: a limit cycle from -20 to 40 N around a
10 N force on one dof); backward Euler in both is stable for every h, critically damped in discrete
time in plain mode (in-range error poles at 1/(1 + h) for lambda = 0), and converges to the
continuous observer at first order in dt. The sqrt is evaluated at an argument >= h^2, so values and
gradients stay finite at zero residual.

Post-processing as in the paper: the force is clipped to [0, f_max] (the observer's own f_hat is not
clipped, which would bias its linear dynamics), smoothed per foot by f_filt = alpha f + (1 - alpha)
f_filt_prev, and compared with per-foot thresholds. Optional hysteresis: contact turns on above
threshold_on and off below threshold_off (equal thresholds = no hysteresis). The soft output
sigmoid((f_filt - threshold) / soft_temperature) uses the threshold active for the previous contact
state, so it equals sigmoid((f_filt - threshold_on) / T) without hysteresis.

A step whose inputs are not all finite (or whose dt is not positive) leaves the state unchanged and
reports valid = False; the estimate then repeats the previous one.
"""

from __future__ import annotations

from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from jaxquad.kernels._small_linalg import spd_solve

_MODES = ("plain", "mixed")
# Floor on h = b dt: keeps the implicit sqrt and its gradient finite if a sweep reaches b = 0.
_MIN_H = 1e-6
# Stand-in dt while a step is rejected, so no NaN reaches the (discarded) arithmetic or gradients.
_SAFE_DT = 1e-3
# Newton iterations for the implicit mixed-mode step; float32 convergence takes at most 5.
_NEWTON_ITERS = 6


class ObserverParams(eqx.Module):
    """Tunable numbers of the contact observer; every number is a traced leaf, `mode` is static.

    bandwidth: b (rad/s), > 0. sharpness: slope of tanh that smooths sgn in k2 (per unit of
    momentum residual). f_max: clip of the estimated force (N). alpha (F,): per-foot smoothing
    factor in (0, 1]. threshold_on / threshold_off (F,): contact thresholds on the smoothed force (N).
    soft_temperature: width of the soft contact sigmoid (N). pinv_damping: lambda of the damped
    least-squares map to foot forces (m^2, J_z rows are in m per unit of generalized velocity).
    mode: "plain" (linear high-gain) or "mixed" (high-gain + sliding-mode)."""

    bandwidth: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    sharpness: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    f_max: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    alpha: Float[Array, "F"] = eqx.field(converter=jnp.asarray)
    threshold_on: Float[Array, "F"] = eqx.field(converter=jnp.asarray)
    threshold_off: Float[Array, "F"] = eqx.field(converter=jnp.asarray)
    soft_temperature: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    pinv_damping: Float[Array, ""] = eqx.field(converter=jnp.asarray)
    mode: Literal["plain", "mixed"] = eqx.field(static=True, default="mixed")

    def __check_init__(self):
        if self.mode not in _MODES:
            raise ValueError(f"ObserverParams.mode must be one of {_MODES}, got {self.mode!r}")

    @classmethod
    def paper(
        cls, n_feet: int = 4, mode: Literal["plain", "mixed"] = "mixed", bandwidth: float = 30.0
    ) -> ObserverParams:
        """The paper's published defaults (facts.md Sec. 3): b = 30 rad/s, tanh sharpness 100,
        clip at 100 N, alpha 0.2 on front feet and 0.1 on rear feet, 1 N threshold on every foot
        (no hysteresis). Feet are ordered front before rear (FL, FR, RL, RR), so n_feet is even.
        soft_temperature 0.25 N and pinv_damping 1e-4 m^2 are this library's choices."""
        if n_feet < 2 or n_feet % 2:
            raise ValueError(f"ObserverParams.paper needs an even number of feet (front, rear), got {n_feet}")
        half = n_feet // 2
        alpha = jnp.concatenate([jnp.full(half, 0.2), jnp.full(half, 0.1)])
        return cls(
            bandwidth=jnp.asarray(bandwidth, jnp.float32),
            sharpness=jnp.asarray(100.0, jnp.float32),
            f_max=jnp.asarray(100.0, jnp.float32),
            alpha=alpha.astype(jnp.float32),
            threshold_on=jnp.full(n_feet, 1.0, jnp.float32),
            threshold_off=jnp.full(n_feet, 1.0, jnp.float32),
            soft_temperature=jnp.asarray(0.25, jnp.float32),
            pinv_damping=jnp.asarray(1e-4, jnp.float32),
            mode=mode,
        )


class ObserverState(eqx.Module):
    """Observer state between steps. p_hat: estimated generalized momentum (nv,). f_hat: unclipped
    z-force estimate per foot (N). f_filt: smoothed clipped force (N). contact: hysteresis state.
    contact_soft: last soft contact, repeated when a step is rejected."""

    p_hat: Float[Array, "nv"]
    f_hat: Float[Array, "F"]
    f_filt: Float[Array, "F"]
    contact: Bool[Array, "F"]
    contact_soft: Float[Array, "F"]


class ContactEstimate(eqx.Module):
    """Output of one step. force_z: estimate clipped to [0, f_max] (N). force_z_filtered: smoothed
    (N). contact: thresholded with hysteresis. contact_soft: differentiable contact in (0, 1).
    valid: False when this step's inputs were rejected (state held)."""

    force_z: Float[Array, "F"]
    force_z_filtered: Float[Array, "F"]
    contact: Bool[Array, "F"]
    contact_soft: Float[Array, "F"]
    valid: Bool[Array, ""]


# Products of these tiny matrices avoid dot ops, which under vmap are separate batched-matmul calls
# (and may run in TF32 on a GPU at the default matmul precision): sums over the few feet are unrolled
# into elementwise multiply-adds, sums over the dofs are a broadcast product and one reduction; both
# fuse with the elementwise code around them and stay in full float32.
def _combine(columns: Float[Array, "F n"], weights: Float[Array, "F"]) -> Float[Array, "n"]:
    """sum_f weights[f] columns[f], unrolled over the static F."""
    return sum((columns[f] * weights[f] for f in range(1, weights.shape[0])), columns[0] * weights[0])


def _rows_dot(a: Float[Array, "m n"], b: Float[Array, "k n"]) -> Float[Array, "m k"]:
    """a b^T."""
    return jnp.sum(a[:, None, :] * b[None, :, :], axis=-1)


def _residual_and_k2(
    s: Float[Array, "nv"], h: Float[Array, ""], sharpness: Float[Array, ""], mode: str
) -> tuple[Float[Array, "nv"], Float[Array, "nv"], Float[Array, "nv"]]:
    """Solve r + h k1(r) = s elementwise in closed form; return (r, k2(r), d k2(r(s)) / ds), all
    smooth in s (the slope is written out, not differentiated, so it shares the root's arithmetic)."""
    if mode == "plain":
        r = s / (1.0 + 2.0 * h)
        return r, r, jnp.broadcast_to(1.0 / (1.0 + 2.0 * h), s.shape)
    # u = |r|^(1/2) solves (1 + h) u^2 + h u - |s| = 0; rationalised root, no cancellation at small s,
    # and a sqrt argument >= h^2 keeps the derivative finite (1/h) at s = 0.
    q = jnp.sqrt(h * h + 4.0 * (1.0 + h) * jnp.abs(s))
    root = 2.0 * s / (h + q)
    r = root * jnp.abs(root)
    tanh = jnp.tanh(sharpness * r)
    # (1 + h) r + h root = s gives d root/ds = 1 / (h + 2 (1 + h) |root|) = 1 / q, d r/ds = 2 |root| / q.
    slope = ((sharpness * (1.0 - tanh * tanh) + 1.0) * 2.0 * jnp.abs(root) + 1.0) / q
    return r, tanh + root + r, slope


def _postprocess(
    params: ObserverParams, force: Float[Array, "F"], f_filt_prev: Float[Array, "F"], contact_prev: Bool[Array, "F"]
) -> tuple[Float[Array, "F"], Bool[Array, "F"], Float[Array, "F"]]:
    """Smooth the clipped force, threshold it with hysteresis, and give the soft contact."""
    f_filt = params.alpha * force + (1.0 - params.alpha) * f_filt_prev
    threshold = jnp.where(contact_prev, params.threshold_off, params.threshold_on)
    contact = f_filt > threshold
    soft = jax.nn.sigmoid((f_filt - threshold) / params.soft_temperature)
    return f_filt, contact, soft


class ContactObserver(eqx.Module):
    """Pure init/step of the contact observer for one robot; vmap over robots or params outside,
    `lax.scan` over time."""

    def init(self, params: ObserverParams, p0: Float[Array, "nv"], n_feet: int) -> ObserverState:
        """State at rest: p_hat = p0 (the first measured momentum), zero force, no contact."""
        p0 = jnp.asarray(p0)
        if p0.ndim != 1:
            raise ValueError(f"p0 must have shape (nv,), got {p0.shape}")
        if params.alpha.shape != (n_feet,):
            raise ValueError(f"params are for {params.alpha.shape} feet, init was given n_feet={n_feet}")
        dtype = jnp.result_type(p0.dtype, jnp.float32)
        zeros = jnp.zeros(n_feet, dtype)
        return ObserverState(
            p_hat=p0.astype(dtype), f_hat=zeros, f_filt=zeros, contact=jnp.zeros(n_feet, bool), contact_soft=zeros
        )

    def step(
        self,
        params: ObserverParams,
        state: ObserverState,
        p: Float[Array, "nv"],
        tau_bar: Float[Array, "nv"],
        J_z: Float[Array, "F nv"],
        dt: float | Float[Array, ""],
    ) -> tuple[ObserverState, ContactEstimate]:
        """Advance one sample. p = M v (generalized momentum), tau_bar = S^T tau + C^T v - g,
        J_z = world-z rows of the foot point Jacobians, all at the new sample time; dt in s."""
        nv, n_feet = state.p_hat.shape[0], state.f_hat.shape[0]
        if p.shape != (nv,) or tau_bar.shape != (nv,) or J_z.shape != (n_feet, nv):
            raise ValueError(
                f"expected p ({nv},), tau_bar ({nv},), J_z ({n_feet}, {nv}); "
                f"got {p.shape}, {tau_bar.shape}, {J_z.shape}"
            )
        dt = jnp.asarray(dt, state.p_hat.dtype)
        valid = (
            jnp.all(jnp.isfinite(p))
            & jnp.all(jnp.isfinite(tau_bar))
            & jnp.all(jnp.isfinite(J_z))
            & jnp.isfinite(dt)
            & (dt > 0)
        )
        # Rejected inputs are replaced before any arithmetic so NaN cannot leak into gradients.
        p = jnp.where(valid, p, state.p_hat)
        tau_bar = jnp.where(valid, tau_bar, 0.0)
        J_z = jnp.where(valid, J_z, 0.0)
        dt = jnp.where(valid, dt, _SAFE_DT)

        h = jnp.maximum(params.bandwidth * dt, _MIN_H)
        gain = dt * params.bandwidth**2
        gram = _rows_dot(J_z, J_z) + params.pinv_damping * jnp.eye(n_feet, dtype=J_z.dtype)
        s0 = p - state.p_hat - dt * (tau_bar + _combine(J_z, state.f_hat))

        def newton(df: Float[Array, "F"]) -> Float[Array, "F"]:
            # k2(r(s)) acts elementwise: its Jacobian is the diagonal D = diag(slope).
            _, k2, slope = _residual_and_k2(s0 - dt * _combine(J_z, df), h, params.sharpness, params.mode)
            # The equation df - gain P k2 and its Jacobian I + gain dt P D J_z^T, both multiplied by
            # the gram matrix G (P = G^-1 J_z): G df - gain J_z k2 and G + gain dt J_z D J_z^T, which
            # is symmetric positive definite (D > 0), so P is never formed and no pivoting is needed.
            # J_z D J_z^T and J_z k2 from one reduction over the dofs.
            products = _rows_dot(J_z, jnp.concatenate([J_z * slope, k2[None, :]]))
            equation = _combine(gram, df) - gain * products[:, n_feet]
            jacobian = gram + gain * dt * products[:, :n_feet]
            return df - spd_solve(jacobian, equation)

        # Newton on the force increment of the implicit step, unrolled (the count is static); in
        # plain mode the equation is linear and one iteration is exact. Newton's map has zero
        # derivative in df at the solution, so differentiating only the last iteration (the earlier
        # ones held constant) gives the implicit-function derivative of the converged df, and the
        # backward pass holds one iteration instead of all of them.
        df = jnp.zeros_like(state.f_hat)
        for _ in range(0 if params.mode == "plain" else _NEWTON_ITERS - 1):
            df = newton(df)
        df = newton(jax.lax.stop_gradient(df))
        r, _, _ = _residual_and_k2(s0 - dt * _combine(J_z, df), h, params.sharpness, params.mode)
        f_hat = state.f_hat + df
        p_hat = p - r

        f_filt, contact, soft = _postprocess(params, jnp.clip(f_hat, 0.0, params.f_max), state.f_filt, state.contact)
        new = ObserverState(p_hat=p_hat, f_hat=f_hat, f_filt=f_filt, contact=contact, contact_soft=soft)
        new = jax.tree.map(lambda a, o: jnp.where(valid, a, o), new, state)
        estimate = ContactEstimate(
            force_z=jnp.clip(new.f_hat, 0.0, params.f_max),
            force_z_filtered=new.f_filt,
            contact=new.contact,
            contact_soft=new.contact_soft,
            valid=valid,
        )
        return new, estimate
