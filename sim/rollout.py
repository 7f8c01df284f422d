"""In-memory fleet runs: `rollout(config, seconds) -> FleetLog`, the same content as a fleet `.npz`.

`FleetLog` is a read-only mapping of the log's keys (the README's log format), so every consumer of
a loaded `.npz` (`jaxquad.estimate`, `jaxquad.io.save_log`, `robot_log`) takes it as it is; it also
keeps the generated worlds for their ground-truth maps. Chunks stream into host arrays (or into
memory-mapped files under `store`, to bound host memory for large fleets).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator, Mapping
from pathlib import Path

import numpy as np

from jaxquad import parallel

from .fleet import FleetConfig, build_fleet, init, n_chunks, run_chunk
from .worlds import World, occupancy_map

__all__ = ["FleetLog", "rollout"]


class FleetLog(Mapping):
    """A simulated fleet's log: arrays keyed as in the `.npz` format (leading robot axis N), the
    configuration that produced it and its worlds (`maps()` gives their ground-truth occupancy)."""

    def __init__(self, arrays: dict[str, np.ndarray], config: FleetConfig, worlds: list[World]):
        self._arrays = dict(arrays)
        self.config = config
        self.worlds = list(worlds)

    def __getitem__(self, key: str) -> np.ndarray:
        return self._arrays[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._arrays)

    def __len__(self) -> int:
        return len(self._arrays)

    @property
    def n_robots(self) -> int:
        return int(self._arrays["fallen"].shape[0])

    def maps(self):
        """Ground-truth `OccupancyMap` of every world (robot i walks world `world_index[i]`)."""
        return [occupancy_map(w) for w in self.worlds]

    def __repr__(self) -> str:
        T = self._arrays["t"].shape[0]
        return f"FleetLog({self.config.robot!r}, {self.n_robots} robots x {T} samples, keys={sorted(self._arrays)})"


def _check_disk(folder, need_bytes: int) -> None:
    free = shutil.disk_usage(folder).free
    if need_bytes > free:
        raise ValueError(
            f"the log needs {need_bytes / 1e9:.1f} GB in {folder} but only {free / 1e9:.1f} GB are free; "
            "simulate fewer robots or seconds, or --no-depth"
        )


def rollout(
    config: FleetConfig,
    seconds: float,
    progress: bool = True,
    store: str | os.PathLike | None = None,
    store_copies: int = 1,
) -> FleetLog | None:
    """Simulate the fleet for `seconds` (rounded up to whole chunks) and return its log.

    The robots are split over `config.devices` devices (all by default; `jaxquad.parallel`), with the
    same numbers as on one. In a multi-process run every process calls this and process 0 gets the
    log (the others get None).
    store: a folder for memory-mapped arrays (`<key>.npy`), else the arrays live in host memory.
    Its file system must have room for `store_copies` times the log (the caller's files written from
    the arrays count too): checked before simulating.
    """
    from tqdm import tqdm

    if not (seconds > 0 and np.isfinite(seconds)):
        raise ValueError(f"seconds must be positive, got {seconds}")
    fleet = build_fleet(config)
    chunks = n_chunks(fleet, seconds)
    n, T = config.n_robots, chunks * fleet.samples_per_chunk
    F = chunks * fleet.frames_per_chunk
    if store is not None and parallel.is_main():  # (N, ...) per chunk, robots on axis 1; n of N are real
        per_chunk = sum(
            np.prod(o.shape) // o.shape[1] * n * o.dtype.itemsize for o in fleet._chunk.out_info[1].values()
        )
        _check_disk(store, int(store_copies * chunks * per_chunk))
    arrays: dict[str, np.ndarray] = {}
    state = init(fleet)
    desc = f"simulate {n} x {config.robot}"
    for c in tqdm(range(chunks), desc=desc, unit="chunk", disable=not (progress and parallel.is_main()), file=None):
        state, outs = run_chunk(fleet, state)
        outs = parallel.gather(outs)
        if not parallel.is_main():
            continue
        for key, value in outs.items():
            if key not in arrays:
                shape = (n, F if key == "depth" else T) + value.shape[2:]  # robot-major on the host
                if store is None:
                    arrays[key] = np.empty(shape, value.dtype)
                else:
                    path = Path(store) / f"{key}.npy"
                    arrays[key] = np.lib.format.open_memmap(path, mode="w+", dtype=value.dtype, shape=shape)
            step = value.shape[0]  # chunks come time-major: (samples or frames, N, ...)
            arrays[key][:, c * step : (c + 1) * step] = np.swapaxes(value[:, :n], 0, 1)  # drops padding robots
    fallen, collided = parallel.gather((state.fallen, state.collided))
    if not parallel.is_main():
        return None
    # A sample describes the state its last physics step started from (`robot_step`), one step earlier.
    arrays.update(
        t=(np.arange(T) + 1) * fleet.log_dt - fleet.dt,
        robot=np.array(config.robot),
        joint_names=np.array(fleet.robot.joint_names),
        fallen=fallen[:n],
        collided=collided[:n],
        world_index=np.arange(n) % config.n_worlds,
    )
    if config.depth:
        arrays.update(
            depth_t=(np.arange(F) + 1) * fleet.frame_dt - fleet.dt, K=fleet.K, T_base_camera=fleet.T_base_camera
        )
    return FleetLog(arrays, config, fleet.worlds)
