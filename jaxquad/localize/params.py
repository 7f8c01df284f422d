"""AMCL parameters from a YAML file: the package's documented defaults (`amcl.yaml`) overridden by
the user's file. Every value is checked (a known key, a finite number in range) with one-line errors
naming the file and key."""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

DEFAULTS_FILE = Path(__file__).with_name("amcl.yaml")
_INTEGER = ("max_particles", "max_beams", "seed")
_POSITIVE = ("max_particles", "max_beams", "sigma_hit", "laser_likelihood_max_dist", "laser_max_range")
_FRACTION = ("recovery_alpha_slow", "recovery_alpha_fast", "resample_ratio")


@dataclasses.dataclass(frozen=True)
class LocalizeParams:
    """Every parameter of `amcl.yaml` (units there); `amcl()` gives the kernel's AmclParams."""

    max_particles: int
    max_beams: int
    alpha1: float
    alpha2: float
    alpha3: float
    alpha4: float
    alpha5: float
    z_hit: float
    z_rand: float
    sigma_hit: float
    laser_likelihood_max_dist: float
    laser_min_range: float
    laser_max_range: float
    update_min_d: float
    update_min_a: float
    recovery_alpha_slow: float
    recovery_alpha_fast: float
    resample_ratio: float
    initial_std_xy: float
    initial_std_yaw: float
    seed: int

    def amcl(self, T_base_laser=(0.0, 0.0, 0.0)):
        from jaxquad.kernels import AmclParams

        return AmclParams.paper(
            n_beams=self.max_beams,
            alpha=[self.alpha1, self.alpha2, self.alpha3, self.alpha4, self.alpha5],
            z_hit=self.z_hit,
            z_rand=self.z_rand,
            sigma_hit=self.sigma_hit,
            range_min=self.laser_min_range,
            range_max=self.laser_max_range,
            update_min_d=self.update_min_d,
            update_min_a=self.update_min_a,
            alpha_slow=self.recovery_alpha_slow,
            alpha_fast=self.recovery_alpha_fast,
            resample_ratio=self.resample_ratio,
            init_std=[self.initial_std_xy, self.initial_std_xy, self.initial_std_yaw],
            T_base_laser=list(T_base_laser),
        )


def _read(path: Path) -> dict:
    import yaml

    from jaxquad.io.files import read_text

    text = read_text(path, "params")
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as e:
        line = getattr(getattr(e, "problem_mark", None), "line", None)
        raise ValueError(
            f"params file {path}: not valid YAML" + (f" (line {line + 1})" if line is not None else "")
        ) from None
    raw = {} if raw is None else raw
    # A Nav2 file nests its values under amcl: ros__parameters:.
    if isinstance(raw, dict) and isinstance(raw.get("amcl"), dict):
        raw = raw["amcl"].get("ros__parameters", raw["amcl"])
    if not isinstance(raw, dict):
        raise ValueError(f"params file {path}: expected a mapping of AMCL parameters")
    return raw


def load_params(path: str | os.PathLike | None = None, **overrides) -> LocalizeParams:
    """The defaults of amcl.yaml, then `path`'s values, then `overrides` (None values ignored)."""
    values = _read(DEFAULTS_FILE)
    source = DEFAULTS_FILE
    if path is not None:
        source = Path(path)
        if not source.is_file():
            raise FileNotFoundError(f"params file not found: {source}")
        user = _read(source)
        unknown = sorted(set(user) - set(values))
        if unknown:
            raise ValueError(f"params file {source}: unknown key(s) {unknown}; known: {sorted(values)}")
        values |= user
    values |= {k: v for k, v in overrides.items() if v is not None}
    for key, v in values.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"params file {source}: {key} must be a finite number, got {v!r}")
        if key in _INTEGER:
            if v != int(v):
                raise ValueError(f"params file {source}: {key} must be an integer, got {v!r}")
            values[key] = int(v)
        if v < 0 or (key in _POSITIVE and v <= 0) or (key in _FRACTION and v > 1):
            raise ValueError(f"params file {source}: {key} = {v!r} is out of range")
    if values["laser_min_range"] >= values["laser_max_range"]:
        raise ValueError(f"params file {source}: laser_min_range must be below laser_max_range")
    return LocalizeParams(**values)
