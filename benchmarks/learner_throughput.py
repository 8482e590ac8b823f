"""Training throughput (frames/s) of a learner's train step, jaml vs a PyTorch port of the VAE.

    python benchmarks/learner_throughput.py [--learners VAE_rpl PRED DSA] [--batches 64 256 1024]
        [--reps 5] [--steps 3] [--dtypes float32 bfloat16]

jaml's rows carry the step's useful FLOPs per frame (`benchmarks/flops.py`: the convolutions and
matmuls the model asks for, counted from its jaxpr; XLA's own `cost_analysis` counts no cuDNN
convolution on a GPU), the useful TFLOP/s they imply, and that rate as a share (MFU) of a matmul
ceiling measured in the same run (a large matmul in the same dtype) and, on a device whose dense
peak is known, of that quoted peak. A frame is one frame a step reads (batch × T for a sequence
learner). Compile time is reported apart; steady state is the median over `reps` blocked
repetitions of `steps` train steps each. jaml's step is compiled with `learners.compiler_options()`
(on the CPU: convolutions on XLA's Eigen path, not YNNPACK; elsewhere XLA's defaults). If torch
imports, the reference's network (suite_reference.md §4), written here in PyTorch, is timed the
same way in the same run, on the same device, and the ratio recorded. The peer gets what a careful
PyTorch user would switch on: cuDNN autotuning and TF32 matmuls (XLA already uses TF32 for float32
convolutions and matmuls on this class of GPU; PyTorch's convolutions use it by default, its
matmuls only when asked). With bfloat16, jaml's convolutions compute in bfloat16 (`compute_dtype`;
parameters, batch norms, heads, loss and Adam float32) and the peer runs its forward pass under
`torch.autocast(dtype=torch.bfloat16)`, the mixed precision a PyTorch user would reach for (it also
casts the MLP and heads).
"""

from __future__ import annotations

import argparse
import contextlib
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
              learner_name: str = "VAE_rpl") -> dict:
    learner = learners.make(learner_name, ld_dim=LD_DIM, compute_dtype=dtype)
    opt = learners.default_optimizer(learner)
    seq_len = learner.config.seq_len
    batch = tuple(jax.device_put(x) for x in _batch(b, seq_len))
    state = learners.init_train_state(learner, opt, jax.random.key(0), batch)
    train_step = learners.make_train_step(learner, opt)
    useful = flops.flops(train_step, state, batch, jax.random.key(0))
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


def bench_torch(b: int, reps: int, steps: int, dtype: str = "float32") -> dict | None:
    try:
        import torch
        from torch import nn
    except ImportError:
        return None

    def enc_block(i, o, k, s, p):
        return [nn.Conv2d(i, o, k, s, p, bias=False), nn.BatchNorm2d(o), nn.ELU()]

    class VAE(nn.Module):
        """The reference VAE: ConvStack → EncoderDynamic (MLP 1024, 512) → heads → ConvDecoder."""

        def __init__(self, z: int, a: int):
            super().__init__()
            self.conv = nn.Sequential(*enc_block(3, 64, 4, 2, 1), *enc_block(64, 128, 4, 2, 1),
                                      *enc_block(128, 128, 4, 2, 1),
                                      *enc_block(128, 256, 4, 2, 1),
                                      *enc_block(256, 128, 4, 1, 0))
            self.mlp = nn.Sequential(nn.Linear(128 + a, 1024), nn.ELU(), nn.Linear(1024, 512),
                                     nn.ELU())
            self.mu, self.logvar = nn.Linear(512, z), nn.Linear(512, z)
            self.dec = nn.Sequential(
                nn.ConvTranspose2d(z, 256, 4, 1, 0), nn.ELU(), nn.BatchNorm2d(256),
                nn.ConvTranspose2d(256, 128, 4, 2, 1), nn.ELU(), nn.BatchNorm2d(128),
                nn.ConvTranspose2d(128, 128, 4, 2, 1), nn.ELU(), nn.BatchNorm2d(128),
                nn.ConvTranspose2d(128, 64, 4, 2, 1), nn.ELU(),
                nn.ConvTranspose2d(64, 3, 4, 2, 1), nn.Sigmoid())

        def loss(self, frames, actions):
            x = frames.float() / 255.0
            h = self.mlp(torch.cat([self.conv(x).flatten(1), actions], dim=1))
            mu = nn.functional.elu(self.mu(h))
            logvar = torch.clamp(self.logvar(h), -6.0, 6.0)
            z = mu + torch.randn_like(mu) * torch.exp(0.5 * logvar)
            recon = self.dec(torch.sigmoid(z)[:, :, None, None])
            nll = 0.5 * (x - recon).square().sum(dim=(1, 2, 3))
            kl = 0.5 * (logvar.exp() + mu.square() - 1.0 - logvar).sum(dim=1)
            return (nll + kl).mean()

    # The peer runs where jaml runs: on the GPU when there is one.
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    torch.backends.cudnn.benchmark = True
    torch.backends.cuda.matmul.allow_tf32 = True
    torch.manual_seed(0)
    model = VAE(2 * LD_DIM, ACTION_DIM).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    frames, actions = _batch(b)
    frames = torch.from_numpy(frames[:, 0]).permute(0, 3, 1, 2).contiguous().to(device)  # NCHW
    actions = torch.from_numpy(actions[:, 0]).to(device)

    autocast = (torch.autocast(device.type, dtype=torch.bfloat16) if dtype == "bfloat16"
                else contextlib.nullcontext())

    def run_steps(n):
        for _ in range(n):
            opt.zero_grad(set_to_none=True)
            with autocast:
                loss = model.loss(frames, actions)
            loss.backward()
            opt.step()
        if device.type == "cuda":
            torch.cuda.synchronize()  # time the work, not the launches

    t0 = time.perf_counter()
    run_steps(1)  # warm-up (eager: no compilation, first-call allocation only)
    first_s = time.perf_counter() - t0
    return {"first_step_s": first_s, "fps": _median_rate(run_steps, b, reps, steps),
            "version": torch.__version__, "threads": torch.get_num_threads(),
            "device": str(device)}


