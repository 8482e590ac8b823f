"""Score your own encoder on the suite's protocol: the runs' test sets and their analysis.

    from jaml import suite, stream
    config = stream.for_env("CartPole", "VAE_rpl", suite.SCALES["small"])
    sets = suite.test_sets(config)               # {"train", "pi_rand", "pi_curr"}: TestSet
    report = suite.evaluate(my_encode, config)   # encode(frames, actions) -> latents [E, Z]
    report["references"]["true_state"]["pi_rand"], report["references"]["constant"]["pi_rand"]

Both run the stream's own code (`jaml.stream.analysis`): the regressor's training set sampled
from the replay, π_rand from a uniform policy under the run's fixed key, π_curr from the current
PPO policy, in chunks of `num_envs` sequences of the learner's `seq_len` frames; the target is
the LD state at the learner's last input frame (`hist`). Without a `state` (a run's
`StreamState`), the run's initial state is taken and its replay filled (`fill_epochs`).
`evaluate` returns what a run's analysis reports (errors, baseline, distortion) plus a linear
probe's errors and R² beside the MLP's, and the reference rows an error is read between: the
constant predictor (the ceiling) and the true state (the floor), pixels' PCA and a random
projection (`jaml.evaluation.references`). Its errors, baseline, linear probe and references
share their keys: the test sets, then "validation" (held-out replay rows; by replay column
unless `eval.validation_split` is "leading").
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaml import evaluation

# The named scales live beside the domains' settings (`stream.config`); here too, where the
# suite's users take them (`suite.scaled(config, "small")`).
from jaml.configs.stream import SCALES as SCALES
from jaml.configs.stream import SMOKE_NOTE, StreamConfig, scale_of
from jaml.configs.stream import scaled as scaled
from jaml.evaluation import alignment
from jaml.learners.learner import FRAME_SHAPE
from jaml.stream import analysis
from jaml.stream.executor import one_run_stacked, run_epochs
from jaml.stream.loop import Stream, StreamState, build


@dataclasses.dataclass(frozen=True)
class TestSet:
    """N sequences as the runs build them; `states` is the alignment target.

    frames: uint8 [N, L, 64, 64, 3]; actions: float32 [N, L, A]; ld: float32 [N, L, D];
    states: [N, D], the LD state at the learner's last input frame; names: the D LD names.
    """

    frames: np.ndarray
    actions: np.ndarray
    ld: np.ndarray
    states: np.ndarray
    names: tuple[str, ...]


class _Phases:
    """One line on stderr as each phase of `evaluate` starts, with the seconds so far, where
    `on`: the first compiles and the replay's fill take minutes on a CPU."""

    def __init__(self, on: bool):
        self.on, self.started = on, time.perf_counter()

    def __call__(self, what: str) -> None:
        if self.on:
            print(f"suite.evaluate [{time.perf_counter() - self.started:5.0f} s] {what}",
                  file=sys.stderr, flush=True)


def _prepare(config: StreamConfig, stream: Stream | None, state: StreamState | None,
             phase=lambda what: None):
    """(stream, state, analysis key, π_rand key): `stream` (built from `config` where None,
    else checked against it) and the keys a run of `config` derives from its seed."""
    if stream is None:
        stream = build(config)
    else:
        try:
            stream.run_config(config)
        except ValueError as error:
            raise ValueError(f"stream was not built from this config ({error}): pass "
                             "stream=jaml.stream.build(config), or none") from None
    k_init, k_eval, pi_rand_key = jax.random.split(jax.random.PRNGKey(config.seed), 3)
    if state is None:
        phase(f"filling the replay: {stream.config.fill_epochs} epochs of the stream")
        state, _ = run_epochs(stream, stream.init(k_init), stream.config.fill_epochs)
    return stream, state, jax.random.fold_in(k_eval, int(state.epoch)), pi_rand_key


def _chunks(stream: Stream, state: StreamState, key, pi_rand_key) -> dict[str, list]:
    """{set: host `Columns` chunks} from the analysis's own samplers and keys (one run: R = 1)."""
    cfg = stream.config
    k_train, k_curr, _ = jax.random.split(key, 3)
    states = one_run_stacked(state)
    out = {"train": [], "pi_rand": []}
    analysis.encoded_replay(stream, states, k_train[None], cfg.eval.train, store=out["train"])
    analysis.encoded_rollouts(stream, states, pi_rand_key[None], cfg.eval.rand, random=True,
                              store=out["pi_rand"])
    if "pi_curr" in analysis.set_names(stream):
        out["pi_curr"] = []
        analysis.encoded_rollouts(stream, states, k_curr[None], cfg.eval.curr, random=False,
                                  store=out["pi_curr"])
    return {k: [jax.tree.map(lambda x: x[0], c) for c in chunks] for k, chunks in out.items()}


