"""The encoder's middle convolutions with their batch norms' statistics: XLA's convolution then its
float32 sums (what the learner runs) against a Pallas kernel that returns the sums from its
epilogue (`halving_conv_stats`, below; not wired into the learner), beside each layer's
roofline bound.

    python benchmarks/conv_bn_kernel.py [--frames 1024] [--layers conv1 conv2 conv3]
        [--reps 7] [--steps 20] [--matmul-size N] [--copy-mib M] [--interpret] [--no-record]

Per layer (k4 s2 p1, bfloat16 input and kernel, float32 accumulation, bfloat16 output): XLA's
convolution alone (the learner's `lax.conv_general_dilated`); the same followed by the float32
sum and sum of squares over N·H·W (a training batch norm's statistics); and the Pallas kernel at
each block shape and Triton setting of a small sweep, the fastest of which is recorded. Steady
state: median over `reps` blocked calls of `steps` calls each, compile apart. The bound is
max(FLOPs / matmul ceiling, bytes / copy bandwidth), FLOPs `benchmarks/flops.py`'s (taps on real
input), bytes the input, kernel and output once each; the bfloat16 n³ matmul ceiling and the copy
bandwidth are measured in the same run (`learner_roofline`'s). --interpret runs the kernel in
Pallas's interpreter (a CPU check at small sizes, nothing recorded).
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as plgpu

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import flops, harness
from benchmarks.learner_roofline import copy_bandwidth
from benchmarks.learner_throughput import matmul_ceiling
from jaml.learners import networks

# Per layer: input [H, W, C] per frame, output channels.
LAYERS = {"conv1": ((32, 32, 64), 128), "conv2": ((16, 16, 128), 128),
          "conv3": ((8, 8, 128), 256)}
# (taps per load, block_m, block_o, block_k, num_warps, num_stages); those that do not fit a
# layer are skipped.
SWEEP = [(1, 128, 128, 64, 4, 3), (1, 128, 128, 64, 4, 2), (1, 128, 128, 64, 8, 3),
         (1, 256, 128, 64, 8, 3), (1, 128, 128, 32, 4, 5), (2, 128, 128, 64, 4, 3),
         (2, 128, 128, 64, 4, 4), (2, 128, 128, 128, 4, 3), (2, 128, 128, 128, 4, 2),
         (2, 128, 128, 128, 8, 3), (2, 256, 128, 64, 8, 3), (2, 256, 128, 128, 8, 3)]
NOTES = ("The encoder's middle k4 s2 p1 convolutions with a training batch norm's statistics "
         "(bfloat16 in, float32 sum and sum of squares per channel): XLA's convolution alone, "
         "then with the sums, and a Pallas kernel returning the sums from its epilogue (the "
         "fastest of a small sweep of blocks, warps and stages), beside the layer's forward "
         "bound max(FLOPs / bf16 matmul ceiling, bytes / copy bandwidth) measured in the same "
         "run (benchmarks/conv_bn_kernel.py).")


# The encoder's k4 s2 p1 convolution as a Pallas (Triton) kernel whose epilogue also returns the
# per-channel sum and sum of squares of its float32 accumulator: a training batch norm's
# statistics without a second read of the output (docs/learners.md, "Roofline").
#
# An implicit GEMM on the NHWC input as it lies in memory (no padded or space-to-depth copy): each
# program owns `block_m` output pixels × `block_o` channels and loops over the 16 taps × the input
# channels in chunks of `block_k`; a tap's rows are the pixels at (2i + kh − 1, 2j + kw − 1), those
# on the padding masked to zero. Not wired into the learner.


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


def xla_conv(x, w):
    return networks._xla_conv(x, w, (2, 2), networks._HALVE)


def xla_conv_stats(x, w):
    """The learner's forward: XLA's convolution, then the batch norm's float32 sums."""
    y = xla_conv(x, w)
    yf = y.astype(jnp.float32)
    return y, yf.sum((0, 1, 2)), (yf * yf).sum((0, 1, 2))


