"""Seconds per alignment fit of R runs (`evaluation.alignment_errors_runs`, as one analysis
calls it: the reference's regressor, 10 000 Adam steps, two test sets), compile time apart.

The fit is a scan of 10 000 small Adam steps; this times it under the process's
XLA flags (`XLA_FLAGS`, recorded in the row), so that flag sets (CUDA graphs of the loop, say)
can be compared one process per GPU, and prints a checksum of the errors: a flag set that
changes the numbers shows it. Synthetic latents: a random linear map of the states plus
noise, Z = 2·D, at the CartPole sizes of a Fig. 2 analysis.

    python benchmarks/regressor_fit.py --runs 4
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from jaml.evaluation import alignment


def data(runs: int, rows: dict[str, int], d: int, seed: int = 0):
    """{name: (latents [R, N, 2D], states [R, N, D])}: latents a noisy linear map of states."""
    rng = np.random.default_rng(seed)
    mix = rng.normal(size=(runs, d, 2 * d)).astype(np.float32)
    sets = {}
    for name, n in rows.items():
        states = rng.normal(size=(runs, n, d)).astype(np.float32)
        latents = np.tanh(states @ mix) + 0.1 * rng.normal(size=(runs, n, 2 * d))
        sets[name] = (latents.astype(np.float32), states)
    return sets


def bench(runs: int, train: int, tests: dict[str, int], iterations: int, repeats: int,
          d: int = 4) -> dict:
    sets = data(runs, {"train": train, **tests}, d)
    x, y = sets.pop("train")
    seeds = np.arange(runs)

    def fit():
        errors = alignment.alignment_errors_runs(x, y, sets, seeds,
                                                 num_iterations=iterations)
        return jax.block_until_ready(errors)

    started = time.perf_counter()
    errors = fit()
    first = time.perf_counter() - started
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        fit()
        times.append(time.perf_counter() - started)
    steady = statistics.median(times)
    flat = np.concatenate([np.asarray(errors[k]).ravel() for k in sorted(errors)])
    return {"benchmark": "regressor_fit", "runs": runs, "train_rows": train,
            "test_rows": tests, "iterations": iterations, "seconds": steady,
            "us_per_step": 1e6 * steady / iterations, "compile_s": first - steady,
            "repeats": repeats, "errors_sha": hashlib.sha256(flat.tobytes()).hexdigest()[:12],
            "xla_flags": os.environ.get("XLA_FLAGS", ""), "device": jax.devices()[0].device_kind,
            "jax": jax.__version__}


def profile(runs: int, train: int, tests: dict[str, int], iterations: int, d: int = 4) -> dict:
    """GPU kernel time of one (compiled) fit by kind and op, per Adam step."""
    import glob
    import tempfile

    from benchmarks.learner_profile import device_kernels, summarise

    sets = data(runs, {"train": train, **tests}, d)
    x, y = sets.pop("train")

    def fit():
        return jax.block_until_ready(alignment.alignment_errors_runs(
            x, y, sets, np.arange(runs), num_iterations=iterations))

    fit()
    with tempfile.TemporaryDirectory() as log_dir:
        with jax.profiler.trace(log_dir):
            started = time.perf_counter()
            fit()
            wall = time.perf_counter() - started
        (path,) = glob.glob(f"{log_dir}/**/*.xplane.pb", recursive=True)
        return summarise(device_kernels(path), iterations, wall, top=30)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=4)
    parser.add_argument("--train", type=int, default=10_000, help="training rows per run")
    parser.add_argument("--iterations", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="tiny sizes for a CPU smoke run")
    parser.add_argument("--profile", action="store_true",
                        help="also the GPU kernels of one fit by kind (learner_profile's summary)")
    args = parser.parse_args(argv)
    tests = {"pi_rand": 10_048, "pi_curr": 2_500}
    if args.quick:
        args.train, args.iterations, args.repeats, tests = 256, 50, 2, {"pi_rand": 64,
                                                                        "pi_curr": 32}
    row = bench(args.runs, args.train, tests, args.iterations, args.repeats)
    print(json.dumps(row))
    if args.profile:
        print(json.dumps(profile(args.runs, args.train, tests, args.iterations)))


if __name__ == "__main__":
    main()
