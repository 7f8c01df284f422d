"""The demo's summary: mean scores per contact source, the printed table, the machine."""

from __future__ import annotations

import os
import platform

import numpy as np

# (label, path into a robot's scores, format, weight path or None) of the mean table: every entry is
# a mean over robots (weighted by the count at the weight path where there is one).
_TABLE = (
    ("contact F1", ("contacts", "f1"), "{:.3f}", None),
    ("precision", ("contacts", "precision"), "{:.3f}", None),
    ("recall", ("contacts", "recall"), "{:.3f}", None),
    ("force RMSE N", ("force", "rmse_n"), "{:.1f}", None),
    ("drift % (2-10 m)", ("drift", "drift_pct", "mean"), "{:.1f}", ("drift", "drift_pct", "n_segments")),
    ("drift deg/m", ("drift", "drift_deg_per_m", "mean"), "{:.2f}", ("drift", "drift_deg_per_m", "n_segments")),
    ("end-point drift %", ("drift", "endpoint_drift_horizontal_pct"), "{:.1f}", None),
    ("z error at end m", ("drift", "z_error_final_m"), "{:+.2f}", None),
    ("ATE m", ("trajectory", "ate", "rmse"), "{:.3f}", None),
    ("RPE 2 m", ("trajectory", "rpe_2m", "rmse"), "{:.3f}", None),
)
_DELAYS = (("touchdown delay ms", "touchdown"), ("lift-off delay ms", "liftoff"))


def _get(d: dict, path: tuple[str, ...]):
    for key in path:
        if not isinstance(d, dict) or key not in d:
            return None
        d = d[key]
    return d


def mean_scores(robots: list[dict]) -> dict:
    """Per table label: {"value", "averages"}: the mean over robots (NaN-free robots only; drift
    weighted by segments) or, for delays, over every matched event of every robot; `averages` says
    over what. A label no robot has is absent."""
    from jaxquad.estimate import scores

    per_robot = [r["scores"] for r in robots]
    out = {}
    for label, path, _, weight in _TABLE:
        m = scores.fleet_mean(per_robot, path, weight)
        if m["n_robots"]:
            what = f"{m['n_robots']} robots" + (f", {m['weight_sum']:.0f} segments" if weight else "")
            out[label] = {"value": m["mean"], "averages": what}
    delays = [r["delays"] for r in per_robot if "delays" in r]
    if delays:
        agg = scores.aggregate_delays(delays)
        for label, kind in _DELAYS:
            a = agg[kind]
            out[label] = {"value": a["mean_ms"], "averages": f"{a['n_events']} matched events ({a['n_missed']} missed)"}
    return out


def format_table(sources: dict[str, dict], scans: dict | None = None) -> str:
    """Plain-text table: one column per contact source, then the scan agreement lines."""
    fmt = {lab: f for lab, _, f, _ in _TABLE} | {lab: "{:+.1f}" for lab, _ in _DELAYS}
    labels = [lab for lab, _, _, _ in _TABLE[:3]] + [lab for lab, _ in _DELAYS] + [lab for lab, _, _, _ in _TABLE[3:]]
    names = list(sources)
    lines = [f"{'':20s}" + "".join(f"{n:>14s}" for n in names)]
    for lab in labels:
        cells = []
        for n in names:
            v = sources[n].get(lab, {}).get("value")
            cells.append("-" if v is None or not np.isfinite(v) else fmt[lab].format(v))
        lines.append(f"{lab:20s}" + "".join(f"{c:>14s}" for c in cells))
    lines.append("(means over robots; delays pooled over matched events; drift over 2, 5 and 10 m segments)")
    if scans:
        lines.append("")
        lines.append(f"{'scan vs true map':20s}" + "".join(f"{n:>14s}" for n in scans))
        lines.append(
            f"{'end points on walls %':20s}" + "".join(f"{s['map_agreement_pct']:>14.1f}" for s in scans.values())
        )
        lines.append(f"{'no reading %':20s}" + "".join(f"{s['no_reading_pct']:>14.1f}" for s in scans.values()))
    return "\n".join(lines)


def machine() -> dict:
    import jax

    return {
        "node": platform.node(),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jax_devices": [str(d) for d in jax.devices()],
    }
