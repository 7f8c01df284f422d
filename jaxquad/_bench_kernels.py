"""Kernel section of `jaxquad bench`: contact observer step and leg twist (together and alone), and the
three scans on 640 x 480 depth with a 30-row band, for one robot and vmapped batches.

Batch 1 is the plain single-robot call (no vmap); larger batches vmap the same function over
independent random inputs. A single call pays a fixed dispatch and launch cost; the
"observer+twist, scanned" row runs 100 steps inside one `lax.scan`, as the estimator does over
time, and reports the time per step. Inputs are random but well-formed: nv = 18 (Go2-like floating base plus
12 joints), 4 feet, dt = 5 ms; depth uniform in 0.3-9 m with 5% invalid (zero) pixels.
"""

from __future__ import annotations

import argparse

_NV = 18
_N_FEET = 4
_DT = 0.005
_IMAGE = (480, 640)
_BAND = 30
_INTRINSICS = (348.0, 348.0, 319.5, 239.5)  # D435i-like at 640 x 480
_SCAN_STEPS = 100


def add_arguments(parser) -> None:
    parser.add_argument("--repeats", type=int, default=20, help="steady calls timed per kernel (median)")


def _observer_inputs(key, batch: int | None):
    import jax
    import jax.numpy as jnp

    from jaxquad.kernels import ContactObserver, ObserverParams

    shape = () if batch is None else (batch,)
    k = jax.random.split(key, 7)
    params = ObserverParams.paper(_N_FEET)
    observer = ContactObserver()
    p0 = jax.random.normal(k[0], shape + (_NV,))
    init = observer.init if batch is None else jax.vmap(observer.init, in_axes=(None, 0, None))
    state = init(params, p0, _N_FEET)
    step_in = dict(
        p=p0 + 0.01 * jax.random.normal(k[1], shape + (_NV,)),
        tau_bar=jax.random.normal(k[2], shape + (_NV,)),
        J_z=0.3 * jax.random.normal(k[3], shape + (_N_FEET, _NV)),
    )
    legs = dict(
        p_base_foot=jnp.array([0.19, 0.14, -0.27]) * jnp.array([[1, 1, 1], [1, -1, 1], [-1, 1, 1], [-1, -1, 1]])
        + 0.03 * jax.random.normal(k[4], shape + (_N_FEET, 3)),
        v_base_foot=0.5 * jax.random.normal(k[5], shape + (_N_FEET, 3)),
        omega_imu=jax.random.normal(k[6], shape + (3,)),
    )
    return observer, params, state, step_in, legs


def _kernels(key, batch: int | None) -> dict:
    """name -> (function of one robot, its arguments, the vmap in_axes of those arguments, steps per call)."""
    import jax
    import jax.numpy as jnp

    from jaxquad.kernels import baseline_scan, body_twist, level_scan, stabilized_scan

    observer, params, state, step_in, legs = _observer_inputs(key, batch)

    def observer_step(params, state, p, tau_bar, J_z):
        return observer.step(params, state, p, tau_bar, J_z, _DT)

    def observer_twist(params, state, p, tau_bar, J_z, p_base_foot, v_base_foot, omega_imu):
        state, estimate = observer.step(params, state, p, tau_bar, J_z, _DT)
        return state, body_twist(p_base_foot, v_base_foot, omega_imu, estimate.contact_soft)

    def observer_twist_scanned(params, state, p, tau_bar, J_z, p_base_foot, v_base_foot, omega_imu):
        # Every step gets its own inputs (scaled per step), so nothing can be hoisted out of the loop.
        def step(state, scale):
            state, _ = observer_twist(
                params, state, scale * p, scale * tau_bar, scale * J_z, scale * p_base_foot, scale * v_base_foot,
                scale * omega_imu,
            )  # fmt: skip
            return state, None

        return jax.lax.scan(step, state, 1.0 + 1e-3 * jnp.arange(_SCAN_STEPS, dtype=p.dtype))[0]

    def twist(p_base_foot, v_base_foot, omega_imu):
        return body_twist(p_base_foot, v_base_foot, omega_imu, jnp.ones(_N_FEET))

    shape = () if batch is None else (batch,)
    k_depth, k_holes, k_angles = jax.random.split(jax.random.fold_in(key, 1), 3)
    depth = jax.random.uniform(k_depth, shape + _IMAGE, minval=0.3, maxval=9.0)
    depth = jnp.where(jax.random.uniform(k_holes, depth.shape) < 0.05, 0.0, depth)
    roll, pitch = 0.15 * jax.random.normal(k_angles, (2,) + shape)

    obs = (params, state, step_in["p"], step_in["tau_bar"], step_in["J_z"])
    obs_axes = (None, 0, 0, 0, 0)
    leg = (legs["p_base_foot"], legs["v_base_foot"], legs["omega_imu"])
    return {
        "observer+twist": (observer_twist, obs + leg, obs_axes + (0, 0, 0), 1),
        "observer+twist, scanned": (observer_twist_scanned, obs + leg, obs_axes + (0, 0, 0), _SCAN_STEPS),
        "observer": (observer_step, obs, obs_axes, 1),
        "twist": (twist, leg, (0, 0, 0), 1),
        "stabilized_scan": (
            lambda d, r, p: stabilized_scan(d, _INTRINSICS, r, p, _BAND), (depth, roll, pitch), (0, 0, 0), 1
        ),
        "baseline_scan": (lambda d: baseline_scan(d, _INTRINSICS, _BAND), (depth,), (0,), 1),
        "level_scan": (lambda d, r, p: level_scan(d, _INTRINSICS, r, p, _BAND), (depth, roll, pitch), (0, 0, 0), 1),
    }


def run(args: argparse.Namespace) -> dict:
    import jax

    from jaxquad.bench import time_jitted

    repeats = getattr(args, "repeats", 20)
    if repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {repeats}")
    rows = []
    for batch in args.batch:
        key = jax.random.key(batch)
        single = batch == 1
        for name, (fn, fn_args, in_axes, steps) in _kernels(key, None if single else batch).items():
            jitted = jax.jit(fn if single else jax.vmap(fn, in_axes=in_axes))
            compile_s, run_ms = time_jitted(jitted, *fn_args, repeats=repeats)
            run_ms /= steps  # per step
            rows.append(
                {
                    "kernel": name,
                    "batch": batch,
                    "compile_s": round(compile_s, 4),
                    "run_ms": round(run_ms, 4),
                    "per_robot_us": round(1e3 * run_ms / batch, 3),
                    "throughput_per_s": round(batch / (run_ms * 1e-3), 1),
                }
            )
        del fn_args  # release a large depth batch before the next size
    return {"rows": rows, "nv": _NV, "n_feet": _N_FEET, "image": f"{_IMAGE[1]}x{_IMAGE[0]}", "band_rows": _BAND}