def _test_set(stream: Stream, chunks: list) -> TestSet:
    cat = {f: np.concatenate([np.asarray(getattr(c, f)) for c in chunks])
           for f in ("frames", "actions", "ld")}
    return TestSet(**cat, states=cat["ld"][:, stream.hist - 1],
                   names=tuple(stream.env.ld_state_names))


def test_sets(config: StreamConfig, state: StreamState | None = None, *,
              stream: Stream | None = None) -> dict[str, TestSet]:
    """The sets a run's analysis at `state` uses: "train" (replay), "pi_rand", "pi_curr" (PPO).
    `stream`: `jaml.stream.build(config)`, whose compiled programs then serve again (default:
    a new one)."""
    stream, state, key, pi_rand_key = _prepare(config, stream, state)
    return {k: _test_set(stream, c) for k, c in _chunks(stream, state, key,
                                                        pi_rand_key).items()}


test_sets.__test__ = False  # not a pytest test


def evaluate(encode: Callable, config: StreamConfig, state: StreamState | None = None, *,
             actions_seen: int = 0, references: bool = True,
             stream: Stream | None = None, progress: bool = True) -> dict:
    """A run's analysis report for `encode(frames uint8 [E, L, 64, 64, 3], actions [E, L, A])
    -> latents [E, Z]`, plus "linear" (a least-squares probe's errors and R², per test set and
    validation), "error_names", "scale" (the `SCALES` entry `config` has the sizes of, else
    None) and, at the smoke scale, a "note" that its numbers do not rank encoders.
    `references`: the reference rows on the same sets and regressor ("references": constant,
    true state, pixels' PCA, a random projection of pixels; three more regressor fits).
    `actions_seen`: how many of a sequence's first actions `encode` reads (0: frames only; a
    suite learner's: `config.actions_seen`); the distortion skips pairs whose inputs `encode`
    cannot tell apart. `encode` is first called on one chunk of zeros and its output checked,
    before the replay is filled. `stream`: as `test_sets`'s. `progress`: a line on stderr as
    each phase starts."""
    if not isinstance(config, StreamConfig):
        raise TypeError(f"config must be a jaml.stream.StreamConfig, got a "
                        f"{type(config).__name__}: make one with stream.for_env(env, learner) "
                        "and suite.scaled(config, scale)")
    if not callable(encode):
        raise TypeError(f"encode must be a function (frames, actions) -> latents [E, Z], got a "
                        f"{type(encode).__name__}")
    phase = _Phases(progress)
    phase("building the stream")
    stream = build(config) if stream is None else stream
    probe = (jnp.zeros((config.num_envs, stream.seq_len, *FRAME_SHAPE), jnp.uint8),
             jnp.zeros((config.num_envs, stream.seq_len, stream.env.action_size), jnp.float32))
    _checked(encode(*probe), config.num_envs, stream.seq_len, "a chunk of zero frames")
    stream, state, key, pi_rand_key = _prepare(config, stream, state, phase)
    phase(f"drawing the test sets ({', '.join(analysis.set_names(stream))})")
    chunks = _chunks(stream, state, key, pi_rand_key)
    phase(f"encoding {sum(len(c) for c in chunks.values())} chunks")
    width = None
    latents = {}
    for k, cs in chunks.items():
        parts = []
        for c in cs:
            parts.append(_checked(encode(jnp.asarray(c.frames), jnp.asarray(c.actions)),
                                  len(c.frames), stream.seq_len, f"the {k} set", width))
            width = parts[-1].shape[1]
        latents[k] = np.concatenate(parts)
    sets = {k: _test_set(stream, cs) for k, cs in chunks.items()}
    tests = {k: (latents[k], sets[k].states) for k in sets if k != "train"}
    phase("fitting the alignment regressor")
    k_reg = jax.random.split(key, 3)[2]
    seed = int(jax.random.randint(k_reg, (), 0, 2**31 - 1))  # as `analysis.evaluate`'s
    # The analysis' own regressor fit (over R runs, here R = 1).
    errors = alignment.alignment_errors_runs(
        latents["train"][None], sets["train"].states[None],
        {k: (lat[None], st[None]) for k, (lat, st) in tests.items()}, seeds=[seed],
        **analysis._regressor_options(stream))
    errors = {k: np.asarray(v)[0] for k, v in errors.items()}
    rand = sets["pi_rand"]
    inputs = analysis.input_fingerprints(stream.hist, jnp.asarray(rand.frames),
                                         jnp.asarray(rand.actions), actions_seen)
    exact, trimmed, left_out = evaluation.distortion_trimmed(
        latents["pi_rand"], rand.states[:, analysis.distortion_columns(stream)], inputs=inputs)
    held_out = alignment.RegressorConfig().split(len(latents["train"]))
    baseline = {k: v.tolist() for k, v in alignment.constant_errors(
        sets["train"].states, {k: s for k, (_, s) in tests.items()}, validation=True,
        **analysis._regressor_options(stream)).items()}
    report = {
        "errors": {k: np.asarray(v).tolist() for k, v in errors.items()},
        "baseline": baseline,
        "distortion": exact,
        "distortion_trimmed": {"value": trimmed, "left_out": left_out},
        "irregularity": {"replay": analysis.irregularity(stream, latents["train"],
                                                         sets["train"].states),
                         "pi_rand": analysis.irregularity(stream, latents["pi_rand"],
                                                          rand.states)},
        "linear": linear_probe(latents["train"][held_out:], sets["train"].states[held_out:],
                               {**tests, "validation": (latents["train"][:held_out],
                                                        sets["train"].states[:held_out])},
                               normalize=stream.config.eval.regressor_normalize),
        "error_names": analysis.error_names(stream),
        "validation_split": config.eval.validation_split,
        "scale": scale_of(config),
    }
    if report["scale"] == "smoke":
        report["note"] = SMOKE_NOTE
    if references:
        phase("the reference rows (true state, pixels' PCA, a random projection)")
        pixels = {k: _pixels(stream, s) for k, s in sets.items()}
        row = analysis.reference_rows(
            stream, pixels["train"][None], sets["train"].states[None],
            {k: (pixels[k][None], s[None]) for k, (_, s) in tests.items()}, [seed])[0]
        report["references"] = {"constant": baseline, **row}
    phase("done")
    return report


