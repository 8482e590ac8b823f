"""Training throughput (frames/s) of a learner's train step, jaml vs its PyTorch peer.

    python benchmarks/learner_throughput.py [--learners VAE_rpl PRED DSA SVAE]
        [--frames 64 256 1024] [--reps 5] [--steps 3] [--dtypes float32 bfloat16]
        [--torch eager compiled]
        [--torch-compile-modes max-autotune-no-cudagraphs default]
        [--torch-memory-formats channels_last contiguous] [--upsample-forms auto dilated phase]
        [--max-unroll 32] [--case-timeout 200]

A case's size is in frames per step, as the stream's (`StreamConfig.frames_per_batch`): a step
of F frames is B = F // T sequences of a learner's T frames (T = 1 for VAE_rpl, 24 for PRED and
DSA), B·T frames, and both sides get the same B sequences. Rows carry `batch` (B),
`seq_len` (T) and `frames_per_step` (B·T); a sequence learner's case names all three.

jaml's rows carry the step's useful FLOPs per frame (`benchmarks/flops.py`: the convolutions and
matmuls the model asks for, counted from its jaxpr; XLA's own `cost_analysis` counts no cuDNN
convolution on a GPU), the useful TFLOP/s they imply, and that rate as a share (MFU) of a matmul
ceiling measured in the same run (a large matmul in the same dtype) and, on a device whose dense
peak is known, of that quoted peak. A frame is one frame a step reads (B·T). Compile time is
reported apart; steady state is the median over `reps` blocked repetitions of `steps` train steps
each. jaml's step is compiled with `learners.compiler_options()`
(on the CPU: convolutions on XLA's Eigen path, not YNNPACK; elsewhere XLA's defaults). Its
decoder's transposed convolutions run in each `--upsample-forms` formulation, a row each: "auto"
(the learner's default: "phase" on the CPU, "pair" elsewhere), "subpixel", "phase", "dilated"
(XLA's input-dilated convolution), "pair"; the useful FLOPs are the same for all.

If torch imports, the same network in PyTorch (`benchmarks/peers/torch_learners.py`: VAE_rpl,
PRED and DSA with jaml's parameter counts and FLOPs; SVAE has no peer and gets jaml's rows
alone) is timed the same way in the same run on the same device: eager, and its whole train
step (zero_grad, forward, backward, Adam) under
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
casts the MLP, heads and RNNs). Case by case (learner, dtype, batch), on a GPU
(`--order peer-first`) the peer's variants run first and release their memory, then jaml's step
(XLA_PYTHON_CLIENT_PREALLOCATE=false, set here unless already set). On the CPU (`--order
separate`) each side runs alone in new processes of this script, `--processes` a side, the
sides' processes taking turns: in one process the two sides move each other's rates, one
after the other or in turns within each repetition (`--order interleaved`; measured in
docs/notes/learners.md), and a user runs one of them alone. Rows carry each round's rate
(`frames_per_s_rounds`: a repetition's, or with `paired: process` a process's median), and
jaml's paired rows the range of its per-round ratios to the peer (`speedup_vs_pytorch_rounds`,
`speedup_vs_pytorch_compiled_rounds`). The case's rows are recorded at once, so a run cut
short keeps the cases it finished. A peer variant or jaml form that fails (out of memory, a
compiler error) is a row with the error's first line, not fatal; jaml's compiled step is
checked against the device's free memory before it runs (`memory_shortfall`), and with
`--case-timeout` a case that runs past it is recorded as far as it got, with an error row for
the impl that did not finish.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import platform
import statistics
import sys
import threading
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import flops, harness
from jaml import _huge_pages, learners
from jaml.configs.learners import UPSAMPLE_FORMS, default_config
from jaml.learners import networks

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


def _round_rates(runners, frames_per_step: int, reps: int, steps: int) -> list[list[float]]:
    """Frames/s of each runner (`run_steps(n)`, blocking) in each of `reps` rounds of `steps`
    steps: the runners take their turns within a round, so load that comes and goes falls on
    all of them."""
    rates = [[] for _ in runners]
    for _ in range(reps):
        for run_steps, out in zip(runners, rates, strict=True):
            t0 = time.perf_counter()
            run_steps(steps)
            out.append(frames_per_step * steps / (time.perf_counter() - t0))
    return rates


def step_shape(learner_name: str, frames: int) -> tuple[int, int]:
    """(B sequences, T frames each) of a train step on `frames` frames, batched as the stream
    batches them (`StreamConfig.frames_per_batch`): B = frames // T, so a sequence learner's
    step reads B·T ≤ frames frames and a single-frame learner's batch is `frames`."""
    t = default_config(learner_name, ld_dim=LD_DIM).seq_len
    if frames < t:
        raise ValueError(f"{frames} frames hold no {t}-frame {learner_name} sequence")
    return frames // t, t


