"""Where a learner's train step spends its GPU time: kernel time by kind, from JAX's profiler.

    python benchmarks/learner_profile.py [--learner VAE_rpl] [--frames 1024] [--dtype bfloat16]
        [--activation-dtype bfloat16] [--upsample-form auto] [--steps 10] [--json out.json]
        [--roofline]

The step is built and compiled as `learner_throughput.py` builds it, run once to warm up, then
`--steps` steps run under `jax.profiler.trace`. The trace's device planes (`ProfileData`) give
every kernel's time; each is put in one kind by the HLO instruction it ran for (its `hlo_op`
stat; inside a CUDA graph, whose op is the graph, the kernel's name, which XLA gives its
fusion) or, lacking either, its kernel name: convolution (cuDNN), matmul, reduction fusion,
elementwise fusion, transpose/copy, memset/memcpy, other. Printed: GPU time per step by kind, its
share of the busy time, the busy time against the step's wall time, and the longest ops. This is
a profile, not a benchmark: rates go in `learner_throughput.py`'s rows.

With --roofline each kernel is also placed in the layer it ran for (`layer_of_op`: its HLO
instruction's op_name, the module path of the code it came from, against the layers of
`learner_roofline.py`; a batch norm counts with the convolution before it), forward apart from
backward, and each layer's kernel time is printed beside its roofline bound (the matmul ceilings
and copy bandwidth measured in the same run).
"""

from __future__ import annotations

import argparse
import collections
import functools
import glob
import itertools
import json
import re
import sys
import tempfile
import time
from pathlib import Path

import jax

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import learner_roofline
from benchmarks.learner_throughput import jaml_step, matmul_ceiling, step_shape
from jaml.configs.learners import COMPUTE_DTYPE_NAMES, UPSAMPLE_FORMS

KINDS = ("convolution", "matmul", "reduction fusion", "elementwise fusion", "transpose/copy",
         "memset/memcpy", "other")


# A convolution's op or kernel ("cudnn-conv.14"), not a fusion of converts ("loop_convert_…").
_CONV = re.compile(r"conv(?!ert)")


def kind_of(op: str, kernel: str) -> str:
    """The kind of a kernel, from its HLO instruction's name (XLA names fusions by their kind:
    loop_*, input_* for reductions) or, without one, from the kernel's own name."""
    o, k = op.lower(), kernel.lower()
    if o.startswith("command_buffer"):  # a CUDA graph's kernels: the kernel names the fusion
        o = k
    if "memcpy" in k or "memset" in k:
        return "memset/memcpy"
    if _CONV.search(o) or (not o and (_CONV.search(k) or any(
            s in k for s in ("fprop", "dgrad", "wgrad")))):
        return "convolution"
    if any(s in o for s in ("gemm", "dot", "cublas")) or (not o and "gemm" in k):
        return "matmul"
    if "transpose" in o or o.startswith("copy"):
        return "transpose/copy"
    if o.startswith("input_") or "reduce" in o:
        return "reduction fusion"
    if "fusion" in o or o.startswith("loop_"):
        return "elementwise fusion"
    return "other"


def device_kernels(xspace_path: str) -> list[tuple[str, str, float]]:
    """(hlo op, kernel name, seconds) of every kernel on the trace's GPU planes."""
    from jax.profiler import ProfileData

    out = []
    for plane in ProfileData.from_file(xspace_path).planes:
        if not plane.name.startswith("/device:GPU"):
            continue
        for line in plane.lines:
            if not line.name.startswith("Stream"):
                continue
            for event in line.events:
                stats = dict(event.stats)
                out.append((str(stats.get("hlo_op", "")), event.name, event.duration_ns / 1e9))
    return out


