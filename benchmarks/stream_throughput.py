"""Frames/s through the suite's learning loop (jaml.stream), compile time apart.

Three cases per (env, learner), each timed as the median of blocked repeats of a block of
`--epochs` epochs (the state carried from call to call, as in a run):
  stream  — `Stream.act`: physics + rendering + policy + PPO update + replay insert
            (the frame stream, perf_anchors S3);
  loop    — the whole epoch: the stream plus `learner_steps` learner updates on replay batches;
            reported as env frames/s collected and learner frames/s trained;
  learner — the learner updates alone, on batches sampled from the filled replay.
There is no peer for the whole loop in this run (the paper's PyBullet + PyTorch stack is not
installed here); its anchors are the reference figures in `reference/perf_anchors.md` (PyBullet
TinyRenderer cartpole ≈ 698 frames/s per core before any learning). The learner's PyTorch peer is
`benchmarks/learner_throughput.py`.

    python benchmarks/stream_throughput.py                       # GPU sizes (64 envs · 32 steps)
    python benchmarks/stream_throughput.py --quick --no-record   # tiny CPU smoke run
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import jax

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness
from jaml.stream import build, for_env
from jaml.stream.loop import _act, _learn_step, _loops_on_host


def bench(env: str, learner: str, num_envs: int, epochs: int, frames_per_batch: int,
          replay_slots: int, repeats: int) -> list[dict]:
    defaults = for_env(env, learner)
    minibatches = defaults.ppo.num_minibatches
    minibatches = minibatches if num_envs % minibatches == 0 else 1
    config = defaults.replace(num_envs=num_envs, replay_slots=replay_slots,
                              frames_per_batch=frames_per_batch,
                              epochs=max(1000, replay_slots // num_envs),
                              ppo=dataclasses.replace(defaults.ppo, num_minibatches=minibatches))
    stream = build(config)
    holder = {"s": stream.init(jax.random.PRNGKey(0))}
    # Fill the replay first so the loop case trains on every epoch.
    fill = config.fill_epochs
    holder["s"], _ = stream.run_epochs(holder["s"], fill)

    def stream_only():
        s = holder["s"]
        for _ in range(epochs):
            s, _, _ = _act(stream, s)
        holder["s"] = s
        return s.replay.size

    def loop():
        holder["s"], m = stream.run_epochs(holder["s"], epochs)
        return m

    def learner_only():
        s = holder["s"]
        ls, key = s.learner, s.key
        for i in range(epochs * config.learner_steps):
            ls, _ = _learn_step(stream, ls, s.replay, jax.random.fold_in(key, i))
        holder["s"] = s.replace(learner=ls)
        return ls.step

    env_frames = epochs * num_envs * config.rollout_len
    learner_frames = epochs * config.learner_steps * stream.batch_sequences * stream.seq_len
    rows = []
    for case, fn in (("stream", stream_only), ("loop", loop), ("learner", learner_only)):
        t = harness.measure(fn, repeats=repeats)
        row = {
            "case": f"{env}/{learner}/{case}",
            "impl": "jaml",
            "batch": num_envs,
            "compile_s": t["compile_s"],
            "median_s": t["median_s"],
            "epochs_per_call": epochs,
            "host_loop": _loops_on_host(),
        }
        if case in ("stream", "loop"):
            row["env_frames_per_s"] = env_frames / t["median_s"]
        if case in ("loop", "learner"):
            row["learner_frames_per_s"] = learner_frames / t["median_s"]
        rows.append(row)
        print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()},
              flush=True)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--envs", nargs="+", default=["CartPole"])
    parser.add_argument("--learners", nargs="+", default=["VAE_rpl"])
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--epochs", type=int, default=10, help="epochs per timed call")
    parser.add_argument("--frames-per-batch", type=int, default=1024)
    parser.add_argument("--replay-slots", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="tiny sizes for a CPU smoke run")
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    if args.quick:
        args.num_envs, args.epochs, args.frames_per_batch = 8, 1, 8
        args.replay_slots, args.repeats = 16, 1
    for env in args.envs:
        for learner in args.learners:
            rows = bench(env, learner, args.num_envs, args.epochs, args.frames_per_batch,
                         args.replay_slots, args.repeats)
            if not args.no_record:  # after each pair: a run cut short keeps what it measured
                harness.record("stream_throughput", rows,
                               notes="frames/s through jaml.stream: stream = act (physics+"
                                     "render+PPO+replay), loop = whole epoch, learner = "
                                     "updates only")
    return 0


if __name__ == "__main__":
    sys.exit(main())
