"""The roofline of a learner's train step: per layer, forward and backward, the FLOPs it asks for
and the bytes an ideally fused layer would move, each layer's bound against the matmul ceiling
and the copy bandwidth measured in the same run, and the step's measured time against the sum.

    python benchmarks/learner_roofline.py [--learners VAE_rpl PRED DSA] [--frames 1024]
        [--dtype auto] [--activation-dtype auto] [--reps 5] [--steps 3] [--matmul-size N]
        [--copy-mib M] [--layers-jsonl PATH] [--no-record]

A layer is a module scope of the traced train step (its jaxpr's name stack) holding a
convolution or a matmul: a conv or deconv with the batch norm and ELU that follow it, a dense
layer, a recurrent layer over all its steps. Its FLOPs are `benchmarks/flops.py`'s count of
those convolutions and matmuls (taps on real input), forward apart from backward (the
`transpose` of the step's autodiff), in the formulation the learner runs. Its bytes are an
ideally fused layer's: forward, its inputs, weights and outputs once each (in their dtypes;
batch-norm statistics and ELU inside the layer, biases and batch-norm parameters not counted);
backward, reading the output's gradient, the input, the output and the weights and writing the
weights' gradient, and the input's gradient where the backward computes one (not for the
frames). A layer's bound is max(FLOPs / ceiling, bytes / bandwidth) per direction, the step's
their sum: what a device that ran every layer at its roofline would take, nothing else counted
(the loss, the optimizer, elementwise work outside the layers).

Measured in the same run on the same device: the matmul ceiling of each dtype the layers'
operands have (`learner_throughput.matmul_ceiling`: n³, 8192 off the CPU), the copy bandwidth
(a pass that reads and writes a large array, median of blocked calls, compile apart), and the
learner's jitted train step (`learner_throughput.bench_jax`: the step as the learner runs it,
its dtypes "auto" made concrete for the backend, steady state). The per-layer FLOP sum is set
beside XLA's `cost_analysis()` of that compiled step (which also counts elementwise work, and on
a GPU none of cuDNN's convolutions). Rows per learner go to the harness; layer rows to
`--layers-jsonl`.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import re
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax._src.interpreters import partial_eval as pe
from jax.extend import core

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import flops, harness
from benchmarks.learner_throughput import (
    LD_DIM,
    abstract_step,
    bench_jax,
    matmul_ceiling,
    step_shape,
)
from jaml import learners
from jaml.configs.learners import COMPUTE_DTYPE_NAMES, dtype_for_backend

_COUNTED = {"conv_general_dilated": flops.conv_flops, "dot_general": flops.dot_flops}
OUTSIDE = "(outside modules)"


@dataclasses.dataclass
class Layer:
    """One layer's work: FLOPs per direction and the bytes of its operands (forward shapes)."""

    name: str
    fwd_flops: float = 0.0
    bwd_flops: float = 0.0
    in_bytes: float = 0.0
    weight_bytes: float = 0.0
    out_bytes: float = 0.0
    dtypes: set = dataclasses.field(default_factory=set)

    @property
    def writes_input_grad(self) -> bool:
        """Whether the backward computes the input's gradient: its FLOPs are then twice the
        forward's (input and weight gradients), not once (the weights' alone)."""
        return self.bwd_flops > 1.5 * self.fwd_flops

    @property
    def fwd_bytes(self) -> float:
        return self.in_bytes + self.weight_bytes + self.out_bytes

    @property
    def bwd_bytes(self) -> float:
        # Read dy, x, y, w; write dw and, where computed, dx.
        return (2 * self.out_bytes + self.in_bytes + 2 * self.weight_bytes
                + self.in_bytes * self.writes_input_grad)

    def bound_s(self, ceiling, bandwidth: float) -> tuple[float, float]:
        """(forward, backward) seconds at the roofline: max(FLOPs / ceiling, bytes /
        bandwidth), with the ceiling (FLOP/s, `ceiling(dtype)`) of its slowest operand dtype."""
        ceiling = min(ceiling(d) for d in self.dtypes)
        return (max(self.fwd_flops / ceiling, self.fwd_bytes / bandwidth),
                max(self.bwd_flops / ceiling, self.bwd_bytes / bandwidth))