def useful_gflop_per_frame(learner_name: str, sequences: int, dtype: str) -> float:
    """The model's FLOPs per frame of one train step on `sequences` sequences, counted from the
    jaxpr (traced on shapes alone: no device memory)."""
    # Useful work is the model's, whatever formulation runs: counted on the plain (input-dilated)
    # transposed convolutions, whose inserted zeros flops.py does not count (the sub-pixel form
    # executes 36 taps an output phase where 16 meet real input).
    plain = learners.make(learner_name, ld_dim=LD_DIM, compute_dtype=dtype,
                          upsample_form="dilated")
    count = flops.flops(*abstract_step(plain, sequences))
    return count / (sequences * plain.config.seq_len) / 1e9


def abstract_step(learner, sequences: int) -> tuple:
    """(train step, state, batch, key) of `learner` with Adam on `sequences` sequences, the
    state and batch as shapes alone: a step to trace, not to run."""
    opt = learners.default_optimizer(learner)
    t = learner.config.seq_len
    batch = (jax.ShapeDtypeStruct((sequences, t, 64, 64, 3), np.uint8),
             jax.ShapeDtypeStruct((sequences, t, ACTION_DIM), np.float32))
    state = jax.eval_shape(lambda *batch: learners.init_train_state(
        learner, opt, jax.random.key(0), batch), *batch)
    return learners.make_train_step(learner, opt), state, batch, jax.random.key(0)


def memory_shortfall(analysis, stats: dict | None) -> str | None:
    """Why a compiled program cannot run on a device, or None: what it allocates beyond its
    arguments (temporaries and outputs, less the donated buffers it reuses) against the device
    allocator's free bytes (`Device.memory_stats()`; None, as on the CPU: not checked)."""
    if not stats or "bytes_limit" not in stats:
        return None
    need = (analysis.temp_size_in_bytes + analysis.output_size_in_bytes
            - analysis.alias_size_in_bytes)
    free = stats["bytes_limit"] - stats.get("bytes_in_use", 0)
    if need <= free:
        return None
    limit = stats["bytes_limit"] / 2**30
    return (f"out of memory: the compiled step needs {need / 2**30:.1f} GiB beyond its "
            f"arguments, {free / 2**30:.1f} GiB of the allocator's {limit:.1f} GiB are free")


def _first_line(e: Exception) -> str:
    lines = [ln for ln in str(e).splitlines() if ln.strip()] or [""]
    return f"{type(e).__name__}: {lines[0][:160]}"


def jaml_step(learner_name: str, sequences: int, dtype: str = "float32",
              upsample_form: str = "auto", activation_dtype: str = "float32"):
    """(train step jitted as the benchmark runs it, its first state, a device batch) of a
    learner on `sequences` random sequences."""
    learner = learners.make(learner_name, ld_dim=LD_DIM, compute_dtype=dtype,
                            upsample_form=upsample_form, activation_dtype=activation_dtype)
    opt = learners.default_optimizer(learner)
    batch = tuple(jax.device_put(x) for x in _batch(sequences, learner.config.seq_len))
    state = learners.init_train_state(learner, opt, jax.random.key(0), batch)
    step = jax.jit(learners.make_train_step(learner, opt), donate_argnums=0,
                   compiler_options=learners.compiler_options())
    return step, state, batch


