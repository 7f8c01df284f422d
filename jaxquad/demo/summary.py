"""The demo's summary: mean scores per contact source, the printed table, the machine."""

from __future__ import annotations

import os
import platform

import numpy as np

# (label, path into a robot's scores, format) of the mean table.
_TABLE = (
    ("contact F1", ("contacts", "f1"), "{:.3f}"),
    ("precision", ("contacts", "precision"), "{:.3f}"),
    ("recall", ("contacts", "recall"), "{:.3f}"),
    ("touchdown delay ms", ("delays", "touchdown", "mean_ms"), "{:+.1f}"),
    ("lift-off delay ms", ("delays", "liftoff", "mean_ms"), "{:+.1f}"),
    ("force RMSE N", ("force", "rmse_n"), "{:.1f}"),
    ("drift horiz. %", ("drift", "horizontal_pct"), "{:.1f}"),
    ("drift 3D %", ("drift", "3d_pct"), "{:.1f}"),
    ("ATE m", ("trajectory", "ate", "rmse"), "{:.3f}"),
)


def _get(d: dict, path: tuple[str, ...]):
    for key in path:
        if not isinstance(d, dict) or key not in d:
            return None
        d = d[key]
    return d


def mean_scores(robots: list[dict]) -> dict:
    """Mean over robots of every table entry and of the first RPE's RMSE (entries a robot lacks
    are skipped; a key no robot has is absent)."""
    out = {}
    for label, path, _ in _TABLE:
        vals = [v for r in robots if (v := _get(r["scores"], path)) is not None]
        if vals:
            out[label] = float(np.mean(vals))
    rpe = [(k, v["rmse"]) for r in robots for k, v in r["scores"].get("trajectory", {}).items() if k.startswith("rpe_")]
    if rpe:
        out["RPE m"] = float(np.mean([v for _, v in rpe]))
    return out


def format_table(sources: dict[str, dict], scans: dict | None = None) -> str:
    """Plain-text table: one column per contact source, then the scan agreement lines."""
    labels = [lab for lab, _, _ in _TABLE] + ["RPE m"]
    fmt = {lab: f for lab, _, f in _TABLE} | {"RPE m": "{:.3f}"}
    names = list(sources)
    lines = [f"{'':20s}" + "".join(f"{n:>12s}" for n in names)]
    for lab in labels:
        cells = [fmt[lab].format(sources[n][lab]) if lab in sources[n] else "-" for n in names]
        lines.append(f"{lab:20s}" + "".join(f"{c:>12s}" for c in cells))
    if scans:
        lines.append("")
        lines.append(f"{'scan vs map':20s}" + "".join(f"{n:>12s}" for n in scans))
        lines.append(f"{'rays on map %':20s}" + "".join(f"{s['map_agreement_pct']:>12.1f}" for s in scans.values()))
        lines.append(f"{'no reading %':20s}" + "".join(f"{s['no_reading_pct']:>12.1f}" for s in scans.values()))
    return "\n".join(lines)


def machine() -> dict:
    import jax

    return {"node": platform.node(), "platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(), "python": platform.python_version(), "jax": jax.__version__,
            "jax_devices": [str(d) for d in jax.devices()]}  # fmt: skip