def layer_of(name_stack: str) -> tuple[str, bool]:
    """(layer, backward) of an equation's full name stack: the module path without the root
    module, method scopes or autodiff wrappers, cut at a scanned cell (one layer over its
    steps); backward when the stack is inside the autodiff's `transpose`."""
    backward = "transpose(" in name_stack
    parts = []
    for comp in name_stack.split("/")[2:]:  # "", then the root module (under its wrappers)
        comp = re.sub(r"^(\w+\()+|\)+$", "", comp)
        if comp.endswith(".scan_fn"):
            parts.append(comp.removesuffix(".scan_fn"))
            break
        if comp and "(" not in comp and "." not in comp:
            parts.append(comp)
    return "/".join(parts) or OUTSIDE, backward


def counted_eqns(jaxpr, stack: str = "", times: int = 1):
    """(equation, full name stack, times it runs) of every convolution and matmul in a jaxpr,
    nested calls included (a scan body `length` times, a `cond` by its costliest branch)."""
    for eqn in jaxpr.eqns:
        here = f"{stack}/{eqn.source_info.name_stack}"
        if eqn.primitive.name in _COUNTED:
            yield eqn, here, times
            continue
        inner = times * eqn.params.get("length", 1) if eqn.primitive.name == "scan" else times
        subs = [s for s in eqn.params.values() if isinstance(s, core.ClosedJaxpr | core.Jaxpr)]
        if eqn.primitive.name == "cond":
            subs = [max(eqn.params["branches"],
                        key=lambda b: sum(flops.jaxpr_flops(b.jaxpr).values()))]
        for sub in subs:
            yield from counted_eqns(getattr(sub, "jaxpr", sub), here, inner)


def _nbytes(aval) -> int:
    return int(np.prod(aval.shape)) * aval.dtype.itemsize


def layers(jaxpr) -> list[Layer]:
    """The layers of a train step's jaxpr in forward order: FLOPs by direction, and from the
    forward equations the distinct inputs (lhs: activations, once per step of a scan), weights
    (rhs: once) and outputs."""
    found: dict[str, Layer] = {}
    seen: set = set()
    for eqn, stack, times in counted_eqns(jaxpr):
        name, backward = layer_of(stack)
        layer = found.setdefault(name, Layer(name))
        count = times * _COUNTED[eqn.primitive.name](eqn)
        if backward:
            layer.bwd_flops += count
            continue
        layer.fwd_flops += count
        lhs, rhs = eqn.invars[:2]
        for var, kind in ((lhs, "in"), (rhs, "weight")):
            if isinstance(var, core.Var) and (name, id(var)) not in seen:
                seen.add((name, id(var)))
                n = _nbytes(var.aval) * (times if kind == "in" else 1)
                setattr(layer, f"{kind}_bytes", getattr(layer, f"{kind}_bytes") + n)
            layer.dtypes.add(var.aval.dtype.name)
        layer.out_bytes += times * _nbytes(eqn.outvars[0].aval)
    return list(found.values())


def concrete_dtypes(dtype: str, activation_dtype: str) -> tuple[str, str]:
    """The dtypes that run on this backend ("auto": bfloat16 off the CPU, float32 on it)."""
    backend = jax.default_backend()
    return dtype_for_backend(dtype, backend), dtype_for_backend(activation_dtype, backend)


def step_jaxpr(learner_name: str, sequences: int, dtype: str, activation_dtype: str):
    """The jaxpr of the learner's train step on `sequences` sequences, as it runs here (its
    upsample form and CPU kernels for this backend), traced on shapes alone, without the work
    XLA drops as dead (a custom VJP's input gradient of the frames)."""
    learner = learners.make(learner_name, ld_dim=LD_DIM, compute_dtype=dtype,
                            activation_dtype=activation_dtype)
    step, *args = abstract_step(learner, sequences)
    jaxpr = jax.make_jaxpr(step)(*args).jaxpr
    return pe.dce_jaxpr(jaxpr, [True] * len(jaxpr.outvars))[0]