@contextlib.contextmanager
def jaml_prepared(sequences: int, dtype: str = "float32", learner_name: str = "VAE_rpl",
                  upsample_form: str = "auto", activation_dtype: str = "float32"):
    """jaml's train step on `sequences` sequences compiled (timed apart) and warmed up by one
    step: {"run_steps", "frames", "compile_s", "xla_gflop_per_frame", "temp_gib"}, or
    {"error": ...} when it fails: a compiled step that needs more memory than the device has
    free (not run), or an error from XLA (its first line)."""
    try:
        jitted, state, batch = jaml_step(learner_name, sequences, dtype, upsample_form,
                                         activation_dtype)
        t0 = time.perf_counter()
        step = jitted.lower(state, batch, jax.random.key(0)).compile()
        compile_s = time.perf_counter() - t0
        analysis = step.memory_analysis()
        short = analysis and memory_shortfall(analysis, jax.devices()[0].memory_stats())
        if short:
            prepared = {"error": short}
        else:
            holder = {"state": state, "i": 0}
            del state  # donated to the first step
            # XLA's own count for the program it compiled (on a GPU it leaves out cuDNN's
            # convolutions).
            cost = step.cost_analysis()
            xla = (cost[0] if isinstance(cost, list) else cost or {}).get("flops",
                                                                           float("nan"))

            def run_steps(n):
                for _ in range(n):
                    holder["i"] += 1
                    holder["state"], metrics = step(holder["state"], batch,
                                                    jax.random.key(holder["i"]))
                jax.block_until_ready((holder["state"], metrics))

            run_steps(1)  # warm-up
            frames = batch[0].shape[0] * batch[0].shape[1]
            prepared = {"run_steps": run_steps, "frames": frames, "compile_s": compile_s,
                        "xla_gflop_per_frame": xla / frames / 1e9,
                        "temp_gib": (analysis.temp_size_in_bytes / 2**30 if analysis
                                     else float("nan"))}
    except Exception as e:  # XLA's RESOURCE_EXHAUSTED among them: a row, not the run's end
        prepared = {"error": _first_line(e)}
    yield prepared


def bench_jax(sequences: int, reps: int, steps: int, dtype: str = "float32",
              learner_name: str = "VAE_rpl", upsample_form: str = "auto",
              activation_dtype: str = "float32") -> dict:
    """jaml's train step on `sequences` sequences (`jaml_prepared`): frames/s, the median over
    reps of `steps` blocked steps, or {"error": ...}."""
    with jaml_prepared(sequences, dtype, learner_name, upsample_form,
                       activation_dtype) as prepared:
        return _timed(prepared, reps, steps)


def _timed(prepared: dict, reps: int, steps: int) -> dict:
    """A prepared side's result: its rates over `reps` rounds of `steps` steps, alone."""
    if "error" in prepared:
        return prepared
    (rates,) = _round_rates([prepared["run_steps"]], prepared["frames"], reps, steps)
    return _result(prepared, rates)


def _result(prepared: dict, rates: list[float]) -> dict:
    """A side's result: what it prepared (less its runner) with its rates per round and their
    median as "fps"."""
    return {**_described(prepared), "fps": statistics.median(rates), "rounds": rates}


def _described(prepared: dict) -> dict:
    """What a prepared side says of itself, less its runner and frame count."""
    return {k: v for k, v in prepared.items() if k not in ("run_steps", "frames")}


# Inductor's autotuned kernels without CUDA graphs (its autotuning takes minutes a case on an
# H100: a GPU job runs one learner and mode per process).
NOTES = ("Frames/s of one training step (forward, backward, Adam) on random 64×64 frames; "
         "useful FLOPs counted from the jaxpr (benchmarks/flops.py), MFU against a matmul "
         "measured in the same run and the quoted dense peak; the PyTorch peer "
         "(benchmarks/peers/torch_learners.py) is the same network in the same run on the same "
         "device (cuDNN autotune, TF32), eager and torch.compile'd, in the layout its label "
         "names, its rates from jaml's FLOP count; jaml's step compiled with "
         "learners.compiler_options(); bfloat16 rows: jaml's convolutions in bfloat16, the peer "
         "under torch.autocast(bfloat16). batch: sequences of seq_len frames, "
         "frames_per_step = batch × seq_len (frames // T sequences of a --frames size); "
         "temp_gib: the compiled jaml step's temporaries (XLA's memory_analysis); "
         "frames_per_s_rounds: each repetition's rate, or with paired = process each "
         "process's (each side alone in new processes taking turns, the CPU's order); "
         "speedup_…_rounds (paired rows): the range of jaml's per-round ratios.")
