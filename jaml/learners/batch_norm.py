"""Batch norm over the last axis with its training backward pass written out: Flax's
`nn.BatchNorm` (the same variables, statistics, running averages and forward arithmetic), whose
backward takes its two sums from one read of the incoming gradient, where XLA split autodiff's
into two passes on the GPU (docs/learners.md, "The batch norm's backward").

Shapes: x [..., C], statistics and parameters [C].
"""

from __future__ import annotations

import functools
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp


class BatchNorm(nn.Module):
    """`nn.BatchNorm(axis=-1)`: in training, the batch's mean and variance (float32,
    E[x²] − E[x]² clipped at 0, Flax's fast variance) normalise x and update the running
    averages ("batch_stats" mean and var, by `momentum`); otherwise the running averages
    normalise it. "params" scale (ones) and bias (zeros). The output has `dtype`, or x's type
    promoted with float32 where None, as Flax's."""

    use_running_average: bool
    momentum: float = 0.99
    epsilon: float = 1e-5
    dtype: Any = None

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        shape = (x.shape[-1],)
        ra_mean = self.variable("batch_stats", "mean", lambda s: jnp.zeros(s, jnp.float32), shape)
        ra_var = self.variable("batch_stats", "var", lambda s: jnp.ones(s, jnp.float32), shape)
        scale = self.param("scale", nn.initializers.ones, shape, jnp.float32)
        bias = self.param("bias", nn.initializers.zeros, shape, jnp.float32)
        dtype = jnp.promote_types(x.dtype, jnp.float32) if self.dtype is None else self.dtype
        if self.use_running_average:
            return _affine(x, ra_mean.value, ra_var.value, scale, bias, self.epsilon, dtype)
        y, mean, var = normalize(x, scale, bias, self.epsilon, dtype)
        if not self.is_initializing():
            m = self.momentum
            ra_mean.value = m * ra_mean.value + (1 - m) * mean
            ra_var.value = m * ra_var.value + (1 - m) * var
        return y


def statistics(x: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(mean, variance) [C] of x over every axis but the last, in float32: Flax's
    E[x²] − E[x]², clipped at 0 (rounding can take it below)."""
    axes = tuple(range(x.ndim - 1))
    xf = x.astype(jnp.float32)
    mean = jnp.mean(xf, axes)
    return mean, jnp.maximum(0.0, jnp.mean(jnp.square(xf), axes) - jnp.square(mean))


def _affine(x, mean, var, scale, bias, epsilon, dtype):
    """(x − mean)·(rsqrt(var + ε)·scale) + bias in float32, then `dtype`: Flax's order."""
    return ((x.astype(jnp.float32) - mean) * (jax.lax.rsqrt(var + epsilon) * scale)
            + bias).astype(dtype)


@functools.partial(jax.custom_vjp, nondiff_argnums=(3, 4))
def normalize(x: jax.Array, scale: jax.Array, bias: jax.Array, epsilon: float,
              dtype) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(y, mean, var): x normalised by its own batch statistics (`statistics`), scaled and
    shifted. Its backward pass is the batch norm's closed form: with x̂ = (x − mean)·r,
    r = rsqrt(var + ε) and N the reduced size, dbias = Σ g, dscale = Σ g·x̂ and
    dx = scale·r·(g − dbias/N − x̂·dscale/N), two sums of one pass over g and x. The
    statistics take no gradient (they feed only the running averages)."""
    return _normalize_fwd(x, scale, bias, epsilon, dtype)[0]


def _normalize_fwd(x, scale, bias, epsilon, dtype):
    mean, var = statistics(x)
    y = _affine(x, mean, var, scale, bias, epsilon, dtype)
    return (y, mean, var), (x, mean, jax.lax.rsqrt(var + epsilon), scale)


def _normalize_bwd(epsilon, dtype, residuals, cotangents):
    x, mean, r, scale = residuals
    g = cotangents[0].astype(jnp.float32)
    axes = tuple(range(x.ndim - 1))
    n = x.size // x.shape[-1]
    x_hat = (x.astype(jnp.float32) - mean) * r
    dbias = jnp.sum(g, axes)
    dscale = jnp.sum(g * x_hat, axes)
    dx = (scale * r) * (g - dbias / n - x_hat * (dscale / n))
    return dx.astype(x.dtype), dscale, dbias


normalize.defvjp(_normalize_fwd, _normalize_bwd)
