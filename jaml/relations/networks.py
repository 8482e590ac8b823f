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


@jax.custom_jvp
def tanh(x):
    """tanh whose derivative is written t·(1 − tanh²x).

    jax's own rule, t·(1 + y)(1 − y), is equivalent, but AML differentiates through input
    gradients (a second derivative of every tanh), and the one-product form compiles to a
    measurably faster step on CPU (benchmarks/relations_fit.py).
    """
    return jnp.tanh(x)


@tanh.defjvp
def _tanh_jvp(primals, tangents):
    (x,), (t,) = primals, tangents
    y = jnp.tanh(x)
    return y, t * (1.0 - y * y)


class _MLP(nn.Module):
    """Fully connected stack on the last axis with PyTorch-style fan-in init."""

    width: int
    depth: int
    out: int
    activation: str

    @nn.compact
    def __call__(self, x):
        act = {"tanh": tanh, "elu": nn.elu}[self.activation]
        fan_in = x.shape[-1]
        for i in range(self.depth):
            x = act(
                nn.Dense(
                    self.width,
                    kernel_init=fan_in_uniform(),
                    bias_init=_bias_init(fan_in),
                    name=f"hidden{i}",
                )(x)
            )
            fan_in = self.width
        return nn.Dense(
            self.out, kernel_init=fan_in_uniform(), bias_init=_bias_init(fan_in), name="out"
        )(x)


class Relation(nn.Module):
    """g: R^D → (−1, 1). `depth` tanh hidden layers of `width` units, tanh on the output.

    Rows are processed feature-major (activations [width, N]): with widths of 4–256 and
    batches of 1024, XLA's CPU matmuls and fusions run markedly faster with the batch as the
    contiguous axis. Kernels are stored [out, in] (PyTorch's layout); the API is row-major.
    """

    width: int
    depth: int = 3
    raw: bool = False  # the output before its tanh: the same zero set, never saturated

    @nn.compact
    def __call__(self, tau):
        """tau [..., D] → g(tau) [...] (atanh g(tau) when raw)."""
        lead, dim = tau.shape[:-1], tau.shape[-1]
        h = tau.reshape(-1, dim).T  # [D, N]
        fan_in = dim
        for i in range(self.depth + 1):
            out = self.width if i < self.depth else 1
            name = f"hidden{i}" if i < self.depth else "out"
            kernel = self.param(f"{name}_kernel", _bias_init(fan_in), (out, fan_in))
            bias = self.param(f"{name}_bias", _bias_init(fan_in), (out, 1))
            h = kernel @ h + bias
            if i < self.depth or not self.raw:
                h = tanh(h)
            fan_in = out
        return h[0].reshape(lead)


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
    """Hidden width of g_{index+1}: base · 2^index, capped (App. B.3.1: 4, 8, 16, … 256)."""
    return min(base_width * 2 ** min(index, 30), max_width)
