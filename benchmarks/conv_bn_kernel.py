"""The encoder's middle convolutions with their batch norms' statistics: XLA's convolution then its
float32 sums (what the learner runs) against a Pallas kernel that returns the sums from its
epilogue (`jaml.learners.conv_kernel`), beside each layer's roofline bound.

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
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import flops, harness
from benchmarks.learner_roofline import copy_bandwidth
from benchmarks.learner_throughput import matmul_ceiling
from jaml.learners import networks
from jaml.learners.conv_kernel import halving_conv_stats

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