def summarise(kernels, steps: int, wall_s: float, top: int = 25) -> dict:
    by_kind = collections.Counter()
    by_op = collections.Counter()
    names = {}
    for op, kernel, s in kernels:
        kind = kind_of(op, kernel)
        by_kind[kind] += s
        # An op's kernels of one kind together (a cuDNN convolution's memset apart from it).
        key = (kernel if not op or op.startswith("command_buffer") else op, kind)
        by_op[key] += s
        names.setdefault(key, kernel)
    busy = sum(by_kind.values())
    return {"steps": steps, "wall_ms_per_step": 1e3 * wall_s / steps,
            "busy_ms_per_step": 1e3 * busy / steps, "kernels_per_step": len(kernels) / steps,
            "by_kind_ms_per_step": {k: 1e3 * by_kind[k] / steps for k in KINDS if by_kind[k]},
            "top_ops": [{"op": op, "kind": kind, "kernel": names[op, kind][:90],
                         "ms_per_step": 1e3 * s / steps}
                        for (op, kind), s in by_op.most_common(top)]}


def op_names(hlo_text: str) -> dict[str, str]:
    """{HLO instruction name: its op_name metadata} of a compiled module's text."""
    pattern = re.compile(r'^\s*(?:ROOT\s+)?%?([\w.\-]+)\s*=.*?metadata=\{[^}]*op_name="([^"]*)"',
                         re.MULTILINE)
    return dict(pattern.findall(hlo_text))


OTHER = "(other)"


def layer_of_op(op_name: str, layers: set[str]) -> tuple[str, bool]:
    """(layer, backward) of an HLO op_name such as "jit(step)/transpose(jvp(VAE))/VAE.posterior/
    conv/bn1/add_any": the longest of `layers` its module path holds; a batch norm "P/bnS" counts
    with the convolution "P/convS" or "P/deconvS" before it; else "P (other)" for the first
    component P that begins a layer's path, or `OTHER`."""
    backward = "transpose(" in op_name
    comps = [re.sub(r"^(\w+\()+|\)+$", "", c).removesuffix(".scan_fn")
             for c in op_name.split("/")]
    comps = [c for c in comps if c and "." not in c]
    path = "/" + "/".join(comps) + "/"
    for layer in sorted(layers, key=len, reverse=True):
        if f"/{layer}/" in path:
            return layer, backward
    for parent, comp in itertools.pairwise(comps):
        if comp.startswith("bn"):
            for conv in ("conv", "deconv"):
                if f"{parent}/{conv}{comp[2:]}" in layers:
                    return f"{parent}/{conv}{comp[2:]}", backward
    tops = {layer.split("/")[0] for layer in layers}
    return next((f"{c} {OTHER}" for c in comps if c in tops), OTHER), backward


def instruction(op: str, kernel: str) -> str:
    """The HLO instruction a kernel ran for, "." written "_" as kernels are named: its op, or
    inside a CUDA graph (op "command_buffer_…") the kernel itself."""
    return (kernel if op.startswith("command_buffer") else op).replace(".", "_")


def by_layer(kernels, names: dict[str, str], layers: set[str], steps: int) -> dict:
    """{(layer, backward): ms per step} of the kernels; kernels whose op is not in `names`
    under ("(not placed)", False)."""
    names = {name.replace(".", "_"): op_name for name, op_name in names.items()}
    out = collections.Counter()
    for op, kernel, s in kernels:
        op = instruction(op, kernel)
        key = layer_of_op(names[op], layers) if op in names else ("(not placed)", False)
        out[key] += 1e3 * s / steps
    return dict(out)