def _diffs(out, ref) -> tuple[float, float]:
    """(max |Δy| / max |y|, max over channels of |Δ sums| / Σ |y| or Σ y²)."""
    y, s, q = (np.asarray(a, np.float32) for a in out)
    ry, rs, rq = (np.asarray(a, np.float32) for a in ref)
    mag = np.abs(ry).reshape(-1, ry.shape[-1]).sum(0)
    return (float(np.abs(y - ry).max() / np.abs(ry).max()),
            float(max((np.abs(s - rs) / mag).max(), (np.abs(q - rq) / rq).max())))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1024)
    parser.add_argument("--layers", nargs="+", default=list(LAYERS), choices=list(LAYERS))
    parser.add_argument("--reps", type=int, default=7)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--matmul-size", type=int, default=None,
                        help="n of the n³ matmul ceiling (default 8192; 1024 with --interpret)")
    parser.add_argument("--copy-mib", type=int, default=None,
                        help="MiB of the copy (default 2048; 64 with --interpret)")
    parser.add_argument("--sweep-json", default=None, help="also write every variant's row here")
    parser.add_argument("--interpret", action="store_true",
                        help="run the kernel in Pallas's interpreter (CPU check, no record)")
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    ceiling = 1e12 * matmul_ceiling(
        "bfloat16", args.matmul_size or (1024 if args.interpret else 8192))
    bandwidth = copy_bandwidth(args.copy_mib or (64 if args.interpret else 2048))
    print(f"{jax.devices()[0].device_kind}: bf16 matmul {ceiling / 1e12:.3g} TFLOP/s, copy "
          f"{bandwidth / 1e12:.3g} TB/s", flush=True)
    rng = np.random.default_rng(0)
    rows, sweep = [], []
    for layer in args.layers:
        (h, w, c), o = LAYERS[layer]
        x = jnp.asarray(rng.normal(size=(args.frames, h, w, c)), jnp.bfloat16)
        k = jnp.asarray(rng.normal(size=(4, 4, c, o)) / np.sqrt(16 * c), jnp.bfloat16)
        m = args.frames * h * w // 4
        gflop = flops.flops(xla_conv, x, k) / 1e9
        mb = (x.nbytes + k.nbytes + 2 * m * o) / 1e6
        bound_s = max(gflop * 1e9 / ceiling, mb * 1e6 / bandwidth)
        case = f"{layer} [{args.frames}, {h}, {w}, {c}] → {o}, bfloat16"
        base = {"case": case, "gflop": gflop, "mb": mb, "bound_us": 1e6 * bound_s,
                "bound_by": "compute" if gflop * 1e9 / ceiling > mb * 1e6 / bandwidth
                else "memory", "matmul_tflop_per_s": ceiling / 1e12,
                "copy_tb_per_s": bandwidth / 1e12}
        print(f"{layer}: {gflop:.1f} GFLOP, {mb:.0f} MB, bound {1e6 * bound_s:.1f} µs "
              f"({base['bound_by']})", flush=True)
        reference, xla_s = None, None
        for name, fn in [("XLA conv alone", xla_conv), ("XLA conv + f32 sums", xla_conv_stats)]:
            compile_s, s, out = harness.measure_calls(fn, (x, k), args.reps, args.steps)
            if fn is xla_conv_stats:
                reference, xla_s = out, s
            rows.append({**base, "impl": name, "us_per_call": 1e6 * s,
                         "x_bound": s / bound_s, "compile_s": compile_s})
            print(f"  {name:34s} {1e6 * s:8.1f} µs  {s / bound_s:4.2f}× bound "
                  f"(compile {compile_s:.1f} s)", flush=True)
        best = None
        for span, bm, bo, bk, warps, stages in SWEEP:
            if bo > o or bk > span * c or bm > m:
                continue
            config = (f"taps per load {span}, block_m {bm}, block_o {bo}, block_k {bk}, "
                      f"warps {warps}, stages {stages}")

            def fn(x, k, bm=bm, bo=bo, bk=bk, warps=warps, stages=stages, span=span):
                return halving_conv_stats(x, k, block_m=bm, block_o=bo, block_k=bk,
                                          num_warps=warps, num_stages=stages, span=span,
                                          interpret=args.interpret)

            try:
                compile_s, s, out = harness.measure_calls(fn, (x, k), args.reps, args.steps)
            except Exception as e:  # a Triton compile failure: report it, try the next
                print(f"  Pallas {config}: FAILED {type(e).__name__}: "
                      f"{str(e).splitlines()[0][:300] if str(e) else ''}", flush=True)
                sweep.append({"case": case, "config": config, "error": repr(e)[:2000]})
                continue
            y_diff, stats_diff = _diffs(out, reference)
            row = {**base, "impl": "Pallas conv, sums in its epilogue (fastest of the sweep)",
                   "config": config, "us_per_call": 1e6 * s, "x_bound": s / bound_s,
                   "vs_xla_conv_sums": s / xla_s, "compile_s": compile_s,
                   "max_rel_diff_y": y_diff, "max_rel_diff_sums": stats_diff}
            sweep.append(row)
            print(f"  Pallas {config:70s} {1e6 * s:8.1f} µs  {s / bound_s:4.2f}× bound  "
                  f"{s / xla_s:4.2f}× XLA  (compile {compile_s:.1f} s, diff y {y_diff:.1e}, "
                  f"sums {stats_diff:.1e})", flush=True)
            if best is None or s < best["us_per_call"] * 1e-6:
                best = row
        if best is not None:
            rows.append(best)
    print("\nlayer   bound µs  XLA conv µs  XLA conv+sums µs  Pallas µs  Pallas/XLA  config")
    for layer in args.layers:
        mine = [r for r in rows if r["case"].startswith(layer + " ")]
        get = {r["impl"].split(" (")[0]: r for r in mine}
        pallas = get.get("Pallas conv, sums in its epilogue")
        print(f"{layer:7s} {mine[0]['bound_us']:8.1f} {get['XLA conv alone']['us_per_call']:12.1f}"
              f" {get['XLA conv + f32 sums']['us_per_call']:17.1f} "
              + (f"{pallas['us_per_call']:10.1f} {pallas['vs_xla_conv_sums']:11.2f}  "
                 f"{pallas['config']}" if pallas else "   (none ran)"), flush=True)
    if args.sweep_json:
        Path(args.sweep_json).write_text(json.dumps(sweep, indent=1))
    if not (args.no_record or args.interpret):
        harness.record("conv_bn_kernel", rows, notes=NOTES)
    return 0


if __name__ == "__main__":
    sys.exit(main())
