"""Control flow that stays cheap under `vmap`."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool


def run_if(pred: Bool[Array, ""], f, operand):
    """f(operand) if pred else operand, as a loop of 0 or 1 trips. Under `vmap` a `lax.cond` runs both
    branches for every item; this loop runs f only when some item of the batch needs it (and on one
    robot, only when pred holds)."""

    def body(carry):
        # The barrier keeps XLA from hoisting work on a loop-invariant operand out of the loop.
        return carry[0] + 1, f(jax.lax.optimization_barrier(carry[1]))

    trips = pred.astype(jnp.int32)
    return jax.lax.while_loop(lambda c: c[0] < trips, body, (jnp.asarray(0, jnp.int32), operand))[1]
