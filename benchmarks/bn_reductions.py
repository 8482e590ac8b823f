"""The batch norms' channel reductions against the card's bandwidth: XLA's fusions and a Pallas
kernel of partial sums, on each conv stack layer's output.

    python benchmarks/bn_reductions.py [--frames 1024] [--layers 32x32x64 ...]
        [--block-rows 128 256] [--reps 7] [--steps 20] [--interpret] [--no-record]

A training batch norm reads its input once for the statistics (sum and sum of squares per
channel) and its backward pass reads the output gradient and the input once more for two sums
(of the gradient, and of the gradient times the normalised input, the ELU's derivative taken on
the way). Each is timed as XLA fuses it and as a Pallas kernel that sums blocks of rows into
partial sums (one program a block, then a small sum over blocks), beside a copy of the same array
(read and write): bytes over time says how far each is from the bandwidth. Steady state: median
over `reps` blocked calls of `steps` calls each, compile apart. --interpret runs the Pallas kernels
in Pallas's interpreter (a CPU check of the kernels, not a timing).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness

# VAE_rpl's batch-normed conv outputs per frame (encoder; the decoder's mirror them): H·W, C.
LAYERS = {"32x32x64": (32 * 32, 64), "16x16x128": (16 * 16, 128), "8x8x128": (8 * 8, 128),
          "4x4x256": (4 * 4, 256)}
NOTES = ("A batch norm's channel reductions on one layer's output (bfloat16 [rows, C], float32 "
         "sums): the statistics' read and the backward pass's two sums, as XLA fuses them and as "
         "a Pallas kernel of per-block partial sums, beside a copy of the array "
         "(benchmarks/bn_reductions.py).")


def xla_stats(y):
    """(sum, sum of squares) over rows, in float32."""
    y = y.astype(jnp.float32)
    return y.sum(0), (y * y).sum(0)


def xla_backward_sums(dz, y, mean, mul, bias, rstd):
    """(Σ dv, Σ dv·u) with v = (y − mean)·mul + bias the pre-ELU value, dv = dz·ELU'(v) and
    u = (y − mean)·rstd the normalised input."""
    yc = y.astype(jnp.float32) - mean
    v = yc * mul + bias
    dv = dz.astype(jnp.float32) * jnp.where(v > 0, 1.0, jnp.exp(v))
    return dv.sum(0), (dv * yc * rstd).sum(0)


def _rows(block_rows: int, c: int) -> pl.BlockSpec:
    return pl.BlockSpec((block_rows, c), lambda i: (i, 0))


def _partial(c: int) -> pl.BlockSpec:
    return pl.BlockSpec((1, c), lambda i: (i, 0))


def pallas_stats(y, block_rows: int, interpret: bool = False):
    """`xla_stats` as a Pallas kernel: each program sums one block of rows."""
    m, c = y.shape

    def kernel(y_ref, s_ref, q_ref):
        v = y_ref[...].astype(jnp.float32)
        s_ref[...] = jnp.sum(v, axis=0, keepdims=True)
        q_ref[...] = jnp.sum(v * v, axis=0, keepdims=True)

    blocks = m // block_rows
    s, q = pl.pallas_call(
        kernel, grid=(blocks,), in_specs=[_rows(block_rows, c)], out_specs=[_partial(c)] * 2,
        out_shape=[jax.ShapeDtypeStruct((blocks, c), jnp.float32)] * 2, interpret=interpret)(y)
    return s.sum(0), q.sum(0)


def pallas_backward_sums(dz, y, mean, mul, bias, rstd, block_rows: int, interpret: bool = False):
    """`xla_backward_sums` as a Pallas kernel: each program sums one block of rows."""
    m, c = y.shape

    def kernel(dz_ref, y_ref, mean_ref, mul_ref, bias_ref, rstd_ref, a_ref, b_ref):
        yc = y_ref[...].astype(jnp.float32) - mean_ref[...]
        v = yc * mul_ref[...] + bias_ref[...]
        dv = dz_ref[...].astype(jnp.float32) * jnp.where(v > 0, 1.0, jnp.exp(v))
        a_ref[...] = jnp.sum(dv, axis=0, keepdims=True)
        b_ref[...] = jnp.sum(dv * yc * rstd_ref[...], axis=0, keepdims=True)

    blocks = m // block_rows
    channel = pl.BlockSpec((1, c), lambda i: (0, 0))
    a, b = pl.pallas_call(
        kernel, grid=(blocks,), in_specs=[_rows(block_rows, c)] * 2 + [channel] * 4,
        out_specs=[_partial(c)] * 2,
        out_shape=[jax.ShapeDtypeStruct((blocks, c), jnp.float32)] * 2, interpret=interpret)(
            dz, y, mean[None], mul[None], bias[None], rstd[None])
    return a.sum(0), b.sum(0)


def _max_rel(a, b) -> float:
    return max(float(jnp.max(jnp.abs(x - y) / (jnp.abs(y) + 1.0)))
               for x, y in zip(a, b, strict=True))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1024)
    parser.add_argument("--layers", nargs="+", default=list(LAYERS), choices=list(LAYERS))
    parser.add_argument("--block-rows", type=int, nargs="+", default=[128, 256])
    parser.add_argument("--reps", type=int, default=7)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--interpret", action="store_true",
                        help="run the Pallas kernels in the interpreter (CPU check, no record)")
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    rows = []
    for layer in args.layers:
        pixels, c = LAYERS[layer]
        m = args.frames * pixels
        y = (jax.random.normal(jax.random.PRNGKey(0), (m, c)) * 2 + 0.5).astype(jnp.bfloat16)
        dz = jax.random.normal(jax.random.PRNGKey(1), (m, c), jnp.bfloat16)
        mean, rstd = jnp.linspace(0.3, 0.7, c), jnp.linspace(0.4, 0.6, c)
        mul, bias = rstd * jnp.linspace(0.5, 1.5, c), jnp.linspace(-0.2, 0.2, c)
        channels = (mean, mul, bias, rstd)
        array_mb = m * c * 2 / 1e6
        cases = [("copy (read + write)", lambda a: a + 1, (y,), 2 * array_mb, None),
                 ("statistics, XLA", xla_stats, (y,), array_mb, "stats"),
                 ("backward sums, XLA", xla_backward_sums, (dz, y, *channels), 2 * array_mb,
                  "backward")]
        for r in args.block_rows:
            if m % r == 0:
                cases += [
                    (f"statistics, Pallas {r}-row blocks",
                     lambda a, r=r: pallas_stats(a, r, args.interpret), (y,), array_mb, "stats"),
                    (f"backward sums, Pallas {r}-row blocks",
                     lambda *a, r=r: pallas_backward_sums(*a, r, interpret=args.interpret),
                     (dz, y, *channels), 2 * array_mb, "backward")]
        reference = {}
        for name, fn, fn_args, mb, kind in cases:
            compile_s, s, out = harness.measure_calls(fn, fn_args, args.reps, args.steps)
            err = None
            if kind is not None:
                reference.setdefault(kind, out)
                err = _max_rel(out, reference[kind])
            rows.append({"case": f"{layer} [{m}, {c}] bfloat16, {args.frames} frames",
                         "impl": name, "us_per_call": 1e6 * s, "TB_per_s": mb / s / 1e6,
                         "compile_s": compile_s, "max_rel_diff": err})
            print(f"{layer:10s} {name:34s} {1e6 * s:9.1f} µs  {mb / s / 1e6:5.2f} TB/s"
                  f"  (compile {compile_s:.1f} s{'' if err is None else f', diff {err:.1e}'})",
                  flush=True)
    if not (args.no_record or args.interpret):
        harness.record("bn_reductions", rows, notes=NOTES)
    return 0


if __name__ == "__main__":
    sys.exit(main())
