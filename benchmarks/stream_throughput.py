"""Frames/s and epochs/s through the suite's learning loop (jaml.stream), compile time apart.

R runs of one config (seeds) train stacked, as `jaml.stream.run.run_many` trains them: one
compiled program, the runs vmapped and, with several devices, split across them. Three cases
per (env, learner, R), each timed as the median of blocked repeats of a block of `--epochs`
epochs (the state carried from call to call, as in a run):
  stream  — `Stream.act` of every run: physics + rendering + policy + PPO update + replay insert
            (the frame stream, docs/reference/perf_anchors.md §3, S3);
  loop    — whole epochs (`run_stacked_epochs`): the stream plus `learner_steps` learner
            updates on replay batches; env frames/s collected, learner frames/s trained and
            epochs/s, all aggregated over the R runs;
  learner — the learner updates alone, on batches sampled from the filled replay;
  analysis — one analysis of the R runs (`analysis.evaluate_runs`, as a run calls it: the
            π_rand sets kept after the first, so a repeat encodes them again), seconds per
            part (train_set, pi_rand, pi_curr, regressor) the median over the repeats.
The peer of a row is the same code at R = 1 in the same run (`speedup_vs_one_run`): the loop
before runs were stacked. There is no peer for the whole loop from the paper's PyBullet +
PyTorch stack here; its anchors are in `docs/reference/perf_anchors.md`.

    python benchmarks/stream_throughput.py --runs 1 6 12             # GPU, paper's 64 envs
    python benchmarks/stream_throughput.py --quick --no-record       # tiny CPU smoke run
    python benchmarks/stream_throughput.py --runs 4 --cases stream loop --cuda-graphs on off
        # the Stream's CUDA graphs against XLA's default command buffers, in one process
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
from pathlib import Path

import jax

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness
from jaml import _huge_pages, learners
from jaml.stream import analysis, build, for_env
from jaml.stream.executor import run_stacked_epochs, runs_mesh, stack_runs
from jaml.stream.loop import _act_runs, _learn_step_runs

CASES = ("stream", "loop", "learner", "analysis")


def bench(env: str, learner: str, runs: int, num_envs: int, epochs: int, frames_per_batch: int,
          replay_slots: int, repeats: int, devices: int | None,
          compute_dtype: str = "float32", activation_dtype: str = "float32",
          eval_sizes: dict | None = None, only: tuple[str, ...] = CASES,
          cuda_graphs: bool = True) -> list[dict]:
    defaults = for_env(env, learner)
    minibatches = defaults.ppo.num_minibatches
    minibatches = minibatches if num_envs % minibatches == 0 else 1
    config = defaults.with_overrides({
        "learner_config.compute_dtype": compute_dtype,
        "learner_config.activation_dtype": activation_dtype, "num_envs": num_envs,
        **{f"eval.{k}": v for k, v in (eval_sizes or {}).items()},
        "replay.slots": replay_slots, "frames_per_batch": frames_per_batch,
        "epochs": max(1000, replay_slots // num_envs), "ppo.num_minibatches": minibatches})
    stream = dataclasses.replace(build(config), cuda_graphs=cuda_graphs)
    mesh = runs_mesh(runs, jax.local_devices()[:devices])
    host_loop = jax.default_backend() == "cpu"
    holder = {"s": stack_runs([stream.init(jax.random.PRNGKey(seed)) for seed in range(runs)])}
    # Fill the replay first so the loop case trains on every epoch.
    holder["s"], _ = run_stacked_epochs(stream, holder["s"], stream.config.fill_epochs,
                                     mesh=mesh)
    filled = harness.tree_digest(holder["s"])

    def stream_only():
        s = holder["s"]
        for _ in range(epochs):
            s, _, _ = stream.jit(_act_runs, graphs=True, donate_argnums=0)(s)
        holder["s"] = s
        return s.replay.size

    def loop():
        holder["s"], m = run_stacked_epochs(stream, holder["s"], epochs, mesh=mesh)
        return m

    learn_runs = jax.jit(stream.learn_runs, donate_argnums=0,
                         compiler_options=learners.compiler_options())

    def learner_only():  # as the loop trains: one call per epoch (host loop: per step)
        s = holder["s"]
        ls = s.learner
        for k in jax.random.split(jax.random.PRNGKey(1), (epochs, runs)):
            if host_loop:
                for step_keys in jax.vmap(stream.learn_keys)(k).swapaxes(0, 1):
                    ls, _ = stream.learner_jit(_learn_step_runs)(ls, s.replay, step_keys)
            else:
                ls, _ = learn_runs(ls, s.replay, k)
        holder["s"] = s.replace(learner=ls)
        return ls.step

    kept = [analysis.PiRandSet() for _ in range(runs)]
    parts: list[dict] = []

    def analyse():  # one analysis of the R runs, as `run._analyse_due` makes it
        seconds: dict = {}
        keys = jax.random.split(jax.random.PRNGKey(2), (2, runs))
        out = analysis.evaluate_runs(stream, holder["s"], keys[0], keys[1], seconds=seconds,
                                     pi_rand_sets=kept)
        parts.append(seconds)
        return out

    env_frames = runs * epochs * num_envs * config.rollout_len
    learner_frames = runs * epochs * config.learner_steps * stream.batch_sequences * stream.seq_len
    rows = []
    flags = os.environ.get("XLA_FLAGS", "")  # named in the rows: flag sets are compared by run
    cases = (("stream", stream_only), ("loop", loop), ("learner", learner_only),
             ("analysis", analyse))
    for case, fn in cases:
        if case not in only or (case != "loop" and mesh.size > 1):
            continue  # the pieces are jitted for one device; only the loop is sharded
        t = harness.measure(fn, repeats=repeats)
        row = {
            "case": f"{env}/{learner}/{case}"
                    + ("" if compute_dtype == "float32" else f", {compute_dtype}")
                    + ("" if activation_dtype == "float32"
                       else f", {activation_dtype} activations"),
            "impl": "jaml" + ("" if cuda_graphs else ", no CUDA graphs of the loops")
                    + (f", XLA_FLAGS={flags}" if flags else ""),
            "batch": num_envs,
            "runs": runs,
            "devices": mesh.size,
            "compile_s": t["compile_s"],
            "median_s": t["median_s"],
            "epochs_per_call": epochs,
            "host_loop": host_loop,
        }
        if case == "stream":
            row["filled_state_sha256"] = filled
        if case in ("stream", "loop"):
            row["env_frames_per_s"] = env_frames / t["median_s"]
        if case in ("loop", "learner"):
            row["learner_frames_per_s"] = learner_frames / t["median_s"]
        if case == "loop":
            row["epochs_per_s"] = runs * epochs / t["median_s"]
        if case == "analysis":  # no epochs: a call is one analysis
            row["epochs_per_call"] = None
            row.update({f"{k}_s": statistics.median(p.get(k, 0.0) for p in parts[1:])
                        for k in ("train_set", "pi_rand", "pi_curr", "regressor")})
        rows.append(row)
        print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()},
              flush=True)
    return rows


def _speedups(rows: list[dict]) -> None:
    """speedup_vs_one_run: aggregate throughput over the same case at R = 1, one device;
    speedup_vs_one_device: over the same case and R on one device (the devices' scaling;
    per-device efficiency is it over `devices`)."""
    for row in rows:
        key = next((k for k in ("env_frames_per_s", "learner_frames_per_s") if k in row), None)
        if key is None:  # the analysis: no frame rate
            continue
        base = next((r for r in rows if r["case"] == row["case"] and r["impl"] == row["impl"]
                     and r["runs"] == 1 and r["devices"] == 1), None)
        if base is not None:
            row["speedup_vs_one_run"] = row[key] / base[key]
        one = next((r for r in rows if r["case"] == row["case"] and r["impl"] == row["impl"]
                    and r["runs"] == row["runs"] and r["devices"] == 1), None)
        if one is not None and row["devices"] > 1:
            row["speedup_vs_one_device"] = row[key] / one[key]


def main(argv=None) -> int:
    if argv is None:  # a process of its own runs as jaml's commands do
        _huge_pages.adopt()
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["CartPole"])
    parser.add_argument("--learners", nargs="+", default=["VAE_rpl"])
    parser.add_argument("--runs", type=int, nargs="+", default=[1],
                        help="stacked runs (seeds) per program; one row set per value")
    parser.add_argument("--devices", type=int, nargs="+", default=[None],
                        help="devices to split the runs across, one row set per value, so "
                             "1 2 4 measures the scaling in one process (default: all, at "
                             "most R)")
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--epochs", type=int, default=10, help="epochs per timed call")
    parser.add_argument("--frames-per-batch", type=int, default=1024)
    parser.add_argument("--replay-slots", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dtypes", nargs="+", default=["float32"],
                        choices=["float32", "bfloat16"],
                        help="the learner's convolution compute dtypes (one row set each)")
    parser.add_argument("--activation-dtype", default="float32", choices=["float32", "bfloat16"],
                        help="the learner's activation dtype (LearnerConfig.activation_dtype)")
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES,
                        help="which cases to time (the analysis compiles for about a minute "
                             "on a GPU)")
    parser.add_argument("--cuda-graphs", nargs="+", default=["on"], choices=["on", "off"],
                        help="the Stream's programs with CUDA graphs of their loops (the "
                             "default on a CUDA GPU) or XLA's default command buffers; one row "
                             "set each, in this process")
    parser.add_argument("--quick", action="store_true", help="tiny sizes for a CPU smoke run")
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    if any(d is not None and d < 1 for d in args.devices):
        parser.error(f"--devices must be ≥ 1, got {args.devices}")
    if args.quick:
        args.num_envs, args.epochs, args.frames_per_batch = 8, 1, 8
        args.replay_slots, args.repeats = 16, 1
    eval_sizes = {"train": 64, "rand": 16, "curr": 16} if args.quick else None
    for env in args.envs:
        for learner in args.learners:
            rows, measured = [], set()
            for dtype in args.dtypes:
                for runs in args.runs:
                    for devices in args.devices:
                        # A setting that gives the runs the same mesh is timed once.
                        used = runs_mesh(runs, jax.local_devices()[:devices]).size
                        if (dtype, runs, used) in measured:
                            continue
                        measured.add((dtype, runs, used))
                        for graphs in args.cuda_graphs:
                            rows += bench(env, learner, runs, args.num_envs, args.epochs,
                                          args.frames_per_batch, args.replay_slots,
                                          args.repeats, used, dtype, args.activation_dtype,
                                          eval_sizes, tuple(args.cases), graphs == "on")
            _speedups(rows)
            if not args.no_record:  # after each pair: a run cut short keeps what it measured
                harness.record("stream_throughput", rows,
                               notes="frames/s through jaml.stream, R stacked runs: stream = "
                                     "act (physics+render+PPO+replay), loop = whole epochs, "
                                     "learner = updates only, analysis = one analysis "
                                     "of the R runs (its parts' seconds apart); "
                                     "speedup_vs_one_run = aggregate "
                                     "over R = 1 on one device, same run; speedup_vs_one_"
                                     "device = over the same R on one device, same run; "
                                     "on a CUDA GPU jaml's stream and loop run their loops "
                                     "as CUDA graphs from commit d92efe3 on (impl says when "
                                     "not); filled_state_sha256: the state after the fill "
                                     "epochs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
