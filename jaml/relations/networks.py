"""The networks of AML (paper §3.2, App. B.3.1): relations g_k and restricted syzygies f."""

from __future__ import annotations

import math

import flax.linen as nn
import jax
import jax.numpy as jnp


def fan_in_uniform(scale: float = 1.0):
    """U(−s/√fan_in, s/√fan_in), the reference's (PyTorch `nn.Linear`) default for W and b.

    For the bias Flax passes no fan-in, so the bias initializer is built per layer with it.
    """

    def init(key, shape, dtype=jnp.float32):
        bound = scale / math.sqrt(shape[0])
        return jax.random.uniform(key, shape, dtype, -bound, bound)

    return init


def _bias_init(fan_in: int):
    def init(key, shape, dtype=jnp.float32):
        bound = 1.0 / math.sqrt(fan_in)
        return jax.random.uniform(key, shape, dtype, -bound, bound)

    return init


class _MLP(nn.Module):
    """Fully connected stack on the last axis with PyTorch-style fan-in init."""

    width: int
    depth: int
    out: int
    activation: str

    @nn.compact
    def __call__(self, x):
        act = {"tanh": jnp.tanh, "elu": nn.elu}[self.activation]
        fan_in = x.shape[-1]
        for i in range(self.depth):
            x = act(
                nn.Dense(self.width, kernel_init=fan_in_uniform(), bias_init=_bias_init(fan_in),
                         name=f"hidden{i}")(x)
            )
            fan_in = self.width
        return nn.Dense(self.out, kernel_init=fan_in_uniform(), bias_init=_bias_init(fan_in),
                        name="out")(x)


class Relation(nn.Module):
    """g: R^D → (−1, 1). `depth` tanh hidden layers of `width` units, tanh on the output."""

    width: int
    depth: int = 3

    @nn.compact
    def __call__(self, tau):
        """tau [..., D] → g(tau) [...]."""
        return jnp.tanh(_MLP(self.width, self.depth, 1, "tanh", name="mlp")(tau))[..., 0]


class SyzygyCoefficients(nn.Module):
    """The coefficient functions f_1..f_{k−1} of a restricted syzygy, as functions of τ.

    ELU hidden layers; outputs clamped to [−bound, bound] (the reference's hardtanh) so a
    syzygy cannot cancel g_k by blowing up a coefficient where g_j is tiny.
    """

    num_coefficients: int
    width: int = 32
    depth: int = 3
    bound: float = 100.0

    @nn.compact
    def __call__(self, tau):
        """tau [..., D] → f(tau) [..., k−1]."""
        raw = _MLP(self.width, self.depth, self.num_coefficients, "elu", name="mlp")(tau)
        return jnp.clip(raw, -self.bound, self.bound)


def relation_width(index: int, base_width: int, max_width: int) -> int:
    """Hidden width of relation g_{index+1}: base · 2^index, capped (App. B.3.1: 4, 8, 16, … 256)."""
    return min(base_width * 2 ** min(index, 30), max_width)
