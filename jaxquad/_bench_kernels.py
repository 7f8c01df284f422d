"""Kernel section of `jaxquad bench`: contact observer step and leg twist (together and alone), and the
three scans on 640 x 480 depth with a 30-row band, for one robot and vmapped batches.

Batch 1 is the plain single-robot call (no vmap); larger batches vmap the same function over
independent random inputs. A single call pays a fixed dispatch and launch cost; the
"observer+twist, scanned" row runs 100 steps inside one `lax.scan`, as the estimator does over
time, and reports the time per step. Inputs are random but well-formed: nv = 18 (Go2-like floating base plus
12 joints), 4 feet, dt = 5 ms; depth uniform in 0.3-9 m with 5% invalid (zero) pixels.

A progress bar on stderr names the kernel being compiled and timed. Host memory stays near one
depth batch (1.3 GB at 1024 images): the images are drawn one at a time in NumPy, and each batch
size's inputs and compiled programs are freed before the next.
"""

from __future__ import annotations

import argparse

import numpy as np

_NV = 18
_N_FEET = 4
_DT = 0.005
_IMAGE = (480, 640)
_BAND = 30
_INTRINSICS = (348.0, 348.0, 319.5, 239.5)  # D435i-like at 640 x 480
_SCAN_STEPS = 100
_DEPTH_CHUNK = 64  # images drawn at a time


def add_arguments(parser) -> None:
    parser.add_argument(
        "--repeats", type=int, default=20, help="steady calls timed per kernel, at most (median; default 20)"
    )


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
        p_base_foot=jnp.array([0.19, 0.14, -0.27])
        * jnp.array([[1.0, 1.0, 1.0], [1.0, -1.0, 1.0], [-1.0, 1.0, 1.0], [-1.0, -1.0, 1.0]])
        + 0.03 * jax.random.normal(k[4], shape + (_N_FEET, 3)),
        v_base_foot=0.5 * jax.random.normal(k[5], shape + (_N_FEET, 3)),
        omega_imu=jax.random.normal(k[6], shape + (3,)),
    )
    return observer, params, state, step_in, legs


def _depth_images(seed: int, batch: int | None):
    """Depth images uniform in 0.3-9 m with 5% zero (invalid) pixels, (H, W) or (batch, H, W).

    Drawn in NumPy a chunk at a time and written into one donated JAX buffer, so host memory holds a
    single batch (jax.random over a whole batch held several batch-sized temporaries: 6.6 GB at 1024)."""
    import functools

    import jax
    import jax.numpy as jnp

    @functools.partial(jax.jit, donate_argnums=0)
    def put(images, chunk, start):
        return jax.lax.dynamic_update_slice_in_dim(images, chunk, start, 0)

    rng = np.random.default_rng(seed)
    n = 1 if batch is None else batch
    images = jnp.zeros((n,) + _IMAGE, jnp.float32)
    for start in range(0, n, _DEPTH_CHUNK):
        chunk = rng.random((min(_DEPTH_CHUNK, n - start),) + _IMAGE, dtype=np.float32)
        holes = rng.random(chunk.shape, dtype=np.float32) < 0.05
        chunk = np.where(holes, 0.0, 0.3 + (9.0 - 0.3) * chunk).astype(np.float32)
        images = put(images, chunk, start)
    return images[0] if batch is None else images


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
                params,
                state,
                scale * p,
                scale * tau_bar,
                scale * J_z,
                scale * p_base_foot,
                scale * v_base_foot,
                scale * omega_imu,
            )
            return state, None

        return jax.lax.scan(step, state, 1.0 + 1e-3 * jnp.arange(_SCAN_STEPS, dtype=p.dtype))[0]

    def twist(p_base_foot, v_base_foot, omega_imu):
        return body_twist(p_base_foot, v_base_foot, omega_imu, jnp.ones(_N_FEET))

    shape = () if batch is None else (batch,)
    k_depth, k_angles = jax.random.split(jax.random.fold_in(key, 1))
    depth = _depth_images(int(jax.random.randint(k_depth, (), 0, 2**31 - 1)), batch)
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
            lambda d, r, p: stabilized_scan(d, _INTRINSICS, r, p, _BAND),
            (depth, roll, pitch),
            (0, 0, 0),
            1,
        ),
        "baseline_scan": (lambda d: baseline_scan(d, _INTRINSICS, _BAND), (depth,), (0,), 1),
        "level_scan": (lambda d, r, p: level_scan(d, _INTRINSICS, r, p, _BAND), (depth, roll, pitch), (0, 0, 0), 1),
    }


def run(args: argparse.Namespace) -> dict:
    import gc

    import jax
    from tqdm import tqdm

    from jaxquad.bench import time_jitted

    repeats = getattr(args, "repeats", 20)
    if repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {repeats}")
    rows = []
    bar = tqdm(total=7 * len(args.batch), desc="kernels", unit="kernel", leave=False)
    for batch in args.batch:
        key = jax.random.key(batch)
        single = batch == 1
        bar.set_postfix_str(f"batch {batch}: inputs")
        kernels = _kernels(key, None if single else batch)
        for name, (fn, fn_args, in_axes, steps) in kernels.items():
            bar.set_postfix_str(f"batch {batch}: {name}")
            jitted = jax.jit(fn if single else jax.vmap(fn, in_axes=in_axes))
            compile_s, run_ms = time_jitted(jitted, *fn_args, repeats=repeats)
            run_ms /= steps  # per step
            bar.update()
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
        # Release this size's inputs (a depth batch of up to GBs) and compiled programs before the next.
        del kernels, fn_args
        jax.clear_caches()
        gc.collect()
    bar.close()
    return {"rows": rows, "nv": _NV, "n_feet": _N_FEET, "image": f"{_IMAGE[1]}x{_IMAGE[0]}", "band_rows": _BAND}
