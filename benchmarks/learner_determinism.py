"""Is a learner's train step deterministic run to run? A check, not a timing.

Each learner's step (`learner_throughput.jaml_step`: the benchmark's step, its init and batch)
runs `--steps` steps from the same initial state with the same keys, twice in a process (one
compiled program called again) and once in each of `--processes` new processes (compiled
again, as a rerun of a seed compiles), and the final parameters and batch statistics are
compared by their digest (`harness.tree_digest`). With `--deterministic`, `--processes` more
new processes compile with XLA's `xla_gpu_deterministic_ops` (no atomics in reductions and
scatters, deterministic cuDNN algorithms) and are compared among themselves: the setting a
bit-for-bit rerun on a GPU needs where the defaults are not enough.

    python benchmarks/learner_determinism.py [--learners VAE_rpl PRED DSA] [--frames 1024]
        [--dtype bfloat16] [--steps 10] [--processes 2] [--deterministic]

Prints one line per learner and setting: the digests and whether they agree.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness

DETERMINISTIC_FLAG = "--xla_gpu_deterministic_ops=true"


def digests(learner_name: str, frames: int, dtype: str, steps: int, runs: int = 2) -> list[str]:
    """The digest of the learner's state after `steps` steps, from `runs` runs of one compiled
    step in this process, each from the same initial state and keys."""
    import jax

    from benchmarks.learner_throughput import jaml_step, step_shape

    sequences, _ = step_shape(learner_name, frames)
    found = []
    jitted = None
    for _ in range(runs):
        step, state, batch = jaml_step(learner_name, sequences, dtype, activation_dtype=dtype)
        jitted = jitted or step  # the first run's compiled program for every run
        for i in range(steps):
            state, _ = jitted(state, batch, jax.random.key(i + 1))
        found.append(harness.tree_digest((state.params, state.batch_stats)))
    return found


def in_new_process(learner_name: str, frames: int, dtype: str, steps: int,
                   deterministic: bool) -> str:
    """One run's digest from a new process of this script (compiled afresh there)."""
    env = dict(os.environ)
    if deterministic:
        env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} {DETERMINISTIC_FLAG}".strip()
    out = subprocess.run(
        [sys.executable, __file__, "--child", "--learners", learner_name, "--frames", str(frames),
         "--dtype", dtype, "--steps", str(steps)],
        env=env, capture_output=True, text=True)
    if out.returncode:
        tail = out.stderr.strip().splitlines()[-1:] or ["no output"]
        raise RuntimeError(f"the {learner_name} child process failed ({out.returncode}): "
                           f"{tail[0]}")
    return json.loads(out.stdout.strip().splitlines()[-1])[learner_name][0]


def check(learner_name: str, frames: int, dtype: str, steps: int, processes: int,
          deterministic: bool = False) -> dict:
    """{"here": digests of two runs in this process, "processes": one per new process, "same":
    whether all of them agree}; with `deterministic`, the new processes compile with
    `DETERMINISTIC_FLAG` and "same" is whether those agree among themselves."""
    here = [] if deterministic else digests(learner_name, frames, dtype, steps)
    others = [in_new_process(learner_name, frames, dtype, steps, deterministic)
              for _ in range(processes)]
    return {"here": here, "processes": others, "same": len(set(here + others)) == 1}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--learners", nargs="+", default=["VAE_rpl", "PRED", "DSA"])
    parser.add_argument("--frames", type=int, default=1024)
    parser.add_argument("--dtype", default="bfloat16", choices=["float32", "bfloat16"])
    parser.add_argument("--steps", type=int, default=10)
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument("--deterministic", action="store_true",
                        help=f"also check new processes compiled with {DETERMINISTIC_FLAG}")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps({name: digests(name, args.frames, args.dtype, args.steps, runs=1)
                          for name in args.learners}))
        return
    import jax

    print(f"{jax.devices()[0].device_kind}, jax {jax.__version__}, {args.dtype}, "
          f"{args.frames} frames a step, {args.steps} steps", flush=True)
    for name in args.learners:
        for deterministic in (False, True) if args.deterministic else (False,):
            found = check(name, args.frames, args.dtype, args.steps, args.processes,
                          deterministic)
            where = (f"{len(found['processes'])} new processes with {DETERMINISTIC_FLAG}"
                     if deterministic else
                     f"2 runs in this process and {len(found['processes'])} new processes")
            print(f"{name}, {where}: {'the same bits' if found['same'] else 'DIFFERENT bits'} "
                  f"({' '.join(found['here'] + found['processes'])})", flush=True)


if __name__ == "__main__":
    main()
