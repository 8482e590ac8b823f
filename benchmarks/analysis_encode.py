"""The analysis' encoder over R stacked runs: jaml's form (`analysis._encode`, one `lax.map`
over the runs) against the runs unrolled in Python (R copies of the encoder in one program,
jaml's form before), compile time and steady state, and whether the latents are the same bits.

    python benchmarks/analysis_encode.py [--learners VAE_rpl DSA] [--runs 6] [--dtype float32]

A chunk is what the analysis encodes per call: `num_envs` sequences of the learner's length for
each run, random frames and actions, the runs' own initial parameters (CartPole). Compile
seconds are XLA's alone (JAX's backend-compile event; tracing is shared by the two forms), the
steady state the median of blocked calls, each form in the same process.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness
from jaml.stream import analysis, build, for_env
from jaml.stream.executor import stack_runs
from jaml.stream.replay import Columns

_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
_COMPILED: list[float] = []  # XLA's compile seconds since the last clear (`main`'s listener)


def unrolled(stream, variables, seqs):
    """The runs one after another in Python: R copies of the encoder in one program."""
    return jnp.stack([
        stream.learner.encode(jax.tree.map(lambda v, r=r: v[r], variables), seqs.frames[r],
                              seqs.actions[r])
        for r in range(seqs.frames.shape[0])])


def jaml_form(stream, variables, seqs):
    return analysis._encode(stream, variables, seqs)[0]


def bench(learner: str, runs: int, dtype: str, reps: int) -> list[dict]:
    config = for_env("CartPole", learner).with_overrides({  # a small replay: a run's holds
        "learner_config.compute_dtype": dtype,               # 2 GB at the default size
        "learner_config.activation_dtype": dtype, "replay.slots": 1024})
    stream = build(config)
    variables = stack_runs([stream.init(jax.random.PRNGKey(r)) for r in range(runs)]
                           ).learner.variables
    e, length = stream.config.num_envs, stream.seq_len
    k_frames, k_actions = jax.random.split(jax.random.PRNGKey(5))
    frames = jax.random.randint(k_frames, (runs, e, length, 64, 64, 3), 0, 256).astype(jnp.uint8)
    actions = jax.random.uniform(k_actions, (runs, e, length, stream.env.action_size),
                                 minval=-1, maxval=1)
    seqs = Columns(frames=frames, actions=actions, ld=jnp.zeros((runs, e, length, 1)),
                   starts=jnp.zeros((runs, e, length), bool))
    rows, latents = [], {}
    case = f"{learner} encoder, {runs} runs × {e} sequences × {length} frames, {dtype}"
    for impl, form in (("runs unrolled in Python (before)", unrolled),
                       ("lax.map over runs (jaml)", jaml_form)):
        _COMPILED.clear()
        compile_s, seconds, out = harness.measure_calls(
            lambda v, s, form=form: form(stream, v, s), (variables, seqs), reps, 1)
        latents[impl] = np.asarray(out)
        rows.append({"case": case, "impl": impl, "learner": learner, "runs": runs,
                     "compile_s": compile_s, "xla_compile_s": sum(_COMPILED),
                     "ms_per_chunk": 1e3 * seconds})
    same = bool(np.array_equal(*latents.values()))
    for row in rows:
        row["same_bits"] = same
        print({k: round(v, 3) if isinstance(v, float) else v for k, v in row.items()},
              flush=True)
    return rows


NOTES = ("The analysis' encoder over R stacked runs, one chunk (num_envs sequences a run): "
         "jaml's lax.map over the runs against the runs unrolled in Python; compile_s: lowering "
         "and compiling, xla_compile_s: XLA's part, ms_per_chunk: median of blocked calls; "
         "same_bits: the two forms' latents equal bit for bit (benchmarks/analysis_encode.py).")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--learners", nargs="+", default=["VAE_rpl", "DSA"])
    parser.add_argument("--runs", type=int, default=6)
    parser.add_argument("--dtype", default="float32", choices=["float32", "bfloat16"])
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error(f"--runs must be ≥ 1, got {args.runs}")
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, seconds, **_: _COMPILED.append(seconds) if event == _COMPILE_EVENT else None)
    rows = [row for learner in args.learners
            for row in bench(learner, args.runs, args.dtype, args.reps)]
    if not args.no_record:
        harness.record("analysis_encode", rows, notes=NOTES)
    return 0


if __name__ == "__main__":
    sys.exit(main())