def copy_bandwidth(mib: int, reps: int = 5) -> float:
    """Bytes/s of one pass over a `mib` MiB float32 array on the default device, read once and
    written once (an increment: a copy XLA cannot elide), median of `reps` blocked calls."""
    x = jnp.zeros((mib * 2**20 // 4,), jnp.float32)
    timing = harness.measure(jax.jit(lambda x: x + 1), x, repeats=reps)
    return 2 * x.nbytes / timing["median_s"]


def layer_rows(found: list[Layer], ceiling, bandwidth: float) -> list[dict]:
    """A row per layer: GFLOP and MB each way, the roofline time each way and which limit binds."""
    rows = []
    for layer in found:
        fwd_s, bwd_s = layer.bound_s(ceiling, bandwidth)
        flop_s = min(ceiling(d) for d in layer.dtypes)
        bound_by = ["memory" if b / bandwidth > f / flop_s else "compute"
                    for f, b in ((layer.fwd_flops, layer.fwd_bytes),
                                 (layer.bwd_flops, layer.bwd_bytes))]
        rows.append({"layer": layer.name, "dtypes": "/".join(sorted(layer.dtypes)),
                     "fwd_gflop": layer.fwd_flops / 1e9, "bwd_gflop": layer.bwd_flops / 1e9,
                     "fwd_mb": layer.fwd_bytes / 1e6, "bwd_mb": layer.bwd_bytes / 1e6,
                     "fwd_bound_us": 1e6 * fwd_s, "bwd_bound_us": 1e6 * bwd_s,
                     "bound_by": "/".join(bound_by)})
    return rows


def markdown(rows: list[dict], step: dict) -> str:
    """The layer rows and the step's totals as a markdown table."""
    head = ("| layer | dtype | fwd GFLOP | bwd GFLOP | fwd MB | bwd MB | fwd bound µs | "
            "bwd bound µs | bound by (fwd/bwd) |")
    lines = [head, "|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        lines.append(f"| {r['layer']} | {r['dtypes']} | {r['fwd_gflop']:.3f} | "
                     f"{r['bwd_gflop']:.3f} | {r['fwd_mb']:.1f} | {r['bwd_mb']:.1f} | "
                     f"{r['fwd_bound_us']:.0f} | {r['bwd_bound_us']:.0f} | {r['bound_by']} |")
    total = sum(r["fwd_bound_us"] + r["bwd_bound_us"] for r in rows)
    lines.append(f"| **step** | | {sum(r['fwd_gflop'] for r in rows):.3f} | "
                 f"{sum(r['bwd_gflop'] for r in rows):.3f} | "
                 f"{sum(r['fwd_mb'] for r in rows):.1f} | {sum(r['bwd_mb'] for r in rows):.1f} | "
                 f"{total:.0f} bound | {1e6 * step['step_s']:.0f} measured | "
                 f"measured / bound {step['measured_over_bound']:.2f} |")
    return "\n".join(lines)


def roofline(learner_name: str, frames: int, dtype: str, activation_dtype: str,
             ceiling, bandwidth: float, reps: int, steps: int) -> tuple[dict, list]:
    """(the step's row, its layers' rows) of one learner on `frames` frames a step;
    `ceiling(dtype)`: the matmul ceiling in FLOP/s."""
    sequences, seq_len = step_shape(learner_name, frames)
    found = layers(step_jaxpr(learner_name, sequences, dtype, activation_dtype))
    rows = layer_rows(found, ceiling, bandwidth)
    used = sorted({d for layer in found for d in layer.dtypes})
    run = bench_jax(sequences, reps, steps, dtype, learner_name, "auto", activation_dtype)
    if "error" in run:
        raise RuntimeError(f"{learner_name}: {run['error']}")
    n = sequences * seq_len
    counted = sum(layer.fwd_flops + layer.bwd_flops for layer in found)
    xla = run["xla_gflop_per_frame"] * n * 1e9
    bound = sum(r["fwd_bound_us"] + r["bwd_bound_us"] for r in rows) / 1e6
    step_s = n / run["fps"]
    size = f"batch {n}" if seq_len == 1 else f"{n} frames ({sequences} sequences × {seq_len})"
    step = {"case": f"{learner_name} train step, {size}", "impl": "jaml",
            "learner": learner_name, "batch": sequences, "seq_len": seq_len,
            "frames_per_step": n, "dtype": dtype, "activation_dtype": activation_dtype,
            **{f"matmul_{d}_tflop_per_s": ceiling(d) / 1e12 for d in used},
            "copy_gb_per_s": bandwidth / 1e9, "layers": len(found),
            "layer_gflop": counted / 1e9, "xla_gflop": xla / 1e9,
            "layer_over_xla_flops": counted / xla, "bound_s": bound, "compile_s":
            run["compile_s"], "step_s": step_s, "measured_over_bound": step_s / bound}
    return step, rows


NOTES = ("The roofline of a train step (benchmarks/learner_roofline.py): per layer, FLOPs "
         "(convolutions and matmuls from the step's jaxpr) and an ideally fused layer's bytes, "
         "forward and backward; bound_s = Σ_layers max(FLOPs / matmul ceiling, bytes / copy "
         "bandwidth), both measured in the same run; step_s the jitted train step (steady "
         "state); layer_over_xla_flops: the layers' FLOPs over XLA's cost_analysis of the "
         "compiled step (which counts elementwise work too, and on a GPU no cuDNN convolution).")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--learners", nargs="+", default=["VAE_rpl", "PRED", "DSA"],
                        choices=["VAE_rpl", "PRED", "DSA"])
    parser.add_argument("--frames", type=int, default=1024,
                        help="frames per train step (frames // T sequences of T frames)")
    parser.add_argument("--dtype", default="auto", choices=COMPUTE_DTYPE_NAMES)
    parser.add_argument("--activation-dtype", default="auto", choices=COMPUTE_DTYPE_NAMES)
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--matmul-size", type=int, default=None,
                        help="n of the n³ matmul ceiling (default 8192; 2048 on the CPU)")
    parser.add_argument("--copy-mib", type=int, default=None,
                        help="MiB of the copied array (default 2048; 256 on the CPU)")
    parser.add_argument("--layers-jsonl", type=Path, help="append the layer rows here")
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    cpu = jax.default_backend() == "cpu"
    dtype, act = concrete_dtypes(args.dtype, args.activation_dtype)
    n = args.matmul_size or (2048 if cpu else 8192)
    ceiling = functools.cache(lambda d: 1e12 * matmul_ceiling(d, n))
    bandwidth = copy_bandwidth(args.copy_mib or (256 if cpu else 2048))
    env = harness.environment()
    print(f"{env['device']}, jax {jax.__version__}: {dtype} compute, {act} activations; "
          f"{n}³ {dtype} matmul {ceiling(dtype) / 1e12:.3g} TFLOP/s, copy "
          f"{bandwidth / 1e9:.3g} GB/s", flush=True)
    for name in args.learners:
        step, rows = roofline(name, args.frames, dtype, act, ceiling, bandwidth, args.reps,
                              args.steps)
        print(f"\n{step['case']}: layers {step['layer_gflop']:.2f} GFLOP, XLA's cost analysis "
              f"{step['xla_gflop']:.2f} ({step['layer_over_xla_flops']:.3f}); bound "
              f"{1e3 * step['bound_s']:.2f} ms, measured {1e3 * step['step_s']:.2f} ms "
              f"(compile {step['compile_s']:.1f} s)\n")
        print(markdown(rows, step), flush=True)
        if args.layers_jsonl:
            with args.layers_jsonl.open("a") as f:
                for r in rows:
                    f.write(json.dumps({"benchmark": "learner_roofline", **env,
                                        "case": step["case"], **r}) + "\n")
        if not args.no_record:
            harness.record("learner_roofline", [step], notes=NOTES)
    return 0


if __name__ == "__main__":
    sys.exit(main())