def _roofline_rows(found, placed: dict) -> list[dict]:
    """Each layer's bound (measured ceilings and bandwidth) beside its kernels' time."""
    ceiling = functools.cache(lambda d: 1e12 * matmul_ceiling(d, 8192))
    bounds = learner_roofline.layer_rows(found, ceiling, learner_roofline.copy_bandwidth(2048))
    def ms(name: str) -> dict:
        return {"fwd_ms": placed.get((name, False), 0.0), "bwd_ms": placed.get((name, True), 0.0)}

    rows = [{**r, **ms(r["layer"])} for r in bounds]
    for name in sorted({n for n, _ in placed} - {r["layer"] for r in bounds}):
        rows.append({"layer": name, "fwd_bound_us": 0.0, "bwd_bound_us": 0.0, **ms(name)})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--learner", default="VAE_rpl", choices=["VAE_rpl", "PRED", "DSA"])
    parser.add_argument("--frames", type=int, default=1024)
    parser.add_argument("--dtype", default="float32", choices=COMPUTE_DTYPE_NAMES)
    parser.add_argument("--activation-dtype", default="float32", choices=COMPUTE_DTYPE_NAMES)
    parser.add_argument("--upsample-form", default="auto", choices=UPSAMPLE_FORMS)
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--json", type=Path, help="also write the summary here")
    parser.add_argument("--roofline", action="store_true",
                        help="also place each kernel in its layer, beside the layer's bound")
    args = parser.parse_args(argv)
    if jax.default_backend() != "gpu":
        parser.error(f"profiles GPU kernels; the default backend is {jax.default_backend()}")
    sequences, seq_len = step_shape(args.learner, args.frames)
    step, state, batch = jaml_step(args.learner, sequences, args.dtype, args.upsample_form,
                                   args.activation_dtype)
    state, metrics = step(state, batch, jax.random.key(0))
    jax.block_until_ready((state, metrics))
    with tempfile.TemporaryDirectory() as log_dir:
        with jax.profiler.trace(log_dir):
            t0 = time.perf_counter()
            for i in range(args.steps):
                state, metrics = step(state, batch, jax.random.key(i + 1))
            jax.block_until_ready((state, metrics))
            wall = time.perf_counter() - t0
        (path,) = glob.glob(f"{log_dir}/**/*.xplane.pb", recursive=True)
        kernels = device_kernels(path)
        summary = summarise(kernels, args.steps, wall)
    summary.update({"learner": args.learner, "frames_per_step": sequences * seq_len,
                    "dtype": args.dtype, "activation_dtype": args.activation_dtype,
                    "upsample_form": args.upsample_form, "device": jax.devices()[0].device_kind,
                    "jax": jax.__version__})
    print(f"{args.learner}, {sequences * seq_len} frames, {args.dtype} convolutions, "
          f"{args.activation_dtype} activations, upsample {args.upsample_form}, "
          f"{summary['device']}: wall {summary['wall_ms_per_step']:.2f} ms/step (profiled), "
          f"GPU busy {summary['busy_ms_per_step']:.2f} ms, "
          f"{summary['kernels_per_step']:.0f} kernels/step")
    for kind, ms in summary["by_kind_ms_per_step"].items():
        print(f"  {kind:20s} {ms:7.3f} ms  {100 * ms / summary['busy_ms_per_step']:5.1f} %")
    for o in summary["top_ops"]:
        print(f"  {o['ms_per_step']:7.3f} ms  {o['kind']:18s} {o['op'][:48]:48s} {o['kernel']}")
    if args.roofline:
        names = op_names(step.lower(state, batch, jax.random.key(0)).compile().as_text())
        found = learner_roofline.layers(learner_roofline.step_jaxpr(
            args.learner, sequences, args.dtype, args.activation_dtype))
        placed = by_layer(kernels, names, {layer.name for layer in found}, args.steps)
        rows = _roofline_rows(found, placed)
        known = {name.replace(".", "_") for name in names}
        unplaced = collections.Counter()
        for op, kernel, sec in kernels:
            key = instruction(op, kernel)
            if key not in known:
                unplaced[key] += 1e3 * sec / args.steps
        summary["not_placed_ms_per_step"] = dict(unplaced.most_common(20))
        summary["layers"] = rows
        print("\n| layer | fwd bound µs | fwd kernels µs | bwd bound µs | bwd kernels µs |")
        print("|---|---:|---:|---:|---:|")
        for r in rows:
            print(f"| {r['layer']} | {r['fwd_bound_us']:.0f} | {1e3 * r['fwd_ms']:.0f} | "
                  f"{r['bwd_bound_us']:.0f} | {1e3 * r['bwd_ms']:.0f} |")
    if args.json:
        args.json.write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
