"""Pausing an exploration run and going on with it later, in another process.

A run longer than one sitting (a batch job's time limit, a shared GPU) saves, at the end of a chunk, the
fleet's whole state and the outputs so far to one `.npz` file; `explore` called again with the same
configuration and file loads it and runs the remaining chunks, with the same result as a run without the
pause (the state holds every random key). The file records the configuration and the starts it belongs to:
another run's file is refused with a one-line error before any compilation; a file saved on another number
of devices (the robots are padded to a multiple of them) or whose state no longer fits the code's (a field
added or a size changed) is refused once the run's state is built.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import numpy as np

from jaxquad.io.atomic import atomic_open

FORMAT = "jaxquad-explore-checkpoint-2"
PAUSED_STATUS = 75  # a paused command's exit status (sysexits' EX_TEMPFAIL: not done yet, run it again)
# Settings that change how the run is computed, not what it computes.
_NOT_IDENTITY = ("devices",)


class CheckpointError(ValueError):
    """A checkpoint file that cannot be resumed: unreadable, of another run, or of another layout."""


class Paused(Exception):
    """`explore` reached its wall-clock budget and saved the run to `path`; call it again to go on."""

    def __init__(self, path: str | Path, sim_s: float, total_s: float):
        self.path, self.sim_s, self.total_s = Path(path), sim_s, total_s
        super().__init__(
            f"paused at {sim_s:.1f} of {total_s:.1f} simulated s; the run is saved in {self.path}: "
            "run the same command again to go on"
        )


def identity(cfg, starts: np.ndarray) -> str:
    """The run a checkpoint belongs to, as JSON: its configuration (less the device split; the SLAM parameters by
    their values, not their file's name) and its starts."""
    fields = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in _NOT_IDENTITY}
    fields["slam_params"] = cfg.slam_values()
    starts = np.asarray(starts, np.float64).round(9).tolist()
    return json.dumps({"config": fields, "starts": starts}, sort_keys=True, default=str)


def _is_key(x) -> bool:
    return jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def save(path: str | Path, run_id: str, states, trace, chunks: int, chunk_s: list, compile_s: float) -> Path:
    """Write the fleet's `states` (device pytree), the outputs so far (`trace`: host pytree, time-major), the
    chunk count, each chunk's wall time (s) and the compilation time to `path`, atomically (a stopped save leaves
    the previous file)."""
    leaves = jax.tree.leaves(states)
    robots = int(leaves[0].shape[0])  # padded to a multiple of the devices
    leaves = jax.device_get([jax.random.key_data(x) if _is_key(x) else x for x in leaves])
    arrays = {f"state_{i}": np.asarray(x) for i, x in enumerate(leaves)}
    arrays |= {f"trace_{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(trace))}
    meta = {
        "format": FORMAT,
        "run": run_id,
        "robots": robots,
        "chunks": chunks,
        "chunk_s": [float(x) for x in chunk_s],
        "compile_s": compile_s,
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path, "wb") as f:
        np.savez(f, meta=np.asarray(json.dumps(meta)), **arrays)
    return path


@dataclasses.dataclass
class Checkpoint:
    states: object  # the fleet's state, placed as the template's
    trace: object  # outputs of the chunks run so far (host, time-major)
    chunks: int  # chunks run so far
    chunk_s: list  # wall time of each of those chunks (s), all sittings
    compile_s: float  # compilation time, all sittings


def _read(path: Path, run_id: str, arrays: bool) -> tuple[dict, dict]:
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"])) if "meta" in z.files else {}
            data = {k: z[k] for k in z.files if k != "meta"} if arrays and meta.get("format") == FORMAT else {}
    except Exception as e:  # noqa: BLE001 - a file of any other kind or a truncated one: say which and why
        why = str(e).split(". ")[0]  # the reason, without advice on loading untrusted files
        raise CheckpointError(f"{path}: unreadable checkpoint ({type(e).__name__}: {why})") from None
    older = isinstance(meta, dict) and str(meta.get("format", "")).startswith(FORMAT.rsplit("-", 1)[0])
    if older and meta["format"] != FORMAT:
        raise CheckpointError(f"{path}: saved by another version of jaxquad; remove it to start afresh")
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not an exploration checkpoint")
    if meta.get("run") != run_id:
        raise CheckpointError(f"{path}: saved by a run with other settings or starts; remove it to start afresh")
    return meta, data


def check(path: str | Path, run_id: str) -> None:
    """Raise CheckpointError (one line) unless `path` is a checkpoint of the run `run_id` (reads its header only)."""
    _read(Path(path), run_id, arrays=False)


def load(path: str | Path, run_id: str, like_states, like_trace) -> Checkpoint:
    """The checkpoint at `path`, checked against the run (`identity`) and the state's structure: `like_states`
    is a freshly initialized state (its leaves' shapes, types and placement) and `like_trace` one chunk's
    outputs as kept (arrays or `jax.ShapeDtypeStruct`s: the trace's structure, shapes after time and types).
    Raises CheckpointError (one line) on a file of another run, device count or layout."""
    path = Path(path)
    meta, data = _read(path, run_id, arrays=True)
    like, treedef = jax.tree.flatten(like_states)
    if meta.get("robots") != like[0].shape[0]:
        raise CheckpointError(
            f"{path}: saved with the robots padded to {meta.get('robots')} for its device count, where this run "
            f"pads them to {like[0].shape[0]}: go on with the same number of devices (--devices)"
        )
    saved = [data.get(f"state_{i}") for i in range(len(like))]
    trace_def = jax.tree.structure(like_trace)
    traces = [data.get(f"trace_{i}") for i in range(trace_def.num_leaves)]
    misfit = CheckpointError(f"{path}: its state does not fit this version of jaxquad; remove it to start afresh")
    if len(data) != len(like) + len(traces) or any(a is None for a in saved + traces):
        raise misfit
    for a, x in zip(traces, jax.tree.leaves(like_trace)):
        if a.shape[1:] != tuple(x.shape[1:]) or a.dtype != x.dtype:
            raise misfit
    leaves = []
    for a, x in zip(saved, like):
        ref = jax.random.key_data(x) if _is_key(x) else x
        if a.shape != ref.shape or a.dtype != ref.dtype:
            raise misfit
        a = jax.device_put(a, x.sharding)
        leaves.append(jax.random.wrap_key_data(a, impl=jax.random.key_impl(x)) if _is_key(x) else a)
    return Checkpoint(
        states=jax.tree.unflatten(treedef, leaves),
        trace=jax.tree.unflatten(trace_def, traces),
        chunks=int(meta["chunks"]),
        chunk_s=[float(x) for x in meta["chunk_s"]],
        compile_s=float(meta["compile_s"]),
    )
