"""Heading from wall directions: a scan's line directions against those of the map built so far.

A leg-inertial odometry's heading is the IMU's yaw, a random walk; a scan match to the last nodes fixes the
heading only relative to them, so the graph's heading drifts with the walk until a loop closes. But walls
seen now mostly run parallel to walls already mapped, however far away those are: the directions of the
scan's straight stretches, put into the map frame by the node's heading, line up with the map's own
directions only at the true heading. This is the angle-histogram idea of Hinkel and Knieriemen (1988) and
Weiss, Wetzler and von Puttkamer (1994), here against the map's accumulated directions rather than one
reference scan, so its error does not add up from node to node.

- `wall_directions`: per return, the direction (mod pi) of the wall through it, from the principal axis
  of the returns within `window_m` along the scan (and at most `HeadingSpec.max_window_beams` beams either
  side: with 160 beams over 86 deg, the whole 0.5 m beyond about 2.7 m of range), and a weight: the inverse
  of that direction's variance for the range noise `depth_noise_k * r^2` (at least `noise_floor_m`; a line
  fit of N points with spread lambda_1 along it: sigma^2 / (N lambda_1)), zero where the stretch is not
  straight (its second eigenvalue exceeds what the noise explains) or too short.
- `direction_spectrum`: the weighted directions as the first `harmonics` Fourier coefficients of their
  density over the doubled angle (lines have no sign), rotated into the map frame by a heading; the map's
  spectrum is the sum of its scans', each turned by its scan's current heading (`rotate_spectrum`).
- `measure_heading`: the cross-correlation of a scan's spectrum with the map's, smoothed by a Gaussian of
  `kernel_std`, searched over +-`search` around the current heading; the peak (refined by a parabola)
  gives the heading error, and the correlation at the peak over the two spectra's norms (Cauchy-Schwarz:
  at most 1) its quality: 0 when the peak lies on the search's edge. A scan whose walls run in no mapped
  direction has a low quality.
- `halves_disagreement`: the scan measured twice, its straight returns split at their median range, and how far
  the near half's error lies from the far half's. A box turned a few degrees off the walls, seen in front of a
  wall, is lined up with the mapped wall direction by its own (near, precise, heavily weighted) returns while the
  wall behind it measures the heading as it is: the halves disagree by about the box's turn. Such a scan's whole
  measurement follows the box, with a high quality, and so does the heading if it is used.

Directions of the map repeat with its walls' symmetry (every 90 deg in a rectilinear building), so the
search must stay well inside that period: the heading must already be known to better than it.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float


class HeadingSpec(eqx.Module):
    """Static sizes: Fourier harmonics of the direction density, the widest fit window in beams, and the
    number of candidate headings of the search."""

    harmonics: int = eqx.field(static=True, default=48)
    max_window_beams: int = eqx.field(static=True, default=20)
    steps: int = eqx.field(static=True, default=401)


def _f(x) -> Array:
    return jnp.asarray(x, jnp.float32)


class HeadingParams(eqx.Module):
    """Tunable numbers (traced)."""

    window_m: Float[Array, ""] = eqx.field(default_factory=lambda: _f(0.5))  # half-length of a fitted stretch (m)
    min_range: Float[Array, ""] = eqx.field(default_factory=lambda: _f(0.2))  # returns outside are unused (m)
    max_range: Float[Array, ""] = eqx.field(default_factory=lambda: _f(5.0))
    depth_noise_k: Float[Array, ""] = eqx.field(default_factory=lambda: _f(0.01))  # range std = k r^2 (1/m) ...
    noise_floor_m: Float[Array, ""] = eqx.field(default_factory=lambda: _f(0.01))  # ... and at least this (m)
    kernel_std: Float[Array, ""] = eqx.field(default_factory=lambda: _f(math.radians(1.0)))  # rad
    search: Float[Array, ""] = eqx.field(default_factory=lambda: _f(math.radians(10.0)))  # +- rad


class HeadingMeasurement(eqx.Module):
    error: Float[Array, ""]  # rad: the heading used minus the heading at which the scan fits the map best
    quality: Float[Array, ""]  # peak correlation / (|scan| |map|), at most 1; 0 when either is empty or on the edge


def wall_directions(
    spec: HeadingSpec,
    params: HeadingParams,
    ranges: Float[Array, " b"],
    bearings: Float[Array, " b"],
    valid: Bool[Array, " b"],
) -> tuple[Float[Array, " b"], Float[Array, " b"]]:
    """(direction rad in the sensor frame, mod pi; weight 1/rad^2) of the wall through each return."""
    b = ranges.shape[0]
    ok = valid & jnp.isfinite(ranges) & (ranges >= params.min_range) & (ranges <= params.max_range)
    r = jnp.where(ok, ranges, 1.0)
    p = r[:, None] * jnp.stack([jnp.cos(bearings), jnp.sin(bearings)], -1)
    step = jnp.mean(jnp.abs(jnp.diff(bearings))) if b > 1 else jnp.asarray(1.0)
    sigma = jnp.maximum(params.depth_noise_k * r**2, params.noise_floor_m)
    half = jnp.clip(jnp.ceil(params.window_m / (r * step)), 2, spec.max_window_beams)

    offsets = jnp.arange(-spec.max_window_beams, spec.max_window_beams + 1)
    idx = jnp.arange(b)[:, None] + offsets[None, :]
    inside = (idx >= 0) & (idx < b)
    idx = jnp.clip(idx, 0, b - 1)
    d = p[idx] - p[:, None, :]  # (b, w, 2), relative to the return itself
    near = jnp.linalg.norm(d, axis=-1) < 1.5 * params.window_m + 3.0 * sigma[:, None]
    use = inside & ok[idx] & (jnp.abs(offsets).astype(r.dtype)[None, :] <= half[:, None]) & near & ok[:, None]
    n = jnp.sum(use, axis=1).astype(r.dtype)
    wgt = use.astype(r.dtype)
    mean = jnp.sum(wgt[..., None] * d, axis=1) / jnp.maximum(n, 1.0)[:, None]
    c = d - mean[:, None, :]
    sxx = jnp.sum(wgt * c[..., 0] ** 2, axis=1) / jnp.maximum(n, 1.0)
    syy = jnp.sum(wgt * c[..., 1] ** 2, axis=1) / jnp.maximum(n, 1.0)
    sxy = jnp.sum(wgt * c[..., 0] * c[..., 1], axis=1) / jnp.maximum(n, 1.0)
    spread = jnp.sqrt((sxx - syy) ** 2 + 4.0 * sxy**2)
    major, minor = 0.5 * (sxx + syy + spread), 0.5 * (sxx + syy - spread)
    direction = 0.5 * jnp.arctan2(2.0 * sxy, sxx - syy)
    # Straight: the scatter across the stretch is within twice the range noise (and 2 cm of surface).
    straight = minor < 4.0 * sigma**2 + 0.02**2
    weight = n * major / sigma**2  # 1 / var(direction) of a line fit: sigma^2 / (N lambda_1)
    good = ok & (n >= 5) & straight & (major > 0)
    return jnp.where(good, direction, 0.0), jnp.where(good, weight, 0.0)


def _harmonics(spec: HeadingSpec) -> Float[Array, " m"]:
    return jnp.arange(1, spec.harmonics + 1, dtype=jnp.float32)


def direction_spectrum(
    spec: HeadingSpec, direction: Float[Array, " b"], weight: Float[Array, " b"], heading: Float[Array, ""]
) -> Float[Array, "m 2"]:
    """(real, imaginary) of sum_i w_i exp(2 j k (phi_i + heading)), k = 1..harmonics: the directions'
    density in the frame where the sensor has `heading`."""
    a = 2.0 * _harmonics(spec)[None, :] * (direction + heading)[:, None]
    return jnp.stack([weight @ jnp.cos(a), weight @ jnp.sin(a)], -1)


def rotate_spectrum(
    spec: HeadingSpec, spectrum: Float[Array, "*n m 2"], heading: Float[Array, "*n"]
) -> Float[Array, "*n m 2"]:
    """A spectrum (`direction_spectrum`) turned by `heading` more: harmonic k's phase advanced by 2 k heading.
    So a node's spectrum kept in its own frame is put into the map frame by its current heading."""
    a = 2.0 * _harmonics(spec) * heading[..., None]
    c, s = jnp.cos(a), jnp.sin(a)
    re, im = spectrum[..., 0], spectrum[..., 1]
    return jnp.stack([re * c - im * s, re * s + im * c], -1)