def _pixels(stream: Stream, test_set: TestSet) -> np.ndarray:
    """uint8 [N, P]: each sequence's last input frame, flattened (the pixel references')."""
    frames = test_set.frames[:, stream.hist - 1]
    return frames.reshape(len(frames), -1)


def _checked(latents, rows: int, seq_len: int, where: str, width: int | None = None
             ) -> np.ndarray:
    """`latents` as a float [rows, Z] host array, or a one-line ValueError naming its shape
    and the fix."""
    try:
        out = np.asarray(latents)
    except Exception as error:  # a tuple of arrays, a dict, ...
        raise ValueError(f"encode returned a {type(latents).__name__} on {where}, which is not "
                         f"an array ({error}); return latents [E, Z] = [{rows}, Z]") from None
    if out.dtype == object:
        raise ValueError(f"encode returned a {type(latents).__name__} on {where}, not an array "
                         f"of numbers; return latents [E, Z] = [{rows}, Z]")
    if out.ndim != 2 or out.shape[0] != rows:
        raise ValueError(f"encode returned shape {out.shape} on {where} of {rows} sequences of "
                         f"{seq_len} frames; return one latent vector per sequence, [E, Z] = "
                         f"[{rows}, Z] (e.g. reshape to ({rows}, -1))")
    if not (np.issubdtype(out.dtype, np.floating) or np.issubdtype(out.dtype, np.integer)):
        raise ValueError(f"encode returned dtype {out.dtype} (shape {out.shape}) on {where}; "
                         "return numbers, e.g. float32 latents [E, Z]")
    if width is not None and out.shape[1] != width:
        raise ValueError(f"encode returned shape {out.shape} on {where}, width {out.shape[1]} "
                         f"after {width} on an earlier chunk; return the same Z every call")
    bad = ~np.isfinite(out)
    if bad.any():
        raise ValueError(f"encode returned {int(bad.sum())} NaN or inf entries in its output "
                         f"of shape {out.shape} on {where}; return finite latents")
    return out.astype(np.float32)


def linear_probe(latents_train, states_train, tests: dict, normalize: bool = True) -> dict:
    """A least-squares affine map latents → state fit on the training rows: per test set its
    per-dimension mean |error| (training-std units when `normalize`, as the MLP's) and R²."""
    x = np.asarray(latents_train, np.float64)
    y = np.asarray(states_train, np.float64)
    design = np.concatenate([x, np.ones((len(x), 1))], axis=1)
    weights = np.linalg.lstsq(design, y, rcond=None)[0]
    scale = y.std(axis=0) + 1e-6 if normalize else np.ones(y.shape[1])
    out = {"errors": {}, "r2": {}}
    for name, (lat, st) in tests.items():
        st = np.asarray(st, np.float64)
        pred = np.concatenate([np.asarray(lat, np.float64), np.ones((len(lat), 1))], 1) @ weights
        out["errors"][name] = (np.abs(pred - st) / scale).mean(axis=0).tolist()
        total = ((st - st.mean(axis=0)) ** 2).sum(axis=0)
        out["r2"][name] = (1 - ((st - pred) ** 2).sum(axis=0) / np.maximum(total, 1e-12)).tolist()
    return out
