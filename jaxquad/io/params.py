"""Observer parameter files (YAML or JSON): what `jaxquad tune` writes and `--params` reads.

Keys (all optional but a mapping is required): mode (plain | mixed), bandwidth (rad/s, > 0),
alpha (per-foot smoothing in (0, 1]), threshold_on and threshold_off (N, >= 0, off <= on per foot),
f_max (N, > 0), sharpness (> 0). Per-foot keys take one number or one per foot. The numbers may sit
at the top level or under an `observer:` key. Every value is checked here, with the key named.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from jaxquad.io.atomic import atomic_write_text

__all__ = ["OBSERVER_KEYS", "observer_params_dict", "read_observer_params", "write_observer_params"]

OBSERVER_KEYS = ("mode", "bandwidth", "alpha", "threshold_on", "threshold_off", "f_max", "sharpness")
_PER_FOOT = ("alpha", "threshold_on", "threshold_off")
# key -> (lowest allowed, whether the lowest is allowed, highest allowed)
_RANGES = {
    "bandwidth": (0.0, False, np.inf),
    "alpha": (0.0, False, 1.0),
    "threshold_on": (0.0, True, np.inf),
    "threshold_off": (0.0, True, np.inf),
    "f_max": (0.0, False, np.inf),
    "sharpness": (0.0, False, np.inf),
}


def observer_params_dict(params) -> dict:
    """The keys a params file holds (floats; per-foot lists) of an ObserverParams."""
    from jaxquad.io.jsonfile import json_ready

    scalar = lambda x: json_ready(np.asarray(x).reshape(()))  # noqa: E731
    vector = lambda x: json_ready(np.asarray(x).reshape(-1))  # noqa: E731
    return {
        "mode": params.mode,
        "bandwidth": scalar(params.bandwidth),
        "alpha": vector(params.alpha),
        "threshold_on": vector(params.threshold_on),
        "threshold_off": vector(params.threshold_off),
        "f_max": scalar(params.f_max),
        "sharpness": scalar(params.sharpness),
    }


def write_observer_params(path: str | os.PathLike, params, header: str = "") -> Path:
    """Write ObserverParams as JSON (.json) or YAML (.yaml/.yml, `header` as comment lines), atomically."""
    import yaml

    path = Path(path)
    data = observer_params_dict(params)
    if path.suffix.lower() == ".json":
        text = json.dumps(data, indent=2) + "\n"
    elif path.suffix.lower() in (".yaml", ".yml"):
        text = "".join(f"# {line}\n" for line in header.splitlines()) + yaml.safe_dump(data, sort_keys=False)
    else:
        raise ValueError(f"params file must end in .json, .yaml or .yml, got {path.name}")
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_text(path, text)


def _number_array(path: Path, key: str, value, n_feet: int) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"params file {path}: {key} must be a number{' or a list of numbers' if key in _PER_FOOT else ''}, "
            f"got {value!r}"
        ) from None
    if key in _PER_FOOT:
        if a.ndim > 1 or (a.ndim == 1 and a.size not in (1, n_feet)):
            raise ValueError(f"params file {path}: {key} needs one number or {n_feet} (one per foot), got {a.size}")
        a = np.broadcast_to(a.reshape(-1) if a.ndim else a, (n_feet,))
    elif a.ndim != 0:
        raise ValueError(f"params file {path}: {key} must be one number, got {value!r}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"params file {path}: {key} is not finite ({value!r})")
    lo, lo_ok, hi = _RANGES[key]
    if np.any(a < lo) or (not lo_ok and np.any(a == lo)) or np.any(a > hi):
        rng = f"{'[' if lo_ok else '('}{lo:g}, {hi:g}{']' if np.isfinite(hi) else ')'}"
        raise ValueError(f"params file {path}: {key} must lie in {rng}, got {value!r}")
    return a


def read_observer_params(path: str | os.PathLike, n_feet: int = 4, mode: str = "mixed"):
    """ObserverParams from a file: the paper's defaults (`ObserverParams.paper`) with the file's keys
    applied. Raises ValueError naming the file and key for anything malformed or out of range."""
    import equinox as eqx
    import jax.numpy as jnp
    import yaml

    from jaxquad.kernels import ObserverParams

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"params file not found: {path}")
    try:
        raw = yaml.safe_load(path.read_text())  # JSON is YAML
    except (yaml.YAMLError, UnicodeDecodeError) as e:
        raise ValueError(f"params file {path}: not YAML or JSON ({type(e).__name__})") from None
    raw = {} if raw is None else raw
    if isinstance(raw, dict) and isinstance(raw.get("observer"), dict):
        raw = raw["observer"]
    if not isinstance(raw, dict):
        raise ValueError(f"params file {path}: expected a mapping of observer parameters")
    unknown = sorted(set(map(str, raw)) - set(OBSERVER_KEYS))
    if unknown:
        raise ValueError(f"params file {path}: unknown key(s) {unknown}; known: {list(OBSERVER_KEYS)}")
    mode = raw.get("mode", mode)
    if mode not in ("plain", "mixed"):
        raise ValueError(f"params file {path}: mode must be plain or mixed, got {mode!r}")
    params = ObserverParams.paper(n_feet, mode)
    for key, value in raw.items():
        if key == "mode":
            continue
        a = _number_array(path, key, value, n_feet)
        params = eqx.tree_at(lambda p, key=key: getattr(p, key), params, jnp.asarray(a, jnp.float32))
    if np.any(np.asarray(params.threshold_off) > np.asarray(params.threshold_on)):
        raise ValueError(f"params file {path}: threshold_off must not exceed threshold_on on any foot")
    return params
