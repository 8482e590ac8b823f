"""Does a scale's report order encoders? `suite.evaluate` at a named scale (`jaml.suite.SCALES`)
on CartPole with VAE_rpl's protocol, per seed: the report's reference rows (true state, the
pixels' PCA, a random projection) and a no-information encoder of the user's side (8 numbers
hashed from the frame's bytes), each as the mean over the LD dimensions of its MLP error over
the constant predictor's, on π_rand and validation; and the wall time of the call, compilation
included (a fresh process per scale: run it once per scale).

    python benchmarks/suite_scales.py --scale small --seeds 0 1 2 [--validation-split leading]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from jaml import stream, suite

_WEIGHTS = jax.random.bits(jax.random.key(1), (64 * 64 * 3, 8), jnp.uint32) | 1


@jax.jit
def frame_hash(frames, actions):
    """[E, 8] in [0, 1): hashes of the last frame's bytes, no information about the state a
    regressor can use (equal frames give equal latents, nearby ones unrelated ones)."""
    del actions
    pixels = frames[:, -1].reshape(len(frames), -1).astype(jnp.uint32)
    h = jnp.sum(pixels[:, :, None] * _WEIGHTS[None], axis=1, dtype=jnp.uint32)
    h = (h ^ (h >> 16)) * jnp.uint32(0x45D9F3B)
    h = h ^ (h >> 16)
    return (h >> 8).astype(jnp.float32) / 2.0**24


def relative(errors, constant) -> float:
    """Mean over the dimensions of error / constant predictor's error."""
    return float(np.mean(np.asarray(errors) / np.asarray(constant)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scale", default="small")
    parser.add_argument("--env", default="CartPole")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--validation-split", default="slots", choices=("slots", "leading"))
    args = parser.parse_args()
    for seed in args.seeds:
        config = suite.scaled(stream.for_env(args.env, "VAE_rpl", {
            "seed": seed, "eval.validation_split": args.validation_split}), args.scale)
        tic = time.perf_counter()
        report = suite.evaluate(frame_hash, config)
        seconds = time.perf_counter() - tic
        refs = report["references"]
        row = {"scale": args.scale, "env": args.env, "seed": seed, "seconds": round(seconds, 1),
               "cpus": os.cpu_count(), "machine": platform.processor() or platform.machine(),
               "validation_split": report["validation_split"]}
        for test_set in ("pi_rand", "validation"):
            constant = refs["constant"][test_set]
            row[test_set] = {
                "true_state": relative(refs["true_state"][test_set], constant),
                "pca": relative(refs["pca"][test_set], constant),
                "random_projection": relative(refs["random_projection"][test_set], constant),
                "frame_hash": relative(report["errors"][test_set], constant),
            }
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