DEFAULT_COMPILE_MODES = ("max-autotune-no-cudagraphs",)
MEMORY_FORMATS = ("channels_last", "contiguous")


def torch_peer():
    """benchmarks.peers.torch_learners, or None where torch does not import."""
    try:
        from benchmarks.peers import torch_learners
    except ImportError:
        return None
    return torch_learners


def setup_torch(variants: int) -> None:
    """What a careful PyTorch user switches on (process-wide, so here, not in the peer)."""
    import torch

    if torch.cuda.is_available():
        # JAX takes memory as it needs it, after the peer has released its own.
        os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    torch.backends.cudnn.benchmark = True
    torch.set_float32_matmul_precision("high")  # TF32 matmuls (convolutions: cuDNN's default)
    print(f"torch {torch.__version__}: {variants} peer variant(s) per case, each before jaml's "
          "step", flush=True)


@contextlib.contextmanager
def torch_prepared(name: str, sequences: int, dtype: str = "float32",
                   compile_mode: str | None = None, warmup: int = 3,
                   memory_format: str = "channels_last"):
    """The peer's train step on `sequences` sequences (jaml's), run once (timed apart:
    compilation, cuDNN autotuning) and `warmup` more times (CUDA graph recording under
    reduce-overhead): {"run_steps", "frames", "label", "version", "device", "threads",
    "first_step_s"}, or those with "error" in place of the runner when it fails (out of memory,
    a compiler error: its first line). The model, its optimizer state and compiled graphs are
    released on leaving."""
    import torch

    tl = torch_peer()
    device = _torch_device()
    variant = tl.Variant(compile_mode, channels_last=memory_format == "channels_last",
                         dtype=dtype)
    info = {"label": variant.label, "version": torch.__version__, "device": str(device),
            "threads": torch.get_num_threads()}
    torch._dynamo.reset()  # a fresh compile per case, free of earlier cases' guards
    peer = None
    try:
        try:
            peer = tl.Peer(name, variant, ld_dim=LD_DIM, action_dim=ACTION_DIM, device=device)
            batch = peer.batch(*_batch(sequences, tl.seq_len(name, LD_DIM)))

            def run_steps(n):
                with peer.host_context():
                    for _ in range(n):
                        peer.step(*batch)
                if device.type == "cuda":
                    torch.cuda.synchronize()  # time the work, not the launches

            t0 = time.perf_counter()
            run_steps(1)
            first_s = time.perf_counter() - t0
            run_steps(warmup)
            prepared = {**info, "run_steps": run_steps, "first_step_s": first_s,
                        "frames": sequences * tl.seq_len(name, LD_DIM)}
        except torch.OutOfMemoryError as e:
            prepared = {**info, "error": f"out of memory: {str(e).splitlines()[0][:120]}"}
        except Exception as e:
            prepared = {**info, "error": _first_line(e)}
        yield prepared
    finally:
        peer = None  # the model, its optimizer state and compiled graphs, released
        torch._dynamo.reset()
        if device.type == "cuda":
            torch.cuda.empty_cache()


def bench_torch(name: str, sequences: int, reps: int, steps: int, dtype: str = "float32",
                compile_mode: str | None = None, warmup: int = 3,
                memory_format: str = "channels_last") -> dict:
    """The peer's train step (`torch_prepared`): frames/s, the median over reps of `steps`
    synchronised steps, or its info with {"error": ...}."""
    with torch_prepared(name, sequences, dtype, compile_mode, warmup,
                        memory_format) as prepared:
        try:
            return _timed(prepared, reps, steps)
        except Exception as e:  # out of memory in a timed step, say
            return _described(prepared) | {"error": _first_line(e)}


def _torch_device():
    import torch

    # The peer runs where jaml runs: on the GPU when there is one.
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def _jaml_impl(form: str, activation_dtype: str = "float32") -> str:
    """A jaml row's impl: the learner's defaults plainly, another form or activation dtype by
    name."""
    return ", ".join(["jaml"] + ([f"upsample {form}"] if form != "auto" else [])
                     + ([f"{activation_dtype} activations"]
                        if activation_dtype != "float32" else []))


