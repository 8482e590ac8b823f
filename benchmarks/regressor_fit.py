"""Seconds per alignment fit of R runs (`evaluation.alignment_errors_runs`, as one analysis
calls it: the reference's regressor, 10 000 Adam steps, two test sets), compile time apart,
against the reference's form in PyTorch in the same run (`peers/torch_regressor.py`: one
model per run, fit in turn, eager).

jaml's row carries the process's XLA flags (`XLA_FLAGS`) in its name, so that flag sets (CUDA
graphs of the loop, say) can be compared one process per GPU, and a checksum of its errors: a
flag set that changes the numbers shows it. Both rows give their mean π_rand error: the same
problem, fit by two random streams. Synthetic latents: a random map of the states plus noise,
Z = 2·D, at the CartPole sizes of a Fig. 2 analysis. `--profile` adds jaml's GPU kernels by
kind (learner_profile's summary).

    python benchmarks/regressor_fit.py --runs 4 [--torch] [--profile]
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness
from benchmarks.learner_profile import device_kernels, summarise
from jaml.evaluation import alignment

TESTS = {"pi_rand": 10_048, "pi_curr": 2_500}


def data(runs: int, rows: dict[str, int], d: int, seed: int = 0):
    """{name: (latents [R, N, 2D], states [R, N, D])}: latents a noisy map of the states."""
    rng = np.random.default_rng(seed)
    mix = rng.normal(size=(runs, d, 2 * d)).astype(np.float32)
    sets = {}
    for name, n in rows.items():
        states = rng.normal(size=(runs, n, d)).astype(np.float32)
        latents = np.tanh(states @ mix) + 0.1 * rng.normal(size=(runs, n, 2 * d))
        sets[name] = (latents.astype(np.float32), states)
    return sets


def fits(runs: int, train: int, tests: dict[str, int], iterations: int, d: int = 4):
    """The problem and its fits: {impl: () -> errors {name: [R, D]}} for jaml and the PyTorch
    peer (imported when called)."""
    sets = data(runs, {"train": train, **tests}, d)
    x, y = sets.pop("train")
    seeds = np.arange(runs)
    config = alignment.RegressorConfig(num_iterations=iterations)

    def jaml():
        return alignment.alignment_errors_runs(x, y, sets, seeds, config)

    def torch_eager():
        from benchmarks.learner_throughput import _torch_device
        from benchmarks.peers import torch_regressor

        return torch_regressor.fit_runs(x, y, sets, seeds, config, _torch_device())

    return {"jaml": jaml, "torch eager": torch_eager}


def checksum(errors) -> str:
    """The errors' digest (`harness.tree_digest`: its dict's keys sorted), 12 hex digits."""
    return harness.tree_digest(errors, 12)


def bench(runs: int, train: int, tests: dict[str, int], iterations: int, repeats: int,
          impls=("jaml",)) -> list[dict]:
    """A row per implementation: median seconds of a fit of the R runs, compile (first call)
    apart."""
    rows = []
    flags = os.environ.get("XLA_FLAGS", "")
    for impl, fit in fits(runs, train, tests, iterations).items():
        if impl not in impls:
            continue
        errors = {}

        def call(fit=fit, errors=errors):
            errors.update(fit())
            return errors

        timing = harness.measure(call, repeats=repeats)
        rows.append({"case": f"R{runs}_N{train}_I{iterations}",
                     "impl": impl + (f", XLA_FLAGS={flags}" if impl == "jaml" and flags else ""),
                     "runs": runs, "iterations": iterations, "seconds": timing["median_s"],
                     "us_per_step": 1e6 * timing["median_s"] / iterations,
                     # jaml's first call compiles; the eager peer's compiles nothing.
                     "compile_s": (timing["compile_s"] - timing["median_s"]
                                   if impl == "jaml" else None),
                     "repeats": repeats, "errors_sha": checksum(errors),
                     "pi_rand_error": float(np.mean(errors["pi_rand"]))})
    return rows


def profile(runs: int, train: int, tests: dict[str, int], iterations: int) -> dict:
    """GPU kernel time of one (compiled) jaml fit by kind and op, per Adam step."""
    fit = fits(runs, train, tests, iterations)["jaml"]
    harness.block(fit())
    with tempfile.TemporaryDirectory() as log_dir:
        with jax.profiler.trace(log_dir):
            started = time.perf_counter()
            harness.block(fit())
            wall = time.perf_counter() - started
        (path,) = glob.glob(f"{log_dir}/**/*.xplane.pb", recursive=True)
        return summarise(device_kernels(path), iterations, wall, top=30)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=4)
    parser.add_argument("--train", type=int, default=10_000, help="training rows per run")
    parser.add_argument("--iterations", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--torch", action="store_true", help="also the PyTorch peer's row")
    parser.add_argument("--quick", action="store_true", help="tiny sizes for a CPU smoke run")
    parser.add_argument("--profile", action="store_true",
                        help="also the GPU kernels of one jaml fit by kind")
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    tests = TESTS
    if args.quick:
        args.train, args.iterations, args.repeats, tests = 256, 50, 2, {"pi_rand": 64,
                                                                        "pi_curr": 32}
    impls = ("jaml", "torch eager") if args.torch else ("jaml",)
    rows = bench(args.runs, args.train, tests, args.iterations, args.repeats, impls)
    for row in rows:
        print(json.dumps(row))
    if len(rows) == 2:
        print(f"jaml {rows[1]['seconds'] / rows[0]['seconds']:.2f}× the PyTorch peer")
    if not args.no_record:
        harness.record("regressor_fit", rows)
    if args.profile:
        print(json.dumps(profile(args.runs, args.train, tests, args.iterations)))


if __name__ == "__main__":
    main()
