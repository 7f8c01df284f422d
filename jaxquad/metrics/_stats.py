"""Error statistics over masked arrays (evo's set: rmse, mean, median, population std, min, max)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int


class Stats(eqx.Module):
    """Statistics of n errors; all zero when n == 0 (check n, never NaN)."""

    rmse: Float[Array, "*b"]
    mean: Float[Array, "*b"]
    median: Float[Array, "*b"]
    std: Float[Array, "*b"]
    min: Float[Array, "*b"]
    max: Float[Array, "*b"]
    n: Int[Array, "*b"]

    def to_dict(self) -> dict:
        """Python floats (lists for batched results)."""
        return {k: np.asarray(getattr(self, k)).tolist() for k in ("rmse", "mean", "median", "std", "min", "max")}


def statistics(x: Float[Array, "M"], mask: Bool[Array, "M"] | None = None) -> Stats:
    """Statistics of the entries of x where mask is True (all entries without a mask)."""
    if mask is None:
        mask = jnp.ones(x.shape, bool)
    if x.shape[-1] == 0:
        zero = jnp.zeros((), x.dtype)
        return Stats(zero, zero, zero, zero, zero, zero, jnp.zeros((), jnp.int32))
    n = jnp.sum(mask)
    any_ = n > 0
    denom = jnp.maximum(n, 1).astype(x.dtype)
    xm = jnp.where(mask, x, 0.0)
    mean = jnp.sum(xm) / denom
    rmse = jnp.sqrt(jnp.sum(xm * xm) / denom)
    dev = jnp.where(mask, x - mean, 0.0)
    std = jnp.sqrt(jnp.sum(dev * dev) / denom)
    # Masked entries sort to the end; the median averages the two middle valid entries.
    s = jnp.sort(jnp.where(mask, x, jnp.inf))
    lo = s[jnp.maximum((n - 1) // 2, 0)]
    hi = s[jnp.maximum(n // 2, 0)]
    zero = jnp.zeros((), x.dtype)
    return Stats(
        rmse=rmse,
        mean=mean,
        median=jnp.where(any_, 0.5 * (lo + hi), zero),
        std=std,
        min=jnp.where(any_, s[0], zero),
        max=jnp.where(any_, jnp.max(jnp.where(mask, x, -jnp.inf)), zero),
        n=n,
    )
