"""Training throughput (frames/s) of a learner's train step, jaml vs its PyTorch peer.

    python benchmarks/learner_throughput.py [--learners VAE_rpl PRED DSA] [--batches 64 256 1024]
        [--reps 5] [--steps 3] [--dtypes float32 bfloat16] [--torch eager compiled]
        [--torch-compile-modes max-autotune-no-cudagraphs default]
        [--torch-memory-formats channels_last contiguous] [--upsample-forms auto dilated phase]

jaml's rows carry the step's useful FLOPs per frame (`benchmarks/flops.py`: the convolutions and
matmuls the model asks for, counted from its jaxpr; XLA's own `cost_analysis` counts no cuDNN
convolution on a GPU), the useful TFLOP/s they imply, and that rate as a share (MFU) of a matmul
ceiling measured in the same run (a large matmul in the same dtype) and, on a device whose dense
peak is known, of that quoted peak. A frame is one frame a step reads (batch × T for a sequence
learner). Compile time is reported apart; steady state is the median over `reps` blocked
repetitions of `steps` train steps each. jaml's step is compiled with `learners.compiler_options()`
(on the CPU: convolutions on XLA's Eigen path, not YNNPACK; elsewhere XLA's defaults). Its
decoder's transposed convolutions run in each `--upsample-forms` formulation, a row each: "auto"
(the learner's default: the phase pair on every backend), "subpixel", "phase", "dilated"
(XLA's input-dilated convolution); the useful FLOPs are the same for all.

If torch imports, the same network in PyTorch (`benchmarks/peers/torch_learners.py`: the three
learners, jaml's parameter counts and FLOPs) is timed the same way in the same run on the same
device: eager, and its whole train step (zero_grad, forward, backward, Adam) under
`torch.compile` in each `--torch-compile-modes` mode, each in every `--torch-memory-formats`
layout of activations and conv weights (channels_last by default). Its rows
carry TFLOP/s and MFU from jaml's count for the same learner (so the rates compare as the
frames/s do) and the peer's own count (`peer_gflop_per_frame`: FlopCounterMode, convolutions by
their real taps, whatever formulation a backend runs). The peer gets what a careful PyTorch user
switches on: cuDNN autotuning, TF32 matmuls (`torch.set_float32_matmul_precision("high")`; XLA
and cuDNN already use TF32 for float32 convolutions on this class of GPU), fused Adam when eager
on a GPU. With bfloat16, jaml's convolutions compute in bfloat16 (`compute_dtype`; parameters,
batch norms, heads, loss and Adam float32) and the peer runs its forward pass under
`torch.autocast(dtype=torch.bfloat16)`, the mixed precision a PyTorch user would reach for (it also
casts the MLP, heads and RNNs). Case by case (learner, dtype, batch), the peer's variants run
first and release their memory, then jaml's step (XLA_PYTHON_CLIENT_PREALLOCATE=false, set here
unless already set), and the case's rows are recorded at once, so a run cut short keeps the
cases it finished. A peer variant that fails (out of memory, a compiler error) is a row with the
error's first line, not fatal.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import flops, harness
from jaml import learners
from jaml.learners.config import UPSAMPLE_FORMS

LD_DIM, ACTION_DIM = 4, 1  # CartPole: D = 4, latent 2·D = 8
# Quoted dense peaks (TFLOP/s; NVIDIA's H100 SXM / H200 datasheets, without sparsity): float32
# rows are set against TF32, which XLA and PyTorch use for float32 convolutions on Hopper.
QUOTED_PEAKS = {"H100": {"float32": 495.0, "bfloat16": 989.0},
                "H200": {"float32": 495.0, "bfloat16": 989.0}}


def _batch(b: int, seq_len: int = 1, seed: int = 0):
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 256, (b, seq_len, 64, 64, 3), dtype=np.uint8)
    return frames, rng.normal(size=(b, seq_len, ACTION_DIM)).astype(np.float32)


def quoted_peak(dtype: str) -> float | None:
    """The quoted dense peak (TFLOP/s) of the default device in `dtype`, if known."""
    kind = jax.devices()[0].device_kind
    return next((p[dtype] for name, p in QUOTED_PEAKS.items() if name in kind), None)


def matmul_ceiling(dtype: str, n: int = 8192, reps: int = 5) -> float:
    """TFLOP/s of an n × n × n matmul in `dtype` on the default device (median of `reps`
    blocked calls after a warm-up): what this device reaches on the easiest dense work."""
    a = jax.random.normal(jax.random.key(0), (n, n), dtype)
    b = jax.random.normal(jax.random.key(1), (n, n), dtype)
    mm = jax.jit(lambda a, b: a @ b)
    jax.block_until_ready(mm(a, b))
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        jax.block_until_ready(mm(a, b))
        times.append(time.perf_counter() - t0)
    return 2 * n**3 / statistics.median(times) / 1e12


def _median_rate(run_steps, frames_per_step: int, reps: int, steps: int) -> float:
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        run_steps(steps)
        times.append(time.perf_counter() - t0)
    return frames_per_step * steps / statistics.median(times)


def bench_jax(b: int, reps: int, steps: int, dtype: str = "float32",
              learner_name: str = "VAE_rpl", upsample_form: str = "auto") -> dict:
    learner = learners.make(learner_name, ld_dim=LD_DIM, compute_dtype=dtype,
                            upsample_form=upsample_form)
    opt = learners.default_optimizer(learner)
    seq_len = learner.config.seq_len
    batch = tuple(jax.device_put(x) for x in _batch(b, seq_len))
    state = learners.init_train_state(learner, opt, jax.random.key(0), batch)
    train_step = learners.make_train_step(learner, opt)
    # Useful work is the model's, whatever formulation runs: counted on the plain (input-dilated)
    # transposed convolutions, whose inserted zeros flops.py does not count (the sub-pixel form
    # executes 36 taps an output phase where 16 meet real input).
    plain = learners.make(learner_name, ld_dim=LD_DIM, compute_dtype=dtype,
                          upsample_form="dilated")
    useful = flops.flops(learners.make_train_step(plain, learners.default_optimizer(plain)),
                         state, batch, jax.random.key(0))
    t0 = time.perf_counter()
    step = jax.jit(train_step, donate_argnums=0,
                   compiler_options=learners.compiler_options()).lower(
        state, batch, jax.random.key(0)).compile()
    compile_s = time.perf_counter() - t0
    holder = {"state": state, "i": 0}
    # XLA's own count for the program it compiled (on a GPU it leaves out cuDNN's convolutions).
    cost = step.cost_analysis()
    xla = (cost[0] if isinstance(cost, list) else cost or {}).get("flops", float("nan"))

    def run_steps(n):
        for _ in range(n):
            holder["i"] += 1
            holder["state"], metrics = step(holder["state"], batch, jax.random.key(holder["i"]))
        jax.block_until_ready((holder["state"], metrics))

    run_steps(1)  # warm-up
    frames = b * seq_len
    return {"compile_s": compile_s, "fps": _median_rate(run_steps, frames, reps, steps),
            "gflop_per_frame": useful / frames / 1e9, "xla_gflop_per_frame": xla / frames / 1e9,
            "seq_len": seq_len}


# Inductor's autotuned kernels without CUDA graphs (its autotuning takes minutes a case on an
# H100: a GPU job runs one learner and mode per process).
NOTES = ("Frames/s of one training step (forward, backward, Adam) on random 64×64 frames; "
         "useful FLOPs counted from the jaxpr (benchmarks/flops.py), MFU against a matmul "
         "measured in the same run and the quoted dense peak; the PyTorch peer "
         "(benchmarks/peers/torch_learners.py) is the same network in the same run on the same "
         "device (cuDNN autotune, TF32), eager and torch.compile'd, in the layout its label "
         "names, its rates from jaml's FLOP count; jaml's step compiled with "
         "learners.compiler_options(); bfloat16 rows: jaml's convolutions in bfloat16, the peer "
         "under torch.autocast(bfloat16).")
DEFAULT_COMPILE_MODES = ("max-autotune-no-cudagraphs",)
MEMORY_FORMATS = ("channels_last", "contiguous")


def torch_peer():
    """benchmarks.peers.torch_learners, or None where torch does not import."""
    try:
        from benchmarks.peers import torch_learners
    except ImportError:
        return None
    return torch_learners


def setup_torch() -> None:
    """What a careful PyTorch user switches on (process-wide, so here, not in the peer)."""
    import torch

    torch.backends.cudnn.benchmark = True
    torch.set_float32_matmul_precision("high")  # TF32 matmuls (convolutions: cuDNN's default)


def bench_torch(name: str, b: int, reps: int, steps: int, dtype: str = "float32",
                compile_mode: str | None = None, warmup: int = 3,
                memory_format: str = "channels_last") -> dict:
    """The peer's train step: frames/s (median over reps of `steps` synchronised steps) after
    its first step (timed apart: compilation, cuDNN autotuning) and `warmup` more (CUDA graph
    recording under reduce-overhead). {"error": ...} when it fails: out of memory, or a
    compiler error (its first line)."""
    import torch

    tl = torch_peer()
    # The peer runs where jaml runs: on the GPU when there is one.
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    variant = tl.Variant(compile_mode, channels_last=memory_format == "channels_last",
                         dtype=dtype)
    info = {"label": variant.label, "version": torch.__version__, "device": str(device),
            "threads": torch.get_num_threads()}
    torch._dynamo.reset()  # a fresh compile per case, free of earlier cases' guards
    peer = None
    try:
        peer = tl.Peer(name, variant, ld_dim=LD_DIM, action_dim=ACTION_DIM, device=device)
        batch = peer.batch(*_batch(b, tl.seq_len(name, LD_DIM)))

        def run_steps(n):
            for _ in range(n):
                peer.step(*batch)
            if device.type == "cuda":
                torch.cuda.synchronize()  # time the work, not the launches

        with peer.host_context():
            t0 = time.perf_counter()
            run_steps(1)
            first_s = time.perf_counter() - t0
            run_steps(warmup)
            fps = _median_rate(run_steps, b * tl.seq_len(name, LD_DIM), reps, steps)
        return {**info, "first_step_s": first_s, "fps": fps}
    except torch.OutOfMemoryError as e:
        return {**info, "error": f"out of memory: {str(e).splitlines()[0][:120]}"}
    except Exception as e:
        lines = [ln for ln in str(e).splitlines() if ln.strip()] or [""]
        return {**info, "error": f"{type(e).__name__}: {lines[0][:160]}"}
    finally:
        peer = None  # the model, its optimizer state and compiled graphs, released
        torch._dynamo.reset()
        if device.type == "cuda":
            torch.cuda.empty_cache()


def _rates(gflop_per_frame: float, fps: float, ceiling: float, peak: float | None) -> dict:
    useful = gflop_per_frame * fps / 1e3
    return {"useful_gflop_per_frame": gflop_per_frame, "useful_tflop_per_s": useful,
            "matmul_ceiling_tflop_per_s": ceiling, "mfu_of_ceiling": useful / ceiling,
            **({"mfu_of_quoted_peak": useful / peak} if peak else {})}


def _mfu_text(rates: dict) -> str:
    return (f"{rates['useful_tflop_per_s']:.2f} TFLOP/s, "
            f"{100 * rates['mfu_of_ceiling']:.1f} % of the matmul ceiling"
            + (f", {100 * rates['mfu_of_quoted_peak']:.1f} % of the quoted peak"
               if "mfu_of_quoted_peak" in rates else ""))


def _compare(learner_name: str, b: int, dtype: str, reps: int, steps: int, ceiling: float,
             peers: list[dict], peer_gflop: float | None,
             upsample_forms=("auto",)) -> list[dict]:
    """jaml at one batch size and dtype, a row per decoder formulation (`upsample_forms`),
    beside the peer's rows measured for the same case."""
    peak = quoted_peak(dtype)
    jaml_rows, lines, j = [], [], None
    for form in upsample_forms:
        j = bench_jax(b, reps, steps, dtype, learner_name, form)
        case = (f"{learner_name} train step, batch {b}" + (f" × {j['seq_len']} frames"
                if j["seq_len"] > 1 else "") + ("" if dtype == "float32" else f", {dtype}"))
        impl = "jaml" if form == "auto" else f"jaml, upsample {form}"
        rates = _rates(j["gflop_per_frame"], j["fps"], ceiling, peak)
        jaml_rows.append({"case": case, "impl": impl, "learner": learner_name, "batch": b,
                          "dtype": dtype, "compile_s": j["compile_s"], "frames_per_s": j["fps"],
                          **rates, "xla_gflop_per_frame": j["xla_gflop_per_frame"]})
        lines.append(f"{case}: {impl} {j['fps']:9.1f} frames/s (compile {j['compile_s']:.1f} s; "
                     f"{j['gflop_per_frame']:.3f} useful GFLOP/frame, {_mfu_text(rates)})")
    fps = jaml_rows[0]["frames_per_s"]  # the ratios are the first form's (auto by default)
    rows = list(jaml_rows)
    fastest = {"eager": [], "compiled": []}
    for t in peers:
        impl = f"pytorch {t['version']} {t['label']} ({t['device']})"
        row = {"case": case, "impl": impl, "learner": learner_name, "batch": b, "dtype": dtype,
               "torch_threads": t["threads"], "peer_gflop_per_frame": peer_gflop}
        if "error" in t:
            rows.append({**row, "note": t["error"]})
            lines.append(f"    {impl}: {t['error']}")
            continue
        eager = t["label"].startswith("eager")
        row.update({"first_step_s" if eager else "compile_s": t["first_step_s"],
                    "frames_per_s": t["fps"],
                    **_rates(j["gflop_per_frame"], t["fps"], ceiling, peak)})
        rows.append(row)
        fastest["eager" if eager else "compiled"].append(t["fps"])
        lines.append(f"    {impl} ({t['threads']} threads): {t['fps']:9.1f} frames/s "
                     f"({'first step' if eager else 'compile + first step'} "
                     f"{t['first_step_s']:.1f} s; {_mfu_text(row)}) | jaml/torch "
                     f"{fps / t['fps']:.2f}×")
    for run, key in (("eager", "speedup_vs_pytorch"), ("compiled", "speedup_vs_pytorch_compiled")):
        if fastest[run]:  # each jaml row against the peer's fastest variant of that kind
            for r in jaml_rows:
                r[key] = r["frames_per_s"] / max(fastest[run])
    print("\n".join(lines), flush=True)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--learners", nargs="+", default=["VAE_rpl"],
                        choices=["VAE_rpl", "PRED", "DSA"])
    parser.add_argument("--batches", type=int, nargs="+", default=[64, 256])
    parser.add_argument("--matmul-size", type=int, default=8192,
                        help="n of the n × n × n matmul that sets the ceiling")
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--dtypes", nargs="+", default=["float32"],
                        choices=["float32", "bfloat16"],
                        help="convolution compute dtypes, each measured for both sides")
    parser.add_argument("--torch", nargs="*", default=["eager", "compiled"],
                        choices=["eager", "compiled"],
                        help="the PyTorch peer's rows (none: jaml alone; skipped without torch)")
    parser.add_argument("--torch-compile-modes", nargs="+", default=list(DEFAULT_COMPILE_MODES),
                        metavar="MODE", help="torch.compile modes, a row each (default, "
                        "reduce-overhead, max-autotune, max-autotune-no-cudagraphs)")
    parser.add_argument("--torch-memory-formats", nargs="+", default=["channels_last"],
                        choices=MEMORY_FORMATS, help="the peer's activation and conv-weight "
                        "layouts, a row each per mode (eager included)")
    parser.add_argument("--upsample-forms", nargs="+", default=["auto"],
                        choices=list(UPSAMPLE_FORMS), help="jaml's decoder formulations "
                        "(LearnerConfig.upsample_form), a row each; ratios are the first's")
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    tl = torch_peer() if args.torch else None
    modes = ([None] if "eager" in args.torch else []) + (
        list(args.torch_compile_modes) if "compiled" in args.torch else [])
    variants = [(mode, fmt) for mode in modes for fmt in args.torch_memory_formats]
    if tl is not None:
        import torch

        if torch.cuda.is_available():
            # JAX takes memory as it needs it, after the peer has released its own.
            os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
        setup_torch()
        print(f"torch {torch.__version__}: {len(variants)} peer variant(s) per case, each "
              "before jaml's step", flush=True)
    elif args.torch:
        print("torch does not import: jaml's rows only")
        variants = []
    print(f"device: {jax.devices()[0].device_kind} ({jax.default_backend()}), "
          f"jax {jax.__version__}, python {platform.python_version()}, {platform.processor()}")
    print(f"train steps (ld_dim {LD_DIM}, Adam), median of {args.reps} reps × {args.steps} steps")
    peer_gflop = {}  # the peer's own count, per learner (the same in every dtype)
    for name in args.learners if variants else ():
        t = tl.seq_len(name, LD_DIM)
        peer_gflop[name] = sum(tl.useful_flops(name, 2, ld_dim=LD_DIM,
                                               action_dim=ACTION_DIM).values()) / 2 / t / 1e9
        print(f"{name}: the peer's own count {peer_gflop[name]:.3f} GFLOP/frame "
              "(FlopCounterMode, convolutions by real taps)")
    for dtype in args.dtypes:
        ceiling = matmul_ceiling(dtype, args.matmul_size)
        print(f"{dtype}: {args.matmul_size}³ matmul ceiling {ceiling:.3g} TFLOP/s", flush=True)
        for name in args.learners:
            for b in args.batches:
                peers = []
                for mode, fmt in variants:
                    r = bench_torch(name, b, args.reps, args.steps, dtype, mode,
                                    memory_format=fmt)
                    peers.append(r)
                    print(f"  {name} batch {b} {dtype} {r['label']}: "
                          + (r["error"] if "error" in r else f"{r['fps']:.1f} frames/s"),
                          flush=True)
                rows = _compare(name, b, dtype, args.reps, args.steps, ceiling, peers,
                                peer_gflop.get(name), args.upsample_forms)
                if not args.no_record:
                    harness.record("learner_throughput", rows, notes=NOTES)
    return 0


if __name__ == "__main__":
    sys.exit(main())
