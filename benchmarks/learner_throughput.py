"""Training throughput (frames/s) of the VAE train step, jaml vs a PyTorch port of the same net.

    python benchmarks/learner_throughput.py [--batches 64 256 1024] [--reps 5] [--steps 3]
        [--dtypes float32 bfloat16]

jaml's row also carries XLA's FLOP count of the compiled step (`cost_analysis`, per frame) and
the rate it implies, to set the frames/s against the device's peak. Compile time is reported
apart; steady state is the median over `reps` blocked repetitions of
`steps` train steps each. jaml's step is compiled with `learners.compiler_options()` (on the CPU:
convolutions on XLA's Eigen path, not YNNPACK; elsewhere XLA's defaults). If torch imports, the
reference's network (suite_reference.md §4), written here in PyTorch, is timed the same way in
the same run, on the same device, and the ratio recorded. The peer gets what a careful PyTorch
user would switch on: cuDNN autotuning and TF32 matmuls (XLA already uses TF32 for float32
convolutions and matmuls on this class of GPU; PyTorch's convolutions use it by default, its
matmuls only when asked). With bfloat16, jaml's convolutions compute in bfloat16
(`compute_dtype`; parameters, batch norms, heads, loss and Adam float32) and the peer runs its
forward pass under `torch.autocast(dtype=torch.bfloat16)`, the mixed precision a PyTorch user
would reach for (it also casts the MLP and heads).
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

from benchmarks import harness
from jaml import learners

LD_DIM, ACTION_DIM = 4, 1  # CartPole: D = 4, latent 2·D = 8


def _batch(b: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, 256, (b, 1, 64, 64, 3), dtype=np.uint8)
    return frames, rng.normal(size=(b, 1, ACTION_DIM)).astype(np.float32)


def _median_rate(run_steps, frames_per_step: int, reps: int, steps: int) -> float:
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        run_steps(steps)
        times.append(time.perf_counter() - t0)
    return frames_per_step * steps / statistics.median(times)


def bench_jax(b: int, reps: int, steps: int, dtype: str = "float32") -> dict:
    learner = learners.make("VAE_rpl", ld_dim=LD_DIM, compute_dtype=dtype)
    opt = learners.default_optimizer(learner)
    batch = tuple(jax.device_put(x) for x in _batch(b))
    state = learners.init_train_state(learner, opt, jax.random.key(0), batch)
    t0 = time.perf_counter()
    step = jax.jit(learners.make_train_step(learner, opt), donate_argnums=0,
                   compiler_options=learners.compiler_options()).lower(
        state, batch, jax.random.key(0)).compile()
    compile_s = time.perf_counter() - t0
    holder = {"state": state, "i": 0}
    # XLA's own count for the program it compiled for this device (the GPU's formulation of
    # the transposed convolutions does 2.25x the decoder's multiply-adds of the CPU's).
    cost = step.cost_analysis()
    flops = (cost[0] if isinstance(cost, list) else cost or {}).get("flops", float("nan"))

    def run_steps(n):
        for _ in range(n):
            holder["i"] += 1
            holder["state"], metrics = step(holder["state"], batch, jax.random.key(holder["i"]))
        jax.block_until_ready((holder["state"], metrics))

    run_steps(1)  # warm-up
    return {"compile_s": compile_s, "fps": _median_rate(run_steps, b, reps, steps),
            "gflop_per_frame": flops / b / 1e9}


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


def _compare(b: int, dtype: str, reps: int, steps: int) -> list[dict]:
    """jaml and (if torch imports) the PyTorch peer at one batch size and dtype, in turn."""
    j = bench_jax(b, reps, steps, dtype)
    case = f"VAE train step, batch {b}" + ("" if dtype == "float32" else f", {dtype}")
    rows = [{"case": case, "impl": "jaml", "batch": b, "dtype": dtype,
             "compile_s": j["compile_s"], "frames_per_s": j["fps"],
             "xla_gflop_per_frame": j["gflop_per_frame"],
             "xla_tflop_per_s": j["gflop_per_frame"] * j["fps"] / 1e3}]
    line = (f"batch {b:4d} {dtype}: jaml {j['fps']:8.1f} frames/s "
            f"(compile {j['compile_s']:.1f} s; XLA counts {j['gflop_per_frame']:.3f} GFLOP/frame, "
            f"{rows[0]['xla_tflop_per_s']:.2f} TFLOP/s)")
    t = bench_torch(b, reps, steps, dtype)
    if t is not None:
        rows[0]["speedup_vs_pytorch"] = j["fps"] / t["fps"]
        rows.append({"case": case, "impl": f"pytorch {t['version']} eager ({t['device']})",
                     "batch": b, "dtype": dtype, "frames_per_s": t["fps"],
                     "first_step_s": t["first_step_s"], "torch_threads": t["threads"]})
        line += (f" | torch {t['version']} on {t['device']} ({t['threads']} threads) "
                 f"{t['fps']:8.1f} frames/s (first step {t['first_step_s']:.2f} s) | "
                 f"jaml/torch {j['fps'] / t['fps']:.2f}×")
    print(line, flush=True)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[64, 256])
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--dtypes", nargs="+", default=["float32"],
                        choices=["float32", "bfloat16"],
                        help="convolution compute dtypes, each measured for both sides")
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    print(f"device: {jax.devices()[0].device_kind} ({jax.default_backend()}), "
          f"jax {jax.__version__}, python {platform.python_version()}, {platform.processor()}")
    print(f"VAE_rpl train step (ld_dim {LD_DIM}, latent {2 * LD_DIM}, Adam), median of "
          f"{args.reps} reps × {args.steps} steps")
    rows = []
    for dtype in args.dtypes:
        for b in args.batches:
            rows += _compare(b, dtype, args.reps, args.steps)
    if not args.no_record:
        harness.record("learner_throughput", rows,
                       notes="Frames/s of one VAE_rpl training step (forward, backward, Adam) "
                             "on random 64×64 frames; the PyTorch peer is the same network in "
                             "the same run on the same device (cuDNN autotune, TF32); "
                             "jaml's step compiled with learners.compiler_options(); "
                             "bfloat16 rows: jaml's convolutions in bfloat16, the peer under "
                             "torch.autocast(bfloat16).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