def _peer_impl(version: str, label: str, device: str) -> str:
    return f"pytorch {version} {label} ({device})"


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


@dataclasses.dataclass
class Case:
    """One learner at one step size and dtype: what its sides measured so far (`jaml`:
    ((upsample form, activation dtype), `bench_jax` result); `peers`: `bench_torch` results;
    each result's "rounds" its rate in each round) and the impl now running, so that a case
    cut short still gives its rows (`rows`)."""

    learner: str
    sequences: int
    seq_len: int
    dtype: str
    ceiling: float
    peak: float | None
    gflop_per_frame: float
    peer_gflop: float | None = None
    jaml: list = dataclasses.field(default_factory=list)
    peers: list = dataclasses.field(default_factory=list)
    running: str | None = None
    paired: str | None = None  # "repetition" or "process": the sides' rounds taken in turns

    @property
    def frames(self) -> int:
        return self.sequences * self.seq_len

    @property
    def name(self) -> str:
        size = (f"batch {self.frames}" if self.seq_len == 1 else
                f"{self.frames} frames ({self.sequences} sequence{'s' * (self.sequences > 1)}"
                f" × {self.seq_len})")
        return (f"{self.learner} train step, {size}"
                + ("" if self.dtype == "float32" else f", {self.dtype}"))

    def rows(self, timeout_s: float | None = None) -> list[dict]:
        """A row per jaml form and peer variant measured (an error row for each that failed),
        and with `timeout_s`, an error row for the impl still running when the case's time ran
        out. jaml's speedups: each row against the peer's fastest eager and compiled rows."""
        base = {"case": self.name, "learner": self.learner, "batch": self.sequences,
                "seq_len": self.seq_len, "frames_per_step": self.frames, "dtype": self.dtype,
                **({"paired": self.paired} if self.paired else {})}
        jaml_rows, rows = [], []
        for form, j in self.jaml:
            row = {**base, "impl": _jaml_impl(*form)}
            if "error" in j:
                rows.append({**row, "note": j["error"]})
                continue
            row.update({"compile_s": j["compile_s"], "frames_per_s": j["fps"],
                        **_rounds(j),
                        **_rates(self.gflop_per_frame, j["fps"], self.ceiling, self.peak),
                        "xla_gflop_per_frame": j["xla_gflop_per_frame"],
                        "temp_gib": j["temp_gib"]})
            jaml_rows.append(row)
            rows.append(row)
        fastest = {"eager": [], "compiled": []}
        for t in self.peers:
            row = {**base, "impl": _peer_impl(t["version"], t["label"], t["device"]),
                   "torch_threads": t["threads"],
                   "peer_gflop_per_frame": self.peer_gflop}
            if "error" in t:
                rows.append({**row, "note": t["error"]})
                continue
            eager = t["label"].startswith("eager")
            row.update({"first_step_s" if eager else "compile_s": t["first_step_s"],
                        "frames_per_s": t["fps"], **_rounds(t),
                        **_rates(self.gflop_per_frame, t["fps"], self.ceiling, self.peak)})
            rows.append(row)
            fastest["eager" if eager else "compiled"].append(t)
        if timeout_s is not None and self.running:
            rows.append({**base, "impl": self.running,
                         "note": f"did not finish within the case's {timeout_s:g} s "
                                 "(--case-timeout)"})
        for run, key in (("eager", "speedup_vs_pytorch"),
                         ("compiled", "speedup_vs_pytorch_compiled")):
            if fastest[run]:
                peer = max(fastest[run], key=lambda t: t["fps"])
                for r in jaml_rows:
                    r[key] = r["frames_per_s"] / peer["fps"]
                    if self.paired:  # each round's ratio: the spread a ratio has here
                        ratios = [a / b for a, b in zip(r["frames_per_s_rounds"],
                                                        peer["rounds"], strict=True)]
                        r[f"{key}_rounds"] = [min(ratios), max(ratios)]
        return rows


def _round_ranges(row: dict) -> list[tuple[str, tuple[float, float]]]:
    """(eager or compiled, (lowest, highest) per-round ratio) of a paired jaml row."""
    return [(run, tuple(row[key])) for run, key in (
        ("eager", "speedup_vs_pytorch_rounds"),
        ("compiled", "speedup_vs_pytorch_compiled_rounds")) if key in row]


