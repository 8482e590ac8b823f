"""The encoder's k4 s2 p1 convolution as a Pallas (Triton) kernel whose epilogue also returns the
per-channel sum and sum of squares of its float32 accumulator: a training batch norm's
statistics without a second read of the output (docs/learners.md, "Roofline").

An implicit GEMM on the NHWC input as it lies in memory (no padded or space-to-depth copy): each
program owns `block_m` output pixels × `block_o` channels and loops over the 16 taps × the input
channels in chunks of `block_k`; a tap's rows are the pixels at (2i + kh − 1, 2j + kw − 1), those
on the padding masked to zero. Not wired into the learner.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as plgpu


def _div(a, d: int):
    """a // d of non-negative int32 (lax's truncating division: no sign corrections)."""
    return jax.lax.div(a, jnp.int32(d))


def _rem(a, d: int):
    return jax.lax.rem(a, jnp.int32(d))


def _kernel(x_ref, w_ref, y_ref, s_ref, q_ref, *, h, w, c, block_m, block_k, span):
    ho, wo = h // 2, w // 2
    r = pl.program_id(0) * block_m + jnp.arange(block_m, dtype=jnp.int32)  # output pixels
    n, i, j = _div(r, ho * wo), _rem(_div(r, wo), ho), _rem(r, wo)
    top, left = 2 * i - 1, 2 * j - 1  # input row and column of tap (0, 0)
    base = n * (h * w) + top * w + left
    chunks = span * c // block_k  # a load: `span` taps side by side, adjacent in memory
    o0 = pl.program_id(1) * y_ref.shape[1]
    cols = jnp.arange(block_k, dtype=jnp.int32)
    zero = jnp.zeros((), x_ref.dtype)

    def step(s, acc):
        group, k0 = _div(s, chunks), _rem(s, chunks) * block_k
        kh, kw = _div(group, 4 // span), _rem(group, 4 // span) * span
        hh, ww = top + kh, left + kw
        if span == 1:
            valid = (hh >= 0) & (hh < h) & (ww >= 0) & (ww < w)
            rows = jnp.where(valid, base + kh * w + kw, 0)
            a = plgpu.load(x_ref.at[rows[:, None], (k0 + cols)[None, :]],
                           mask=valid[:, None], other=zero)
        else:  # columns kw … kw + span − 1: rows kk // C of the chunk, channels kk % C
            kk = k0 + cols
            dw = _div(kk, c)[None, :]
            valid = ((hh >= 0) & (hh < h))[:, None] & (ww[:, None] + dw >= 0) & (
                ww[:, None] + dw < w)
            a = plgpu.load(x_ref.at[(base + kh * w + kw)[:, None] + dw, _rem(kk, c)[None, :]],
                           mask=valid, other=zero)
        b = w_ref[pl.ds(group * span * c + k0, block_k), pl.ds(o0, y_ref.shape[1])]
        return acc + plgpu.dot(a, b)

    acc = jax.lax.fori_loop(0, 16 // span * chunks, step, jnp.zeros(y_ref.shape, jnp.float32))
    y_ref[...] = acc.astype(y_ref.dtype)
    s_ref[...] = jnp.sum(acc, axis=0, keepdims=True)
    q_ref[...] = jnp.sum(acc * acc, axis=0, keepdims=True)


@functools.partial(jax.jit, static_argnames=("block_m", "block_o", "block_k", "num_warps",
                                             "num_stages", "span", "interpret"))
def halving_conv_stats(x: jax.Array, kernel: jax.Array, *, block_m: int = 128,
                       block_o: int = 128, block_k: int = 64, num_warps: int = 4,
                       num_stages: int = 3, span: int = 1, interpret: bool = False):
    """[N, H, W, C] × [4, 4, C, O] (k4 s2 p1, NHWC / HWIO) → (y [N, H/2, W/2, O] in x's dtype,
    Σ y [O], Σ y² [O]): the sums over N·H/2·W/2 of the float32 accumulator, before rounding.

    Every block size a power of two: block_m divides N·H/2·W/2, block_o divides O, block_k
    divides span·C (and is ≥ 16, as are the others, for the matrix units). span: taps per load,
    1 or 2 (a tap and its right neighbour: two adjacent pixels, 2·C contiguous elements).
    """
    n, h, w, c = x.shape
    o = kernel.shape[-1]
    if kernel.shape != (4, 4, c, o) or h % 2 or w % 2:
        raise ValueError(f"expected [N, 2H, 2W, C] × [4, 4, C, O], got {x.shape} × {kernel.shape}")
    m = n * (h // 2) * (w // 2)
    block_o, block_k = min(block_o, o), min(block_k, span * c)
    if span not in (1, 2) or m % block_m or o % block_o or span * c % block_k:
        raise ValueError(f"blocks ({block_m}, {block_o}, {block_k}) do not divide ({m}, {o}, {c})")
    grid = (m // block_m, o // block_o)
    body = functools.partial(_kernel, h=h, w=w, c=c, block_m=block_m, block_k=block_k,
                             span=span)
    partial = pl.BlockSpec((1, block_o), lambda i, k: (i, k))
    y, s, q = pl.pallas_call(
        body,
        grid=grid,
        in_specs=[pl.no_block_spec, pl.no_block_spec],
        out_specs=[pl.BlockSpec((block_m, block_o), lambda i, k: (i, k)), partial, partial],
        out_shape=[jax.ShapeDtypeStruct((m, o), x.dtype),
                   *[jax.ShapeDtypeStruct((grid[0], o), jnp.float32)] * 2],
        compiler_params=plgpu.CompilerParams(num_warps=num_warps, num_stages=num_stages),
        interpret=interpret,
    )(x.reshape(n * h * w, c), kernel.reshape(16 * c, o))
    return y.reshape(n, h // 2, w // 2, o), s.sum(0), q.sum(0)
