"""Gradient tuning of the observer's numbers through a differentiable surrogate of contact quality.

    loss = mean BCE(contact_soft, gt_contact) + force_weight mean((f_filt - clip(f_true, 0, f_max))^2) / force_scale^2
over valid samples and feet of the training robots, with contact_soft = sigmoid((f_filt - threshold)
/ temperature). Parameters are unconstrained (`Unconstrained`): bandwidth = exp(u), alpha =
sigmoid(u) per foot, threshold_on = softplus(u) per foot, threshold_off = threshold_on sigmoid(u)
per foot (so 0 < off <= on). Adam (optax); stops after `steps` or when the loss has not improved by
a relative `tolerance` for `patience` steps; returns the parameters of the lowest loss.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from jaxquad.estimate.tune.observer_inputs import ContactTruth, ObserverInputs
from jaxquad.estimate.tune.observer_scan import _observer_scan
from jaxquad.kernels import ContactEstimate, ObserverParams


def _softplus_inv(x):
    return x + jnp.log(-jnp.expm1(-x))


class Unconstrained(eqx.Module):
    """Unconstrained coordinates of the tuned observer numbers (see the module docstring)."""

    log_bandwidth: Float[Array, ""]
    logit_alpha: Float[Array, "F"]
    raw_threshold_on: Float[Array, "F"]
    logit_off_ratio: Float[Array, "F"]

    @classmethod
    def from_params(cls, params: ObserverParams, eps: float = 1e-4) -> Unconstrained:
        ratio = params.threshold_off / params.threshold_on
        return cls(
            log_bandwidth=jnp.log(params.bandwidth),
            logit_alpha=jax.scipy.special.logit(jnp.clip(params.alpha, eps, 1 - eps)),
            raw_threshold_on=_softplus_inv(jnp.maximum(params.threshold_on, eps)),
            logit_off_ratio=jax.scipy.special.logit(jnp.clip(ratio, eps, 1 - eps)),
        )

    def params(self, base: ObserverParams) -> ObserverParams:
        on = jax.nn.softplus(self.raw_threshold_on)
        return dataclasses.replace(
            base,
            bandwidth=jnp.exp(self.log_bandwidth),
            alpha=jax.nn.sigmoid(self.logit_alpha),
            threshold_on=on,
            threshold_off=on * jax.nn.sigmoid(self.logit_off_ratio),
        )


class LossTerms(eqx.Module):
    bce_sum: Float[Array, ""]
    force_sq_sum: Float[Array, ""]  # N^2
    count: Float[Array, ""]  # valid sample-feet


def _loss_terms(params: ObserverParams, inputs: ObserverInputs, truth: ContactTruth) -> LossTerms:
    zero = jnp.zeros((), jnp.float32)

    def reduce(acc: LossTerms, est: ContactEstimate, truth_k):
        contact, force_z, valid = truth_k
        soft = jnp.clip(est.contact_soft, 1e-6, 1 - 1e-6)
        bce = -jnp.where(contact, jnp.log(soft), jnp.log1p(-soft))
        err = est.force_z_filtered - jnp.clip(force_z, 0.0, params.f_max)
        w = valid.astype(jnp.float32)
        return LossTerms(
            acc.bce_sum + w * bce.sum(), acc.force_sq_sum + w * (err * err).sum(), acc.count + w * contact.shape[-1]
        ), None

    # Rematerialise each step's internals in the backward pass: memory grows with the carry only.
    reduce = jax.checkpoint(reduce)
    return _observer_scan(
        params, inputs, LossTerms(zero, zero, zero), reduce, (truth.contact, truth.force_z, truth.valid)
    )[0]


def surrogate_loss(
    u: Unconstrained,
    base: ObserverParams,
    inputs: ObserverInputs,
    truth: ContactTruth,
    force_weight: float = 0.1,
    force_scale: float = 50.0,
    temperature: float = 2.0,
) -> Float[Array, ""]:
    """The gradient objective over a fleet (inputs with a leading robot axis)."""
    params = dataclasses.replace(u.params(base), soft_temperature=jnp.asarray(temperature, jnp.float32))
    terms = jax.vmap(_loss_terms, in_axes=(None, 0, 0))(params, inputs, truth)
    count = jnp.maximum(terms.count.sum(), 1.0)
    return terms.bce_sum.sum() / count + force_weight * terms.force_sq_sum.sum() / count / force_scale**2


@dataclasses.dataclass(frozen=True)
class GradientResult:
    best: ObserverParams
    loss: np.ndarray  # per step, at the parameters before that step's update
    best_step: int
    stopped: str  # "plateau" or "max_steps"
    wall_s: float


def gradient_tune(
    start: ObserverParams,
    inputs: ObserverInputs,
    truth: ContactTruth,
    steps: int = 200,
    learning_rate: float = 0.05,
    patience: int = 25,
    tolerance: float = 1e-4,
    force_weight: float = 0.1,
    force_scale: float = 50.0,
    temperature: float = 2.0,
    progress: Callable[[int, float], None] | None = None,
) -> GradientResult:
    """Adam on the surrogate loss from `start` (see the module docstring); the returned parameters
    are those of the lowest loss seen."""
    import optax

    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    t0 = time.perf_counter()
    opt = optax.adam(learning_rate)
    u = Unconstrained.from_params(start)
    loss_fn = functools.partial(
        surrogate_loss, force_weight=force_weight, force_scale=force_scale, temperature=temperature
    )

    @jax.jit
    def update(u, opt_state, inputs, truth):
        loss, grad = jax.value_and_grad(loss_fn)(u, start, inputs, truth)
        grad = jax.tree.map(lambda g: jnp.where(jnp.isfinite(g), g, 0.0), grad)
        upd, opt_state = opt.update(grad, opt_state, u)
        return optax.apply_updates(u, upd), opt_state, loss

    opt_state = opt.init(u)
    history, best_u, best_loss, best_step, stopped = [], u, np.inf, 0, "max_steps"
    for k in range(steps):
        new_u, opt_state, loss = update(u, opt_state, inputs, truth)
        loss = float(loss)
        if not np.isfinite(loss):
            raise ValueError(f"gradient tuning: the loss became {loss} at step {k}")
        history.append(loss)
        if loss < best_loss * (1 - tolerance):
            best_u, best_loss, best_step = u, loss, k
        if progress is not None:
            progress(k + 1, loss)
        if k - best_step >= patience:
            stopped = "plateau"
            break
        u = new_u
    best = best_u.params(start)
    return GradientResult(
        best=best, loss=np.asarray(history), best_step=best_step, stopped=stopped, wall_s=time.perf_counter() - t0
    )
