"""The `jaxquad` command: a thin dispatcher; each subcommand's module is imported only when used."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
from collections.abc import Callable, Iterator

# subcommand -> module defining `add_arguments(parser)` and `run(args) -> int`.
_COMMANDS: dict[str, tuple[str, str]] = {
    "bench": ("jaxquad.bench", "time the kernels (compile and steady run) for one robot and batches"),
    "demo": (
        "jaxquad.demo.cli",
        "simulate a small fleet, estimate contacts and odometry, score, write a report folder",
    ),
    "eval": ("jaxquad.metrics.cli", "ATE/ARE/APE/RPE of an estimated TUM trajectory against a reference, as evo"),
    "estimate": (
        "jaxquad.estimate.cli",
        "contacts and leg-inertial odometry over a robot log (TUM, npz, JSON summary)",
    ),
    "tune": (
        "jaxquad.estimate.tune.cli",
        "tune the contact observer's gains and thresholds on a fleet log (grid search or gradient)",
    ),
    "convert": ("jaxquad.ros.convert_cli", "a robot log (.npz) from a ROS 1 or ROS 2 bag and a topics file"),
    "export": (
        "jaxquad.ros.export_cli",
        "estimation, odometry, SLAM results (TUM, scans, maps) as a ROS bag for RViz/Foxglove",
    ),
    "navigate": (
        "jaxquad.nav.cli",
        "closed-loop navigation of a simulated fleet to random goals (JSON summary, paths)",
    ),
    "explore": (
        "jaxquad.explore.cli",
        "autonomous frontier exploration of an unknown world by a simulated fleet (coverage, maps, JSON summary)",
    ),
    "localize": (
        "jaxquad.localize.cli",
        "AMCL localization of a log's robots on a saved map (TUM, npz, JSON summary with errors)",
    ),
    "slam": (
        "jaxquad.slam.cli",
        "online 2D graph SLAM with leg-odometry constraints over a robot or laser log (TUM, map, g2o)",
    ),
    "posegraph": ("jaxquad.slam.posegraph_cli", "optimize a 2D g2o pose graph (sparse Levenberg-Marquardt)"),
    "vo": ("jaxquad.vo.cli", "depth-inertial visual odometry guided and restarted by leg odometry (TUM, JSON summary)"),
    "simulate": (
        "jaxquad.sim.cli",
        "run an MJX fleet of robots in generated worlds; write the fleet log, ground-truth TUM and maps",
    ),
}


@contextlib.contextmanager
def progress_bar(desc: str, unit: str) -> Iterator[Callable[[int | float, int | float], None]]:
    """A `progress(done, total)` callback drawing a tqdm bar on stderr from its first call on. Runs
    report `progress(0, total)` once their inputs are checked, so an input error prints alone."""
    bar = None

    def progress(done: int | float, total: int | float) -> None:
        nonlocal bar
        if bar is None:
            from tqdm import tqdm

            bar = tqdm(total=total, desc=desc, unit=unit)
        bar.total = total
        bar.update(done - bar.n)

    try:
        yield progress
    finally:
        if bar is not None:
            bar.close()


def add_devices_argument(parser, what: str = "robots", processes: bool = True) -> None:
    """The shared `--devices N` option of commands whose batch is split over devices (`jaxquad.parallel`);
    `processes`: the command also runs over several processes."""
    every = "all devices this run sees; in a multi-process run all devices of all processes"
    if not processes:
        every = "all devices of this process"
    parser.add_argument(
        "--devices",
        type=int,
        default=None,
        metavar="N",
        help=f"split the {what} over the first N devices (default: {every}); results equal one device's up to float "
        "rounding",
    )


def add_band_reduce_argument(
    parser, default: str | None = "median", default_text: str = "median", scope: str = ""
) -> None:
    """The shared `--band-reduce` option: how each scan ray's range comes from its band of pixel rows
    (`jaxquad.kernels.scan`); `scope` prefixes the help (e.g. "robot logs: ")."""
    from jaxquad.kernels.scan import BAND_REDUCTIONS

    parser.add_argument(
        "--band-reduce",
        choices=BAND_REDUCTIONS,
        default=default,
        help=f"{scope}each scan ray's range from its band of pixel rows: the median, or the paper's minimum "
        f"(biased short by depth noise; see jaxquad.kernels.scan) (default {default_text})",
    )


class _Parser(argparse.ArgumentParser):
    """argparse with the project's error rule: one line on stderr, exit status 1 (argparse uses 2)."""

    def error(self, message: str):
        self.exit(1, f"{self.prog}: error: {message}\n")


def main(argv: list[str] | None = None) -> int:
    parser = _Parser(prog="jaxquad", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    # Build every subparser lazily: only the chosen command's module is imported.
    argv = sys.argv[1:] if argv is None else argv
    chosen = next((a for a in argv if not a.startswith("-")), None)
    modules = {}
    for name, (module, help_) in _COMMANDS.items():
        p = sub.add_parser(name, help=help_)
        if name == chosen:
            modules[name] = importlib.import_module(module)
            modules[name].add_arguments(p)
    args = parser.parse_args(argv)
    try:
        if os.environ.get("JAXQUAD_NUM_PROCESSES"):  # a multi-process run starts before any JAX computation
            from jaxquad import parallel

            parallel.initialize()
        return int(modules[args.command].run(args) or 0)
    except (ValueError, OSError) as e:
        # Known input and output errors (a full disk, a folder not writable): one line, exit 1.
        print(f"jaxquad {args.command}: error: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