def _rounds(result: dict) -> dict:
    """A row's rate in each round, where its result has them."""
    return {"frames_per_s_rounds": result["rounds"]} if "rounds" in result else {}


def _lines(rows: list[dict]) -> str:
    """The case's rows as the run prints them; the jaml/torch ratio is the first jaml row's."""
    first = next((r["frames_per_s"] for r in rows
                  if r["impl"].startswith("jaml") and "frames_per_s" in r), None)
    lines = []
    for r in rows:
        jaml = r["impl"].startswith("jaml")
        head = f"{r['case']}: {r['impl']}" if jaml else f"    {r['impl']}"
        if "note" in r:
            lines.append(f"{head}: {r['note']}")
        elif jaml:
            lines.append(f"{head} {r['frames_per_s']:9.1f} frames/s (compile {r['compile_s']:.1f}"
                         f" s, {r['temp_gib']:.2f} GiB of temporaries; "
                         f"{r['useful_gflop_per_frame']:.3f} useful GFLOP/frame, {_mfu_text(r)})"
                         + "".join(f"; {lo:.2f}–{hi:.2f}× the fastest {run} peer per "
                                   f"{r.get('paired', 'round')}"
                                   for run, (lo, hi) in _round_ranges(r)))
        else:
            eager = "first_step_s" in r
            ratio = f" | jaml/torch {first / r['frames_per_s']:.2f}×" if first else ""
            lines.append(f"{head} ({r['torch_threads']} threads): {r['frames_per_s']:9.1f} "
                         f"frames/s ({'first step' if eager else 'compile + first step'} "
                         f"{r['first_step_s' if eager else 'compile_s']:.1f} s; "
                         f"{_mfu_text(r)}){ratio}")
    return "\n".join(lines)


ORDERS = ("separate", "interleaved", "peer-first")


def measure_case(case: Case, reps: int, steps: int, variants, jaml_variants,
                 order: str = "peer-first", processes: int = 3) -> list[dict]:
    """The peer's variants and jaml's step in each (upsample form, activation dtype), in one of
    `ORDERS`. peer-first: in this process one after another, each peer variant releasing its
    memory before the next side is built (a GPU's way). interleaved: every side built first,
    then timed in turns within each repetition (`_round_rates`). separate: each side alone in
    a new process of this script, `processes` of them a side, the sides' processes taking
    turns (the CPU's way: in one process the two sides move each other's rates)."""
    sides = ([("peer", (mode, fmt)) for mode, fmt in variants]
             + [("jaml", (form, act)) for form, act in jaml_variants])
    if order == "separate":
        runs = {side: [] for side in sides}
        for _ in range(processes):
            for side in sides:
                case.running = _running(case, *side)
                runs[side].append(_side_in_a_process(case, *side, reps, steps))
        results = {side: _across_processes(found) for side, found in runs.items()}
        case.paired = "process"
    else:
        with contextlib.ExitStack() as held:
            built = {}
            for side in sides:
                case.running = _running(case, *side)
                if order == "interleaved":
                    built[side] = held.enter_context(_prepared(case, *side))
                else:
                    built[side] = _measured(case.learner, case.sequences, case.dtype, *side,
                                            reps, steps)
                    print(f"  {case.name} {case.running}: " + (
                        built[side]["error"] if "error" in built[side]
                        else f"{built[side]['fps']:.1f} frames/s"), flush=True)
            results = built
            if order == "interleaved":
                case.running = "the sides' rounds, interleaved"
                live = [side for side in sides if "error" not in built[side]]
                rates = _round_rates([built[side]["run_steps"] for side in live], case.frames,
                                     reps, steps)
                results = {side: built[side] if side not in live else
                           _result(built[side], rates[live.index(side)]) for side in sides}
                case.paired = "repetition"
    for (kind, key) in sides:
        if kind == "peer":
            case.peers.append(results[kind, key])
        else:
            case.jaml.append((key, results[kind, key]))
    case.running = None
    rows = case.rows()
    print(_lines(rows), flush=True)
    return rows


