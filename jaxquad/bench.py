"""`jaxquad bench`: timing of the library's hot paths, one section per module.

A section is a module `jaxquad._bench_<name>` exposing `run(args) -> dict` and, if it takes options
of its own, `add_arguments(parser)`. Section modules keep jax/mujoco imports inside functions, so
registering their options is cheap; a section's work runs only when its flag is given. With no
section flag the kernel section runs.

A section's dict is printed as JSON with `--json` (all sections in one object, with the device) or,
for people, as a table built from its `"rows"` (a list of flat dicts sharing keys) followed by its
other keys. `time_jitted` is the shared timer (compile time apart from the steady median).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os

# flag -> (module, help). Order is the run order.
_SECTIONS: dict[str, tuple[str, str]] = {
    "kernels": ("jaxquad._bench_kernels", "contact observer, leg twist and scan kernels (default)"),
    "metrics": ("jaxquad._bench_metrics", "trajectory metrics"),
    "sim": ("jaxquad._bench_sim", "MJX simulation"),
    "frontend": ("jaxquad._bench_slam_frontend", "SLAM front end: scan matching and likelihood grids"),
    "nav": ("jaxquad._bench_nav", "navigation: MPPI tick, costmap, global planner, frontier choice"),
    "localize": ("jaxquad._bench_localize", "AMCL update: R robots x P particles x B beams"),
    "slam": ("jaxquad._bench_slam", "pose-graph optimization vs GTSAM, batched graphs, occupancy scan insertion"),
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cpu", action="store_true", help="run on the CPU (sets JAX_PLATFORMS=cpu)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of tables")
    parser.add_argument(
        "--batch",
        type=int,
        nargs="+",
        default=[1, 1024],
        metavar="N",
        help="vmapped batch sizes (default: 1 1024)",
    )
    parser.add_argument(
        "--devices",
        type=int,
        nargs="+",
        default=None,
        metavar="N",
        help="device counts to run --sim on, one row each, in this run (default: all devices)",
    )
    for name, (module, help_) in _SECTIONS.items():
        parser.add_argument(f"--{name}", action="store_true", help=help_)
        if importlib.util.find_spec(module) is not None:
            section = importlib.import_module(module)
            if hasattr(section, "add_arguments"):
                section.add_arguments(parser.add_argument_group(f"{name} section"))


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            return next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        import platform

        return platform.processor() or "unknown"


def _environment() -> dict:
    import jax

    device = jax.devices()[0]
    name = getattr(device, "device_kind", str(device))
    if device.platform == "cpu":
        name = f"cpu ({_cpu_model()}, {os.cpu_count()} cores)"
    return {
        "device": name,
        "backend": jax.default_backend(),
        "n_devices": jax.device_count(),
        "jax_version": jax.__version__,
    }


def time_jitted(fn, *args, repeats: int = 20, budget_s: float = 3.0) -> tuple[float, float]:
    """(compile_s, run_ms) of a jitted `fn` on `args`: ahead-of-time lowering + compilation timed
    apart from the median of up to `repeats` steady calls (at least 3; fewer than `repeats` once
    `budget_s` is spent), each waited on with `block_until_ready` after one warm-up call."""
    import time

    import jax

    t0 = time.perf_counter()
    compiled = fn.lower(*args).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(*args))
    runs = []
    start = time.perf_counter()
    while len(runs) < repeats and (len(runs) < 3 or time.perf_counter() - start < budget_s):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        runs.append(time.perf_counter() - t0)
    runs.sort()
    return compile_s, 1e3 * runs[len(runs) // 2]


def _format_value(v) -> str:
    if isinstance(v, float):
        return f"{v:,.0f}" if abs(v) >= 1e4 else f"{v:.4g}"
    return str(v)


def format_table(rows: list[dict]) -> str:
    """Left-aligned text table of flat dicts (columns: the first row's keys)."""
    if not rows:
        return "(no rows)"
    keys = list(rows[0])
    cells = [[_format_value(r.get(k, "")) for k in keys] for r in rows]
    widths = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(keys)]
    line = lambda vals: "  ".join(v.ljust(w) for v, w in zip(vals, widths)).rstrip()
    return "\n".join([line(keys), line(["-" * w for w in widths])] + [line(c) for c in cells])


def run(args: argparse.Namespace) -> int:
    if any(b < 1 for b in args.batch):
        raise ValueError(f"--batch sizes must be >= 1, got {args.batch}")
    if args.cpu:
        # Must precede the first jax import to take effect.
        os.environ["JAX_PLATFORMS"] = "cpu"
        import jax

        jax.config.update("jax_platforms", "cpu")  # in case jax was imported already
    chosen = [name for name in _SECTIONS if getattr(args, name)] or ["kernels"]
    for name in chosen:
        if importlib.util.find_spec(_SECTIONS[name][0]) is None:
            raise ValueError(f"bench section '{name}' is not available ({_SECTIONS[name][0]} missing)")

    env = _environment()
    if not args.json:
        print(f"device: {env['device']}  backend: {env['backend']}  jax {env['jax_version']}")
    results = {}
    for name in chosen:
        results[name] = importlib.import_module(_SECTIONS[name][0]).run(args)
        if not args.json:
            print(f"\n[{name}]")
            print(format_table(results[name].get("rows", [])))
            for k, v in results[name].items():
                if k != "rows":
                    print(f"{k}: {_format_value(v)}")
    if args.json:
        from jaxquad.io.jsonfile import to_json

        print(to_json({**env, "sections": results}, indent=1))
    return 0
