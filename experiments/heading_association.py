"""How often the wall-heading measurement lines a scan up with the wrong map direction, at the true poses.

    python experiments/heading_association.py [--robots 2] [--seconds 60] [--seed 0] [--every 0.5] [--skip 10]
        [--json rows.json]

The walks and scans are `heading_replay.py`'s (a drawn warehouse, a scripted path, 160-beam level scans 0.32 m above
the floor with range noise 1 % of r^2). Every `--every` s after the first `--skip` s a node's scan is measured
against the map's wall-direction spectrum built from the earlier nodes, all at their true poses
(`kernels.wall_heading`, exploration's SLAM settings), so every error the measurement reports is a wrong association
or noise: no pose error enters.
Variants of the weights (the map built with the same weights as the scan):

  inverse-variance  each straight return weighs the inverse variance of its direction (the SLAM's way)
  unit              every straight return weighs 1 (nearer returns no longer dominate)
  unit, log map     as unit, and the map's direction density compressed to log(1 + 100 d / max d) before the
                    search (a direction seen by few nodes counts nearly as much as one seen by many)
  inverse-variance, halves within 2 deg
                    the SLAM's weights, and a measurement left out when the scan's near and far halves (split
                    at the median range of its straight returns) disagree by more than 2 deg
                    (`wall_heading_halves_tolerance`, `kernels.wall_heading.halves_disagreement`)

It prints the command, the machine and one Markdown row per variant: nodes measured, measurements reaching
`wall_heading_min_quality` (the only ones the SLAM would use), and their error's rms, median and counts beyond 1,
2 and 4 deg.
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import sys
from pathlib import Path

import numpy as np

HALVES_TOLERANCE_DEG = 2.0
HALVES = f"inverse-variance, halves within {HALVES_TOLERANCE_DEG:g} deg"
VARIANTS = ("inverse-variance", "unit", "unit, log map", HALVES)
LOG_GAIN = 100.0  # log(1 + LOG_GAIN d / max d)


def _replay():
    """experiments/heading_replay.py as a module (the walks and scans)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("heading_replay", Path(__file__).with_name("heading_replay.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def density(spectrum, total, kernel_std: float, bins: int):
    """The direction density on `bins` directions over [0, pi) from a spectrum (`kernels.wall_heading`: sum_i
    w_i exp(2 j k phi_i), k >= 1) and its total weight sum_i w_i, smoothed by a Gaussian of `kernel_std` (rad)."""
    import jax.numpy as jnp

    k = jnp.arange(1, spectrum.shape[-2] + 1, dtype=jnp.float32)
    theta = jnp.arange(bins, dtype=jnp.float32) * jnp.pi / bins
    smooth = jnp.exp(-2.0 * (k * kernel_std) ** 2)
    a = 2.0 * k[None, :] * theta[:, None]
    series = jnp.cos(a) @ (smooth * spectrum[..., 0]).T + jnp.sin(a) @ (smooth * spectrum[..., 1]).T
    return (jnp.asarray(total)[..., None] + 2.0 * series.T) / jnp.pi


def spectrum_of(values, harmonics: int):
    """The spectrum (k = 1..harmonics) of a density given on equally spaced directions over [0, pi)."""
    import jax.numpy as jnp

    bins = values.shape[-1]
    k = jnp.arange(1, harmonics + 1, dtype=jnp.float32)
    a = 2.0 * k[None, :] * (jnp.arange(bins, dtype=jnp.float32) * jnp.pi / bins)[:, None]
    return jnp.stack([values @ jnp.cos(a), values @ jnp.sin(a)], -1) * (jnp.pi / bins)


def log_compressed(spectrum, total, kernel_std: float):
    """A spectrum whose density is replaced by log(1 + LOG_GAIN d / max d) (negative ringing clipped to 0)."""
    import jax.numpy as jnp

    d = jnp.maximum(density(spectrum, total, kernel_std, 8 * spectrum.shape[-2]), 0.0)
    top = jnp.max(d, axis=-1, keepdims=True)
    return spectrum_of(jnp.log1p(LOG_GAIN * d / jnp.where(top > 0, top, 1.0)), spectrum.shape[-2])


def errors_deg(x: dict, truths: np.ndarray, every: float, skip: float) -> dict:
    """Per variant, the (error deg, quality) of every measured node of every robot."""
    import jax
    import jax.numpy as jnp

    from jaxquad.explore.config import ExploreConfig
    from jaxquad.kernels.wall_heading import (
        direction_spectrum,
        halves_disagreement,
        measure_heading,
        rotate_spectrum,
        wall_directions,
    )
    from jaxquad.slam import grid_spec, map_max_range, slam_config
    from jaxquad.slam.heading import HALVES_MIN_QUALITY

    base = ExploreConfig(world="warehouse").slam_values()
    grid = grid_spec((-0.5, -0.5, 15.5, 20.5), base["resolution"], map_max_range(base))
    spec, params = slam_config(base, grid, "preintegrated")
    hs, hp = spec.heading, params.heading
    bearings = jnp.asarray(x["bearings"], jnp.float32)
    dt = float(x["t"][1] - x["t"][0])  # s between scans
    nodes = np.arange(0, truths.shape[1], max(1, round(every / dt)))
    first = int(np.searchsorted(nodes * dt, skip))
    directions = jax.jit(jax.vmap(lambda r, v: wall_directions(hs, hp, r, bearings, v)))
    measure = jax.jit(jax.vmap(lambda s, m: measure_heading(hs, hp, s, m)))
    split = jax.jit(
        jax.vmap(lambda d, w, r, h, m: halves_disagreement(hs, hp, d, w, r, h, m, jnp.float32(HALVES_MIN_QUALITY)))
    )

    @jax.jit
    def spectra(d, w, heading):
        local = jax.vmap(lambda a, b: direction_spectrum(hs, a, b, 0.0))(d, w)
        scans = jax.vmap(lambda s, h: rotate_spectrum(hs, s, h))(local, heading)
        total = jnp.sum(w, axis=-1)
        return scans, jnp.cumsum(scans, 0) - scans, jnp.cumsum(total) - total  # the map: the earlier nodes

    out = {v: [] for v in VARIANTS}
    for r in range(truths.shape[0]):
        ranges = jnp.asarray(x["ranges"][r, nodes], jnp.float32)
        d, w = directions(ranges, jnp.isfinite(ranges) & (ranges > 0))
        heading = jnp.asarray(truths[r, nodes, 2], jnp.float32)
        for variant in VARIANTS[:3]:
            scans, maps, totals = spectra(d, w if variant == "inverse-variance" else (w > 0).astype(w.dtype), heading)
            if variant == "unit, log map":
                maps = log_compressed(maps, totals, float(hp.kernel_std))
            m = measure(scans, maps)
            error, quality = np.rad2deg(np.asarray(m.error)), np.asarray(m.quality)
            out[variant].append(np.stack([error, quality], -1)[first:])
            if variant == "inverse-variance":  # the same measurements, left out (quality 0) where the halves disagree
                apart = np.rad2deg(np.asarray(split(d, w, ranges, heading, maps)))
                kept = np.where(apart <= HALVES_TOLERANCE_DEG, quality, 0.0)
                out[HALVES].append(np.stack([error, kept], -1)[first:])
    return {v: np.concatenate(rows) for v, rows in out.items()}


def score(variant: str, measured: np.ndarray, min_quality: float) -> dict:
    """One row: `measured` holds (error deg, quality) per node."""
    used = np.isfinite(measured[:, 0]) & (measured[:, 1] >= min_quality)
    e = np.abs(measured[used, 0])
    return {
        "variant": variant,
        "nodes": int(len(measured)),
        "measurements": int(used.sum()),
        "rms_deg": float(np.sqrt(np.mean(e**2))) if e.size else None,
        "median_deg": float(np.median(e)) if e.size else None,
        "over_1_deg": int((e > 1).sum()),
        "over_2_deg": int((e > 2).sum()),
        "over_4_deg": int((e > 4).sum()),
    }


def table(rows: list[dict]) -> str:
    lines = [
        "| weights | nodes | measurements (quality >= min) | rms deg | median deg | > 1 deg | > 2 deg | > 4 deg |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    f = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
    for r in rows:
        lines.append(
            f"| {r['variant']} | {r['nodes']} | {r['measurements']} | {f(r['rms_deg'])} | {f(r['median_deg'])} "
            f"| {r['over_1_deg']} | {r['over_2_deg']} | {r['over_4_deg']} |"
        )
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    replay = _replay()
    replay.add_walk_arguments(p, robots=2)
    p.add_argument("--every", type=float, default=0.5, help="time between measured nodes (s)")
    p.add_argument("--skip", type=float, default=10.0, help="nodes of the first seconds are not measured (s)")
    p.add_argument("--json", help="write the rows here as JSON")
    args = p.parse_args(argv)
    replay.check_walk_arguments(p, args)
    if not args.every > 0 or not 0 <= args.skip < args.seconds:
        p.error(f"--every must be > 0 s and --skip in [0, --seconds), got {args.every} and {args.skip}")
    if args.json and not os.access(os.path.dirname(os.path.abspath(args.json)), os.W_OK):
        p.error(f"--json {args.json}: its folder is not writable")
    import jax

    from jaxquad.explore.config import ExploreConfig

    print(f"command: python {shlex.join(['experiments/heading_association.py', *(argv or sys.argv[1:])])}")
    machine = platform.processor() or platform.machine()
    print(f"machine: {platform.node()} {machine}, jax {jax.__version__} on {jax.default_backend()}")
    x, truths = replay.inputs(args.robots, args.seconds, args.seed, 0.32)
    measured = errors_deg(x, truths, args.every, args.skip)
    min_quality = float(ExploreConfig(world="warehouse").slam_values()["wall_heading_min_quality"])
    rows = [score(v, measured[v], min_quality) for v in VARIANTS]
    print(table(rows))
    if args.json:
        from jaxquad.io import write_json

        write_json(args.json, rows)


if __name__ == "__main__":
    main()