def _running(case: Case, kind: str, key: tuple) -> str:
    return _peer_running(case.dtype, *key) if kind == "peer" else _jaml_impl(*key)


def _prepared(case: Case, kind: str, key: tuple):
    """A side built and warmed up in this process (a context: the peer is released on
    leaving)."""
    if kind == "peer":
        mode, fmt = key
        return torch_prepared(case.learner, case.sequences, case.dtype, mode, memory_format=fmt)
    return jaml_prepared(case.sequences, case.dtype, case.learner, *key)


def _measured(learner: str, sequences: int, dtype: str, kind: str, key: tuple, reps: int,
              steps: int) -> dict:
    """A side's result, measured alone in this process."""
    if kind == "peer":
        mode, fmt = key
        return bench_torch(learner, sequences, reps, steps, dtype, mode, memory_format=fmt)
    return bench_jax(sequences, reps, steps, dtype, learner, *key)


def _side_in_a_process(case: Case, kind: str, key: tuple, reps: int, steps: int) -> dict:
    """A side's result measured in a new process of this script (`--side`), or its error."""
    spec = [kind, list(key), case.learner, case.sequences, case.dtype, reps, steps,
            networks._MAX_UNROLL]
    try:
        return harness.child_result(__file__, "--side", json.dumps(spec))
    except RuntimeError as e:
        return {"error": str(e)}


def _side_here(spec: list) -> dict:
    """`--side`: one side of a case measured in this process (`_side_in_a_process`'s child)."""
    kind, key, learner, sequences, dtype, reps, steps, unroll = spec
    networks._MAX_UNROLL = unroll
    if kind == "peer":
        setup_torch(1)
    return _measured(learner, sequences, dtype, kind, tuple(key), reps, steps)


def _across_processes(found: list[dict]) -> dict:
    """A side's result over its processes: the median process's rate, each process's rate as
    its "rounds", the rest from the first process; the first error if any process failed."""
    failed = [r for r in found if "error" in r]
    if failed:
        return failed[0]
    rates = [r["fps"] for r in found]
    return {**found[0], "fps": statistics.median(rates), "rounds": rates}


def _peer_running(dtype: str, mode: str | None, memory_format: str) -> str:
    """The impl a peer variant's row will name."""
    import torch

    label = torch_peer().Variant(mode, channels_last=memory_format == "channels_last",
                                 dtype=dtype).label
    return _peer_impl(torch.__version__, label, str(_torch_device()))


def _watch(case: Case, seconds: float | None, record: bool) -> threading.Timer | None:
    """After `seconds`, the case's rows so far and an error row for the impl still running are
    recorded and the process exits (status 3): a step XLA cannot fit (it retries its allocator
    and rematerialisation for minutes) or a compiler that does not return cannot be cancelled
    from Python."""
    if not seconds:
        return None

    def give_up():
        if case.running is None:  # the case has just finished: the main thread records it
            return
        rows = case.rows(timeout_s=seconds)
        print(_lines(rows), flush=True)
        if record:
            harness.record("learner_throughput", rows, notes=NOTES)
        os._exit(3)

    timer = threading.Timer(seconds, give_up)
    timer.daemon = True
    timer.start()
    return timer