def _compare(learner_name: str, b: int, dtype: str, reps: int, steps: int,
             ceiling: float) -> list[dict]:
    """jaml and (VAE_rpl, if torch imports) the PyTorch peer at one batch size and dtype."""
    j = bench_jax(b, reps, steps, dtype, learner_name)
    case = (f"{learner_name} train step, batch {b}" + (f" × {j['seq_len']} frames"
            if j["seq_len"] > 1 else "") + ("" if dtype == "float32" else f", {dtype}"))
    useful = j["gflop_per_frame"] * j["fps"] / 1e3
    peak = quoted_peak(dtype)
    rows = [{"case": case, "impl": "jaml", "learner": learner_name, "batch": b, "dtype": dtype,
             "compile_s": j["compile_s"], "frames_per_s": j["fps"],
             "useful_gflop_per_frame": j["gflop_per_frame"], "useful_tflop_per_s": useful,
             "xla_gflop_per_frame": j["xla_gflop_per_frame"],
             "matmul_ceiling_tflop_per_s": ceiling, "mfu_of_ceiling": useful / ceiling,
             **({"mfu_of_quoted_peak": useful / peak} if peak else {})}]
    line = (f"{case}: jaml {j['fps']:9.1f} frames/s (compile {j['compile_s']:.1f} s; "
            f"{j['gflop_per_frame']:.3f} useful GFLOP/frame, {useful:.2f} TFLOP/s, "
            f"{100 * useful / ceiling:.1f} % of the matmul ceiling"
            + (f", {100 * useful / peak:.1f} % of the quoted peak" if peak else "") + ")")
    t = bench_torch(b, reps, steps, dtype) if learner_name == "VAE_rpl" else None
    if t is not None:
        rows[0]["speedup_vs_pytorch"] = j["fps"] / t["fps"]
        rows.append({"case": case, "impl": f"pytorch {t['version']} eager ({t['device']})",
                     "learner": learner_name, "batch": b, "dtype": dtype,
                     "frames_per_s": t["fps"], "first_step_s": t["first_step_s"],
                     "torch_threads": t["threads"]})
        line += (f" | torch {t['version']} on {t['device']} ({t['threads']} threads) "
                 f"{t['fps']:8.1f} frames/s (first step {t['first_step_s']:.2f} s) | "
                 f"jaml/torch {j['fps'] / t['fps']:.2f}×")
    print(line, flush=True)
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
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    print(f"device: {jax.devices()[0].device_kind} ({jax.default_backend()}), "
          f"jax {jax.__version__}, python {platform.python_version()}, {platform.processor()}")
    print(f"train steps (ld_dim {LD_DIM}, Adam), median of {args.reps} reps × {args.steps} steps")
    rows = []
    for dtype in args.dtypes:
        ceiling = matmul_ceiling(dtype, args.matmul_size)
        print(f"{dtype}: {args.matmul_size}³ matmul ceiling {ceiling:.1f} TFLOP/s", flush=True)
        for name in args.learners:
            for b in args.batches:
                rows += _compare(name, b, dtype, args.reps, args.steps, ceiling)
    if not args.no_record:
        harness.record("learner_throughput", rows,
                       notes="Frames/s of one training step (forward, backward, Adam) on "
                             "random 64×64 frames; useful FLOPs counted from the jaxpr "
                             "(benchmarks/flops.py), MFU against a matmul measured in the "
                             "same run and the quoted dense peak; the PyTorch peer (VAE_rpl) "
                             "is the same network in the same run on the same device "
                             "(cuDNN autotune, TF32); "
                             "jaml's step compiled with learners.compiler_options(); "
                             "bfloat16 rows: jaml's convolutions in bfloat16, the peer under "
                             "torch.autocast(bfloat16).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