def measure_heading(
    spec: HeadingSpec, params: HeadingParams, scan: Float[Array, "m 2"], reference: Float[Array, "m 2"]
) -> HeadingMeasurement:
    """The heading error of a scan's spectrum (at the heading in use) against the map's spectrum."""
    k = _harmonics(spec)
    smooth = jnp.exp(-2.0 * (k * params.kernel_std) ** 2)  # a Gaussian of kernel_std over the angle
    (sr, si), (mr, mi) = scan.T, reference.T
    cross_re, cross_im = smooth * (sr * mr + si * mi), smooth * (sr * mi - si * mr)  # smooth conj(s) m
    delta = jnp.linspace(-1.0, 1.0, spec.steps) * params.search
    a = 2.0 * k[None, :] * delta[:, None]
    corr = jnp.cos(a) @ cross_re + jnp.sin(a) @ cross_im  # Re(sum_k smooth conj(s) m exp(-2 j k delta))
    peak = jnp.argmax(corr)
    i = jnp.clip(peak, 1, spec.steps - 2)
    lo, mid, hi = corr[i - 1], corr[i], corr[i + 1]
    curve = lo - 2.0 * mid + hi
    shift = jnp.where(curve < 0, jnp.clip(0.5 * (lo - hi) / jnp.where(curve < 0, curve, -1.0), -1.0, 1.0), 0.0)
    best = delta[i] + shift * (delta[1] - delta[0])
    norm = jnp.sqrt(jnp.sum(smooth * (sr**2 + si**2))) * jnp.sqrt(jnp.sum(smooth * (mr**2 + mi**2)))  # no overflow
    # A peak on the search's edge is no peak: the best alignment lies outside the search.
    inside = (peak > 0) & (peak < spec.steps - 1) & (norm > 0)
    quality = jnp.where(inside, corr[i] / jnp.where(norm > 0, norm, 1.0), 0.0)
    return HeadingMeasurement(error=-best, quality=quality)


def halves_disagreement(
    spec: HeadingSpec,
    params: HeadingParams,
    direction: Float[Array, " b"],
    weight: Float[Array, " b"],
    ranges: Float[Array, " b"],
    heading: Float[Array, ""],
    reference: Float[Array, "m 2"],
    min_quality: Float[Array, ""],
) -> Float[Array, ""]:
    """|near half's error - far half's error| (rad) of a scan measured against `reference`, its straight returns
    (weight > 0) split at their median range; 0 when either half measures below `min_quality` (nothing to
    compare). `direction`, `weight` from `wall_directions`, in the sensor frame at `heading`."""
    straight = weight > 0
    median = jnp.nanmedian(jnp.where(straight, ranges, jnp.nan))
    near = straight & (ranges < median)
    errors, qualities = [], []
    for half in (near, straight & ~near):
        m = measure_heading(
            spec, params, direction_spectrum(spec, direction, jnp.where(half, weight, 0.0), heading), reference
        )
        errors.append(m.error)
        qualities.append(m.quality)
    both = (qualities[0] >= min_quality) & (qualities[1] >= min_quality)
    return jnp.where(both, jnp.abs(errors[0] - errors[1]), 0.0)
