"""The whole tuning run: split robots, tune on the training ones, score on both."""

from __future__ import annotations

import dataclasses
import inspect
from typing import Literal

import numpy as np

from jaxquad.estimate.tune.gradient import gradient_tune
from jaxquad.estimate.tune.grid import GridSpec, grid_search
from jaxquad.estimate.tune.observer_inputs import ContactTruth, ObserverInputs, select_robots
from jaxquad.estimate.tune.observer_scan import fleet_scores
from jaxquad.io.params import observer_params_dict
from jaxquad.kernels import ObserverParams


def call_options(fn, given: dict) -> dict:
    """The keyword options of `fn` a call with `given` uses: `given` completed with `fn`'s defaults
    (callbacks left out), for a summary that records every parameter."""
    params = inspect.signature(fn).parameters
    return {k: given.get(k, p.default) for k, p in params.items() if p.default is not p.empty and k != "progress"}


def split_robots(n: int, holdout: float) -> tuple[np.ndarray, np.ndarray]:
    """Training and held-out robot indices: the last round(n * holdout) robots (>= 1 when holdout
    > 0) are held out; at least one robot trains."""
    if not 0 <= holdout < 1:
        raise ValueError(f"holdout must lie in [0, 1), got {holdout}")
    k = 0 if holdout == 0 else max(1, round(n * holdout))
    if n - k < 1:
        raise ValueError(f"a held-out fraction of {holdout} leaves no training robot among {n}")
    return np.arange(n - k), np.arange(n - k, n)


def tune_fleet(
    method: Literal["grid", "gradient"],
    inputs: ObserverInputs,
    truth: ContactTruth,
    t,
    mode: Literal["plain", "mixed"] = "mixed",
    holdout: float = 0.25,
    spec: GridSpec | None = None,
    chunk: int = 256,
    steps: int = 200,
    start: ObserverParams | None = None,
    progress=None,
    **options,
) -> tuple[ObserverParams, dict]:
    """Tune on the training robots; return the best params and a JSON-ready summary with scores of
    the paper's defaults and of the result on the training and held-out robots, and wall times."""
    n = inputs.p.shape[0]
    train, held = split_robots(n, holdout)
    tr_in, tr_truth = select_robots(inputs, train), select_robots(truth, train)
    paper = ObserverParams.paper(inputs.n_feet, mode)
    summary: dict = {
        "method": method,
        "mode": mode,
        "holdout": holdout,
        "robots_train": int(train.size),
        "robots_heldout": int(held.size),
        "samples": int(t.size),
        "duration_s": float(t[-1] - t[0]),
    }
    if method == "grid":
        spec = GridSpec.default() if spec is None else spec
        res = grid_search(spec, paper, tr_in, tr_truth, t, chunk, progress=progress, **options)
        best = res.best
        summary.update(
            configurations=spec.size,
            chunk=chunk,
            best_index=res.index,
            wall_s=res.wall_s,
            grid={f.name: list(getattr(spec, f.name)) for f in dataclasses.fields(spec)},
            options=call_options(grid_search, {"chunk": chunk, **options}),
            base_params=observer_params_dict(paper),
        )
    elif method == "gradient":
        start = paper if start is None else start
        res = gradient_tune(start, tr_in, tr_truth, steps, progress=progress, **options)
        best = res.best
        summary.update(
            steps=int(res.loss.size),
            best_step=res.best_step,
            stopped=res.stopped,
            wall_s=res.wall_s,
            loss=[float(x) for x in res.loss],
            options=call_options(gradient_tune, {"steps": steps, **options}),
            start_params=observer_params_dict(start),
        )
    else:
        raise ValueError(f"method must be grid or gradient, got {method!r}")
    summary["params"] = observer_params_dict(best)
    parts = {"train": train} | ({"heldout": held} if held.size else {})
    for name, idx in parts.items():
        sub_in, sub_truth = select_robots(inputs, idx), select_robots(truth, idx)
        summary[f"paper_{name}"] = fleet_scores(paper, sub_in, sub_truth, t)
        summary[f"tuned_{name}"] = fleet_scores(best, sub_in, sub_truth, t)
    return best, summary
