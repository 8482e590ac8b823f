"""The shared networks (docs/reference/suite.md §4): conv encoder, deconv decoder, MLP/RNN
trunks, Gaussian heads.

Shapes: N frames (B·T flattened), B batch, T time, F conv feature, Z latent.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaml.configs.learners import UPSAMPLE_FORMS
from jaml.learners.batch_norm import BatchNorm

# PyTorch BatchNorm2d defaults (momentum 0.1 on the new statistic, eps 1e-5), as in the reference.
_BN = {"momentum": 0.9, "epsilon": 1e-5}
# PyTorch's k4 s2 p1 convolution halves the size.
_HALVE = ((1, 1), (1, 1))
_NHWC = ("NHWC", "HWIO", "NHWC")
# Few channels: a kernel gradient over up to this many input channels is one patches matmul
# (`_halving_kernel_grad`), a transposed convolution onto up to this many outputs one 2×2
# convolution onto the four phases (`_phase_conv`).
_FEW_CHANNELS = 4
# cuDNN's tensor-core convolutions take channels in multiples of this and pad others with a slow
# layout kernel of their own on every call: off the CPU, the frames' layers are reformulated
# onto such channel counts (`_blocks_conv`, `_phase_conv`; docs/learners.md "Roofline").
_CUDNN_CHANNELS = 8
# The most steps of a recurrent layer unrolled into one loop iteration off the CPU (`scan_unroll`):
# past 8 the layers ran no faster, and unrolling all of a sequence's steps multiplied the compile
# time of the analysis' encoders (docs/learners.md, DSA).
_MAX_UNROLL = 8


def _use_cpu_kernels(cpu_kernels: bool | None) -> bool:
    """None: the CPU formulation when tracing for the CPU backend (the GPU path is XLA's own)."""
    return _on_cpu() if cpu_kernels is None else cpu_kernels


def _on_cpu() -> bool:
    return jax.default_backend() == "cpu"


def _pad_channels(a: jax.Array, axis: int) -> jax.Array:
    """a with zeros appended along axis up to a multiple of `_CUDNN_CHANNELS`."""
    widths = [(0, 0)] * a.ndim
    widths[axis] = (0, -a.shape[axis] % _CUDNN_CHANNELS)
    return jnp.pad(a, widths)


def _xla_conv(x, kernel, strides, padding):
    return lax.conv_general_dilated(x, kernel, strides, padding, dimension_numbers=_NHWC)


def _swap_io(kernel: jax.Array) -> jax.Array:
    """[kh, kw, I, O] → [kh, kw, O, I]: the adjoint map's kernel (k4 s2 p1 conv ↔ its transpose)."""
    return kernel.transpose(0, 1, 3, 2)


def _halving_kernel_grad(x: jax.Array, g: jax.Array) -> jax.Array:
    """x [N, 2H, 2W, C], g [N, H, W, O] → [4, 4, C, O]: Σ_{n,m} x_pad[n, 2m + k]ᵀ g[n, m].

    The kernel gradient of the k4 s2 p1 convolution; `_doubling`'s is the same sum with the
    roles swapped. Few channels (the frames' 3): x's 4×4 patches [N·H·W, 16·C] times g, one
    matmul (XLA's convolution transposes x to [C, …, N], slower on the CPU; see
    docs/notes/learners.md); otherwise as XLA computes it, a convolution whose "kernel" is g.
    """
    n, h, w, o = g.shape
    c = x.shape[-1]
    if c <= _FEW_CHANNELS:
        xp = jnp.pad(x, ((0, 0), (1, 1), (1, 1), (0, 0)))
        s2d = xp.reshape(n, h + 1, 2, w + 1, 2, c).transpose(0, 1, 3, 2, 4, 5)
        s2d = s2d.reshape(n, h + 1, w + 1, 4 * c)  # [N, H+1, W+1, (ph, pw, C)]
        patches = jnp.concatenate([s2d[:, a:a + h, b:b + w] for a in (0, 1) for b in (0, 1)],
                                  axis=-1).reshape(-1, 16 * c)  # [(N, H, W), (a, b, ph, pw, C)]
        dk = lax.dot_general(patches, g.reshape(-1, o), (((0,), (0,)), ((), ())))
        return dk.reshape(2, 2, 2, 2, c, o).transpose(0, 2, 1, 3, 4, 5).reshape(4, 4, c, o)
    kernel = jax.ShapeDtypeStruct((4, 4, c, o), g.dtype)
    return jax.linear_transpose(lambda k: _xla_conv(x, k, (2, 2), _HALVE), kernel)(g)[0]


# For a k4 s2 p1 transposed convolution, output 2m + r sums input m − 1 + j times kernel tap
# _TAPS[r][j] (4 = no tap): out[2m] = x[m−1]·w3 + x[m]·w1, out[2m+1] = x[m]·w2 + x[m+1]·w0.
_TAPS = np.array([[3, 1, 4], [4, 2, 0]])
# The same sums as 2×2 windows over x padded by one (x_pad[q] = x[q − 1]): output 2m + r is the
# window at q = m + r, (x[m + r − 1], x[m + r]), times taps _TAPS2[j][r] = 3 − 2j − r.
_TAPS2 = np.array([[3, 2], [1, 0]])


def _phase_conv(x: jax.Array, kernel: jax.Array) -> jax.Array:
    """[N, H, W, I] → [N, 2H, 2W, O]: the k4 s2 p1 transposed convolution as 2×2 convolutions of
    x onto the four output phases (16 taps per output, against the sub-pixel form's 36).

    One convolution per phase (r_h, r_w), x padded by (1 − r, r), then interleaved; with few
    output channels one convolution of x padded by one onto all four ((H+1)(W+1) windows), each
    phase read off at its own offset, keeps the matmul wide (docs/notes/learners.md).
    """
    n, h, w, i = x.shape
    o = kernel.shape[-1]
    k2 = kernel[_TAPS2[:, None, :, None], _TAPS2[None, :, None, :]]  # [jh, jw, rh, rw, I, O]
    if o > _FEW_CHANNELS:
        y = jnp.stack([jnp.stack([
            _xla_conv(x, k2[:, :, rh, rw], (1, 1), ((1 - rh, rh), (1 - rw, rw)))
            for rw in (0, 1)], axis=3) for rh in (0, 1)], axis=2)  # [N, H, rh, W, rw, O]
        return y.reshape(n, 2 * h, 2 * w, o)
    k2 = k2.transpose(0, 1, 4, 2, 3, 5).reshape(2, 2, i, 4 * o)
    if not _on_cpu():  # 4·O outputs padded to a multiple of 8 (`_CUDNN_CHANNELS`)
        k2 = _pad_channels(k2, 3)
    y = _xla_conv(x, k2, (1, 1), _HALVE)[..., :4 * o].reshape(n, h + 1, w + 1, 2, 2, o)
    y = jnp.stack([jnp.stack([y[:, rh:rh + h, rw:rw + w, rh, rw] for rw in (0, 1)], axis=3)
                   for rh in (0, 1)], axis=2)  # [N, H, rh, W, rw, O]
    return y.reshape(n, 2 * h, 2 * w, o)


def _blocks_conv(x: jax.Array, kernel: jax.Array) -> jax.Array:
    """[N, 2H, 2W, C] × [4, 4, C, O] → [N, H, W, O]: the k4 s2 p1 convolution as a k2 s1
    convolution of the padded input's 2×2 blocks (4·C channels, padded to a multiple of 8): the
    same taps, on channels cuDNN's kernels take as they are (the GPU's form for few C)."""
    n, h2, w2, c = x.shape
    h, w = h2 // 2 + 1, w2 // 2 + 1
    xp = jnp.pad(x, ((0, 0), (1, 1), (1, 1), (0, 0)))
    blocks = xp.reshape(n, h, 2, w, 2, c).transpose(0, 1, 3, 2, 4, 5).reshape(n, h, w, 4 * c)
    k2 = kernel.reshape(2, 2, 2, 2, c, -1).transpose(0, 2, 1, 3, 4, 5).reshape(2, 2, 4 * c, -1)
    return _xla_conv(_pad_channels(blocks, 3), _pad_channels(k2, 2), (1, 1), ((0, 0), (0, 0)))


def _k4s2(x: jax.Array, kernel: jax.Array) -> jax.Array:
    """The k4 s2 p1 convolution of even sizes: `_blocks_conv` off the CPU for few channels."""
    if x.shape[-1] <= _FEW_CHANNELS and not _on_cpu():
        return _blocks_conv(x, kernel)
    return _xla_conv(x, kernel, (2, 2), _HALVE)


# The phase pair: the k4 s2 p1 convolution ("halving", the encoder's on the CPU) and its
# transpose ("doubling", PyTorch's ConvTranspose2d(4, 2, 1), the decoder's on every backend) are
# each other's input gradients, so each one's backward pass runs the other's forward pass, and
# both kernel gradients are `_halving_kernel_grad`. XLA's own input gradients are input-dilated
# convolutions, which its CPU backend runs on a slow generic path (docs/notes/learners.md).
@jax.custom_vjp
def _halving(x: jax.Array, kernel: jax.Array) -> jax.Array:
    return _k4s2(x, kernel)


@jax.custom_vjp
def _doubling(x: jax.Array, kernel: jax.Array) -> jax.Array:
    return _phase_conv(x, kernel)


def _dilated(x: jax.Array, kernel: jax.Array) -> jax.Array:
    """The k4 s2 p1 transposed convolution as XLA's input-dilated convolution: the flipped
    kernel over x dilated by 2, padded by k − 1 − p = 2 (on a GPU, cuDNN's backward-data
    kernel, writing each output once)."""
    return lax.conv_transpose(x, kernel[::-1, ::-1], (2, 2), ((2, 2), (2, 2)),
                              dimension_numbers=_NHWC)


# `_dilated` with the phase pair's backward pass (upsample form "pair").
_doubling_dilated = jax.custom_vjp(_dilated)


def _halving_bwd(res, g):
    x, kernel = res
    return _doubling(g, _swap_io(kernel)), _halving_kernel_grad(x, g)


def _doubling_bwd(res, g):
    x, kernel = res
    return _halving(g, _swap_io(kernel)), _swap_io(_halving_kernel_grad(g, x))


for _f, _bwd in ((_halving, _halving_bwd), (_doubling, _doubling_bwd),
                 (_doubling_dilated, _doubling_bwd)):  # each saves its inputs for the backward
    _f.defvjp(lambda x, kernel, f=_f: (f(x, kernel), (x, kernel)), _bwd)
del _f, _bwd


@jax.custom_vjp
def elu(x: jax.Array) -> jax.Array:
    """`nn.elu`, whose backward pass reads its output alone: d elu / dx is 1 above zero and
    exp(x) = elu(x) + 1 below, which is how JAX differentiates `expm1` too, so the gradients are
    `nn.elu`'s bit for bit. Autodiff of `nn.elu` keeps expm1's output as a second
    activation-sized array for the backward pass; this keeps only the output, which the next
    layer keeps anyway (docs/learners.md, "The ELU's residual")."""
    return nn.elu(x)


def _elu_fwd(x):
    y = nn.elu(x)
    return y, y


def _elu_bwd(y, g):
    return (g * jnp.where(y > 0, 1, y + 1).astype(g.dtype),)


elu.defvjp(_elu_fwd, _elu_bwd)


def conv2d(x: jax.Array, kernel: jax.Array, strides: tuple[int, int] = (1, 1),
           padding=((0, 0), (0, 0)), cpu_kernels: bool | None = None) -> jax.Array:
    """[N, H, W, I] × [kh, kw, I, O] → [N, H', W', O]: `lax.conv_general_dilated`, NHWC/HWIO.

    cpu_kernels (None: when the default backend is the CPU) computes the encoder's two kinds
    differently, to float32 rounding: k4 s2 p1 on even sizes as `_halving` (its input gradient a
    transposed-convolution forward pass), a kernel covering the whole input (k4 s1 p0 onto 1×1)
    as one matmul. Otherwise (the GPU) k4 s2 p1 on even sizes and few channels (the frames') is
    `_blocks_conv` and its autodiff. Other convolutions are the plain convolution and its
    autodiff.
    """
    strides, padding = tuple(strides), tuple(tuple(p) for p in padding)
    if _use_cpu_kernels(cpu_kernels):
        (kh, kw), (h, w) = kernel.shape[:2], x.shape[1:3]
        if (kh, kw, strides, padding) == (4, 4, (2, 2), _HALVE) and h % 2 == w % 2 == 0:
            return _halving(x, kernel)
        if (kh, kw) == (h, w) and padding == ((0, 0), (0, 0)):
            out = x.reshape(x.shape[0], -1) @ kernel.reshape(-1, kernel.shape[-1])
            return out.reshape(x.shape[0], 1, 1, -1)
    elif (kernel.shape[:2], strides, padding) == ((4, 4), (2, 2), _HALVE) and \
            x.shape[-1] <= _FEW_CHANNELS and x.shape[1] % 2 == x.shape[2] % 2 == 0:
        return _blocks_conv(x, kernel)
    return _xla_conv(x, kernel, strides, padding)


class Conv(nn.Module):
    """`nn.Conv` without bias (same "kernel" parameter, init and dtype promotion) over `conv2d`."""

    features: int
    kernel_size: tuple[int, int]
    strides: tuple[int, int] = (1, 1)
    padding: tuple[tuple[int, int], tuple[int, int]] = ((0, 0), (0, 0))
    dtype: jnp.dtype | None = None
    cpu_kernels: bool | None = None

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        kernel = self.param("kernel", nn.initializers.lecun_normal(),
                            (*self.kernel_size, x.shape[-1], self.features))
        x, kernel = nn.dtypes.promote_dtype(x, kernel, dtype=self.dtype)
        return conv2d(x, kernel, self.strides, self.padding, self.cpu_kernels)


class ConvEncoder(nn.Module):
    """[N, 64, 64, C] float → [N, F]: conv(k4 s2 p1) → BN → ELU per filter, then k4 s1 p0 to 1×1.

    No biases (each conv feeds a BatchNorm). Default filters 64, 128, 128, 256 → F = 128: the
    reference code's sizes, not the paper's "[64, 64, 128, 256]".
    """

    filters: Sequence[int] = (64, 128, 128, 256)
    features: int = 128
    # The convolutions' input and kernel dtype (bfloat16: mixed precision; parameters, batch
    # norms and everything after them stay float32).
    compute_dtype: jnp.dtype = jnp.float32
    # The CPU formulation of its convolutions (`conv2d`); None: when tracing for the CPU.
    cpu_kernels: bool | None = None
    # The batch norms' and ELUs' output dtype (statistics float32); the feature is float32.
    activation_dtype: jnp.dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        if x.shape[-3:-1] != (64, 64):
            raise ValueError(f"ConvEncoder expects 64×64 frames, got {tuple(x.shape)}")
        for i, f in enumerate(self.filters):
            x = Conv(f, (4, 4), (2, 2), _HALVE, self.compute_dtype, self.cpu_kernels,
                     name=f"conv{i}")(x)
            x = elu(_norm(f"bn{i}", train, self.activation_dtype)(x))
        x = Conv(self.features, (4, 4), dtype=self.compute_dtype, cpu_kernels=self.cpu_kernels,
                 name="conv_out")(x)
        x = elu(_norm("bn_out", train, self.activation_dtype)(x))
        return x.reshape(x.shape[0], self.features).astype(jnp.float32)


def _norm(name: str, train: bool, dtype: jnp.dtype | None) -> BatchNorm:
    """PyTorch's BatchNorm (batch statistics in training, running ones otherwise), its output in
    dtype (None: the input's promoted with float32); statistics and parameters float32 whatever
    dtype is (`batch_norm.BatchNorm`: Flax's, with its backward pass written out)."""
    return BatchNorm(use_running_average=not train, dtype=dtype, name=name, **_BN)


def upsample2x(x: jax.Array, kernel: jax.Array, compute_dtype=None,
               form: str = "auto") -> jax.Array:
    """[N, H, W, I] → [N, 2H, 2W, O]: PyTorch's ConvTranspose2d(k=4, s=2, p=1), kernel [4, 4, I, O].

    out[s·i − p + k] += x[i]·w[k] per axis. form picks the formulation, one function each way:
    "phase" (`_doubling`: a 2×2 convolution of the padded input onto each of the four output
    phases, 16 taps an output, whose input gradient is the k4 s2 p1 convolution's forward pass),
    "subpixel" (one stride-1 3×3 convolution onto the four phases, then depth-to-space: 36 taps
    an output phase against 16 useful), or "dilated" (`lax.conv_transpose`, XLA's input-dilated
    convolution and its autodiff, which XLA's CPU backend runs on a slow generic path), or
    "pair" (that input-dilated convolution forward, the phase pair's backward pass). "auto"
    is "phase" on the CPU and elsewhere for few outputs (the frames' 3), "pair" for more (why:
    docs/learners.md). compute_dtype (e.g.
    bfloat16) is the convolution's input and kernel dtype; None keeps x's.
    """
    if form not in UPSAMPLE_FORMS:
        raise ValueError(f"upsample form must be one of {list(UPSAMPLE_FORMS)}, got {form!r}")
    if compute_dtype is not None:
        x, kernel = x.astype(compute_dtype), kernel.astype(compute_dtype)
    if form == "auto":
        form = "phase" if _on_cpu() or kernel.shape[-1] <= _FEW_CHANNELS else "pair"
    if form == "phase":
        return _doubling(x, kernel)
    if form == "pair":
        return _doubling_dilated(x, kernel)
    if form == "dilated":
        return _dilated(x, kernel)
    n, h, w, i = x.shape
    o = kernel.shape[-1]
    padded = jnp.pad(kernel, ((0, 1), (0, 1), (0, 0), (0, 0)))  # tap index 4 reads zeros
    taps = _TAPS.T  # [j, r]
    k3 = padded[taps[:, None, :, None], taps[None, :, None, :]]  # [jh, jw, rh, rw, I, O]
    k3 = k3.transpose(0, 1, 4, 2, 3, 5).reshape(3, 3, i, 4 * o)
    y = _xla_conv(x, k3, (1, 1), _HALVE)
    y = y.reshape(n, h, w, 2, 2, o).transpose(0, 1, 3, 2, 4, 5)
    return y.reshape(n, 2 * h, 2 * w, o)


class Upsample2x(nn.Module):
    """ConvTranspose2d(k=4, s=2, p=1) with bias, PyTorch semantics; see `upsample2x`."""

    features: int
    compute_dtype: jnp.dtype = jnp.float32
    form: str = "auto"
    # The biased output's dtype.
    dtype: jnp.dtype = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        kernel = self.param("kernel", nn.initializers.lecun_normal(),
                            (4, 4, x.shape[-1], self.features))
        bias = self.param("bias", nn.initializers.zeros, (self.features,))
        y = upsample2x(x, kernel, self.compute_dtype, self.form)
        return y.astype(self.dtype) + bias.astype(self.dtype)


class ConvDecoder(nn.Module):
    """[N, Z] → [N, 64, 64, C] in (0, 1): the latent as a 1×1 image, transposed convolutions up.

    1×1 → 4 (k4 s1 p0) → 8 → 16, each deconv → ELU → BN; → 32 (+ ELU); → 64 (+ Sigmoid): the
    mean of the unit-variance Gaussian likelihood.
    """

    filters: Sequence[int] = (256, 128, 128, 64)
    channels: int = 3
    # As ConvEncoder's: the transposed convolutions' dtype; the output is float32.
    compute_dtype: jnp.dtype = jnp.float32
    # The transposed convolutions' formulation (`upsample2x`'s form; "auto": per backend).
    upsample_form: str = "auto"
    # As ConvEncoder's: the dtype between convolutions; the output is float32.
    activation_dtype: jnp.dtype = jnp.float32

    @nn.compact
    def __call__(self, z: jax.Array, train: bool) -> jax.Array:
        first, *middle, last = self.filters
        dt, at = self.compute_dtype, self.activation_dtype
        # k4 s1 p0 on a 1×1 input is a dense layer onto a 4×4 map (no input dilation).
        x = nn.ConvTranspose(first, (4, 4), padding="VALID", dtype=dt, name="deconv0")(
            z.reshape(z.shape[0], 1, 1, z.shape[-1]))
        x = _norm("bn0", train, at)(elu(x))
        up = functools.partial(Upsample2x, compute_dtype=dt, form=self.upsample_form, dtype=at)
        for i, f in enumerate(middle, start=1):
            x = elu(up(f, name=f"deconv{i}")(x))
            x = _norm(f"bn{i}", train, at)(x)
        x = elu(up(last, name=f"deconv{len(middle) + 1}")(x))
        out = up(self.channels, name="deconv_out", dtype=jnp.float32)(x)
        return nn.sigmoid(out)


class MLP(nn.Module):
    """[..., I] → [..., widths[-1]]: Dense + ELU per width (the reference's 1024 → 512 trunk)."""

    widths: Sequence[int] = (1024, 512)

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for i, w in enumerate(self.widths):
            x = elu(nn.Dense(w, name=f"dense{i}")(x))
        return x


def torch_rnn_init(hidden: int):
    """U(±1/√hidden), PyTorch's LSTM/RNN weight init (the reference's framework).

    Also cheaper than Flax's orthogonal recurrent init: no QR to compile per cell.
    """
    bound = 1.0 / math.sqrt(hidden)

    def init(key, shape, dtype=jnp.float32):
        return jax.random.uniform(key, shape, dtype, -bound, bound)

    return init


def scan_unroll(steps: int, unroll: int | None) -> int:
    """Steps per iteration of a recurrent layer's loop; None: 1 on the CPU, elsewhere the largest
    divisor of `steps` up to `_MAX_UNROLL` (8 of DSA's 24 steps): off the CPU a step is a few
    small kernels and the loop's own work between them dominates (docs/learners.md, DSA)."""
    if unroll is not None:
        return unroll
    if _on_cpu():
        return 1
    return max(d for d in range(1, min(steps, _MAX_UNROLL) + 1) if steps % d == 0)


def _scan_time(step, carry, xs: jax.Array, reverse: bool, unroll: int | None) -> jax.Array:
    """`step` scanned over axis 1 of xs [B, T, ...] (from the last step when `reverse`; outputs
    kept in the inputs' order) → the outputs [B, T, ...]."""
    _, ys = lax.scan(step, carry, jnp.swapaxes(xs, 0, 1), reverse=reverse,
                     unroll=scan_unroll(xs.shape[1], unroll))
    return jnp.swapaxes(ys, 0, 1)


def _projected(layer: nn.Module, x: jax.Array, width: int) -> tuple[jax.Array, jax.Array]:
    """A recurrent layer's parameters (PyTorch's init) and its inputs' projection for every step:
    (x [B, T, I] · input_kernel + bias [B, T, width], recurrent_kernel [hidden, width])."""
    init = torch_rnn_init(layer.hidden)
    w_in = layer.param("input_kernel", init, (x.shape[-1], width))
    w_rec = layer.param("recurrent_kernel", init, (layer.hidden, width))
    bias = layer.param("bias", init, (width,))
    return jnp.dot(x.astype(w_in.dtype), w_in) + bias, w_rec


class LSTM(nn.Module):
    """[B, T, I] → [B, T, hidden]: an LSTM over time with PyTorch's init (one bias) and a zero
    initial state; `reverse` runs it from the last step, outputs in the inputs' order.

    The inputs' projection for every step is one [B·T, I] × [I, 4H] matmul before the scan (and
    its gradient one after), so a step runs one [B, H] × [H, 4H] matmul and the gates: Flax's
    `nn.RNN(OptimizedLSTMCell)`, the same function, runs both matmuls at every step. Gates in
    the order i, f, g, o; c' = f·c + i·g, h' = o·tanh(c').
    """

    hidden: int
    reverse: bool = False
    unroll: int | None = None  # steps per loop iteration (`scan_unroll`)

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        projected, w_rec = _projected(self, x, 4 * self.hidden)

        def step(carry, z_in):
            c, h = carry
            i, f, g, o = jnp.split(z_in + jnp.dot(h, w_rec), 4, axis=-1)
            c = nn.sigmoid(f) * c + nn.sigmoid(i) * jnp.tanh(g)
            h = nn.sigmoid(o) * jnp.tanh(c)
            return (c, h), h

        zeros = jnp.zeros((x.shape[0], self.hidden), projected.dtype)
        return _scan_time(step, (zeros, zeros), projected, self.reverse, self.unroll)


class TanhRNN(nn.Module):
    """[B, T, I] → [B, T, hidden]: h' = tanh(W_i x + b + W_h h) from a zero state, PyTorch's
    init; the inputs' projection hoisted out of the scan as in `LSTM`."""

    hidden: int
    unroll: int | None = None  # steps per loop iteration (`scan_unroll`)

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        projected, w_rec = _projected(self, x, self.hidden)

        def step(h, z_in):
            h = jnp.tanh(z_in + jnp.dot(h, w_rec))
            return h, h

        zeros = jnp.zeros((x.shape[0], self.hidden), projected.dtype)
        return _scan_time(step, zeros, projected, False, self.unroll)


class RNNEncoder(nn.Module):
    """[B, T, I] → [B, T, H]: bidirectional LSTM(H) (the two directions' outputs concatenated),
    then a one-way tanh RNN(H) (SVAE, DSA)."""

    hidden: int = 512
    unroll: int | None = None  # steps per loop iteration of its layers (`scan_unroll`)

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        both = jnp.concatenate([LSTM(self.hidden, unroll=self.unroll, name="forward")(x),
                                LSTM(self.hidden, True, self.unroll, name="backward")(x)],
                               axis=-1)
        return TanhRNN(self.hidden, self.unroll, name="rnn")(both)


class GaussianHead(nn.Module):
    """[..., I] → (μ, logvar) each [..., size]; logvar is clipped to ±logvar_limit (Hardtanh).

    mu_activation: "none", "elu" (the reference's EncoderDynamic quirk when mu_nl is set) or
    "sigmoid" (DSA's static posterior and dynamic prior).
    """

    size: int
    mu_activation: str = "none"
    logvar_limit: float = 6.0

    @nn.compact
    def __call__(self, h: jax.Array) -> tuple[jax.Array, jax.Array]:
        act = {"none": lambda v: v, "elu": elu, "sigmoid": nn.sigmoid}[self.mu_activation]
        mu = act(nn.Dense(self.size, name="mu")(h))
        logvar = jnp.clip(nn.Dense(self.size, name="logvar")(h), -self.logvar_limit,
                          self.logvar_limit)
        return mu, logvar