def main(argv=None) -> int:
    if argv is None:  # a process of its own runs as jaml's commands do
        _huge_pages.adopt()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--learners", nargs="+", default=["VAE_rpl"],
                        choices=["VAE_rpl", "PRED", "DSA", "SVAE"])
    parser.add_argument("--frames", type=int, nargs="+", default=[64, 256],
                        help="frames per train step, a case each: frames // T sequences of a "
                        "learner's T frames (the stream's frames_per_batch)")
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
    parser.add_argument("--activation-dtypes", nargs="+", default=["float32"],
                        choices=["float32", "bfloat16"], help="jaml's activation dtypes "
                        "(LearnerConfig.activation_dtype), a row each per upsample form")
    parser.add_argument("--max-unroll", type=int, default=None, metavar="N",
                        help="off the CPU, the most recurrent steps jaml's layers unroll per "
                        "loop iteration (DSA, SVAE; `networks.scan_unroll`; default: jaml's), "
                        "named in its rows")
    parser.add_argument("--case-timeout", type=float, default=None, metavar="S",
                        help="seconds a case (peer variants and jaml forms) may take; past "
                        "them its rows so far and an error row for the impl still running are "
                        "recorded, and the run ends")
    parser.add_argument("--order", choices=["auto", *ORDERS], default="auto",
                        help="separate: each side alone in new processes, --processes a side, "
                        "taking turns; interleaved: every side built in this process, then "
                        "timed in turns within each repetition; peer-first: the peer's variants "
                        "one after another in this process, each released before jaml's step "
                        "is built (auto: separate on the CPU, peer-first elsewhere)")
    parser.add_argument("--processes", type=int, default=3,
                        help="processes a side with --order separate")
    parser.add_argument("--side", help=argparse.SUPPRESS)  # a --order separate child
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    if args.side:  # one side in this process: its result on stdout's last line
        print(json.dumps(_side_here(json.loads(args.side))), flush=True)
        return 0
    if args.processes < 1:
        parser.error(f"--processes must be at least 1, got {args.processes}")
    order = args.order if args.order != "auto" else (
        "separate" if jax.default_backend() == "cpu" else "peer-first")
    if args.max_unroll is not None:
        if args.max_unroll < 1:
            parser.error(f"--max-unroll must be ≥ 1, got {args.max_unroll}")
        networks._MAX_UNROLL = args.max_unroll
    try:
        shapes = {(name, f): step_shape(name, f) for name in args.learners for f in args.frames}
    except ValueError as e:
        parser.error(str(e))
    tl = torch_peer() if args.torch else None
    modes = ([None] if "eager" in args.torch else []) + (
        list(args.torch_compile_modes) if "compiled" in args.torch else [])
    variants = [(mode, fmt) for mode in modes for fmt in args.torch_memory_formats]
    if tl is not None:
        setup_torch(len(variants))
    elif args.torch:
        print("torch does not import: jaml's rows only")
        variants = []
    print(f"device: {jax.devices()[0].device_kind} ({jax.default_backend()}), "
          f"jax {jax.__version__}, python {platform.python_version()}, {platform.processor()}")
    print(f"train steps (ld_dim {LD_DIM}, Adam), median of {args.reps} reps × {args.steps} steps"
          + {"separate": f", each side alone in {args.processes} processes taking turns",
             "interleaved": ", the sides in turns within each rep", "peer-first": ""}[order])
    peer_gflop = {}  # the peer's own count, per learner (the same in every dtype)
    peered = [n for n in args.learners if variants and n in tl.LEARNERS]
    for name in (n for n in args.learners if variants and n not in peered):
        print(f"{name}: no PyTorch peer (it has {', '.join(tl.LEARNERS)}): jaml's rows only")
    for name in peered:
        t = tl.seq_len(name, LD_DIM)
        peer_gflop[name] = sum(tl.useful_flops(name, 2, ld_dim=LD_DIM,
                                               action_dim=ACTION_DIM).values()) / 2 / t / 1e9
        print(f"{name}: the peer's own count {peer_gflop[name]:.3f} GFLOP/frame "
              "(FlopCounterMode, convolutions by real taps)")
    for dtype in args.dtypes:
        ceiling = matmul_ceiling(dtype, args.matmul_size)
        print(f"{dtype}: {args.matmul_size}³ matmul ceiling {ceiling:.3g} TFLOP/s", flush=True)
        for name in args.learners:
            for f in args.frames:
                sequences, seq_len = shapes[name, f]
                case = Case(name, sequences, seq_len, dtype, ceiling, quoted_peak(dtype),
                            useful_gflop_per_frame(name, sequences, dtype), peer_gflop.get(name))
                timer = _watch(case, args.case_timeout, not args.no_record)
                rows = measure_case(case, args.reps, args.steps,
                                    variants if name in peered else [],
                                    [(form, act) for act in args.activation_dtypes
                                     for form in args.upsample_forms], order,
                                    args.processes)
                if timer:
                    timer.cancel()
                if args.max_unroll is not None:
                    for row in (r for r in rows if r["impl"].startswith("jaml")):
                        row["impl"] += f", unroll ≤ {args.max_unroll}"
                if not args.no_record:
                    harness.record("learner_throughput", rows, notes=NOTES)
    return 0


if __name__ == "__main__":
    sys.exit(main())
