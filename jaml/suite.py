"""Score your own encoder on the suite's protocol: the runs' test sets and their analysis.

    from jaml import suite, stream
    config = stream.for_env("CartPole", "VAE_rpl", suite.SCALES["smoke"])
    sets = suite.test_sets(config)               # {"train", "pi_rand", "pi_curr"}: TestSet
    report = suite.evaluate(my_encode, config)   # encode(frames, actions) -> latents [E, Z]

Both run the stream's own code (`jaml.stream.analysis`): the regressor's training set sampled
from the replay, π_rand from a uniform policy under the run's fixed key, π_curr from the current
PPO policy, in chunks of `num_envs` sequences of the learner's `seq_len` frames; the target is
the LD state at the learner's last input frame (`hist`). Without a `state` (a run's
`StreamState`), the run's initial state is taken and its replay filled (`fill_epochs`).
`evaluate` returns what a run's analysis reports (errors, baseline, distortion) plus a linear
probe's errors and R² beside the MLP's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaml import evaluation
from jaml.evaluation import alignment
from jaml.stream import analysis
from jaml.stream.config import StreamConfig
from jaml.stream.executor import build, run_epochs
from jaml.stream.loop import Stream, StreamState

# Sizes for a run that finishes in minutes on two CPU cores (`jaml suite --scale smoke`), and
# the paper's (the StreamConfig defaults, `for_env`'s per-domain settings), as overrides
# (`StreamConfig.with_overrides`).
SCALES: dict[str, dict] = {
    "smoke": {"num_envs": 8, "rollout_len": 4, "replay.slots": 16, "frames_per_batch": 8,
              "learner_steps": 2, "epochs": 4, "eval.every": 2, "eval.train": 64,
              "eval.rand": 64, "eval.curr": 32, "eval.transient": 3,
              "eval.regressor_iterations": 200},
    "paper": {},
}


def scaled(config: StreamConfig, scale: str) -> StreamConfig:
    """`config` with the sizes of `scale` ("smoke": minutes on a CPU; "paper": unchanged); PPO's
    minibatches are cut to split the smoke run's envs, and a sequence learner's window (SVAE's
    24 frames) keeps the rollout and batch long enough to hold one sequence."""
    if scale not in SCALES:
        raise ValueError(f"unknown scale {scale!r}; valid: {list(SCALES)}")
    changes = dict(SCALES[scale])
    if not changes:
        return config
    if changes["num_envs"] % config.ppo.num_minibatches:
        changes["ppo.num_minibatches"] = 4
    seq_len = _seq_len(config)
    changes["rollout_len"] = max(changes["rollout_len"], seq_len - 1)
    changes["frames_per_batch"] = max(changes["frames_per_batch"], seq_len)
    return config.with_overrides(changes)


def _seq_len(config: StreamConfig) -> int:
    """The learner's sequence length (1 for a learner of your own: its factory is not called)."""
    from jaml import learners

    if config.learner not in learners.ALL_LEARNERS:
        return 1
    return config.learner_config.seq_len


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


def _prepare(config: StreamConfig, state: StreamState | None):
    """(stream, state, analysis key, π_rand key): the keys a run derives from its seed."""
    stream = build(config)
    k_init, k_eval, pi_rand_key = jax.random.split(jax.random.PRNGKey(config.seed), 3)
    if state is None:
        state, _ = run_epochs(stream, stream.init(k_init), config.fill_epochs)
    return stream, state, jax.random.fold_in(k_eval, int(state.epoch)), pi_rand_key


def _chunks(stream: Stream, state: StreamState, key, pi_rand_key) -> dict[str, list]:
    """{set: host `Columns` chunks} from the analysis's own samplers and keys (one run: R = 1)."""
    cfg = stream.config
    k_train, k_curr, _ = jax.random.split(key, 3)
    states = jax.tree.map(lambda x: x[None], state)
    out = {"train": [], "pi_rand": []}
    analysis.encoded_replay(stream, states, k_train[None], cfg.eval.train, store=out["train"])
    analysis.encoded_rollouts(stream, states, pi_rand_key[None], cfg.eval.rand, random=True,
                              store=out["pi_rand"])
    if cfg.policy == "ppo" and cfg.eval.curr > 0:
        out["pi_curr"] = []
        analysis.encoded_rollouts(stream, states, k_curr[None], cfg.eval.curr, random=False,
                                  store=out["pi_curr"])
    return {k: [jax.tree.map(lambda x: x[0], c) for c in chunks] for k, chunks in out.items()}


def _test_set(stream: Stream, chunks: list) -> TestSet:
    cat = {f: np.concatenate([np.asarray(getattr(c, f)) for c in chunks])
           for f in ("frames", "actions", "ld")}
    return TestSet(**cat, states=cat["ld"][:, stream.hist - 1],
                   names=tuple(stream.env.ld_state_names))


def test_sets(config: StreamConfig, state: StreamState | None = None) -> dict[str, TestSet]:
    """The sets a run's analysis at `state` uses: "train" (replay), "pi_rand", "pi_curr" (PPO)."""
    stream, state, key, pi_rand_key = _prepare(config, state)
    return {k: _test_set(stream, c) for k, c in _chunks(stream, state, key,
                                                        pi_rand_key).items()}


test_sets.__test__ = False  # not a pytest test


def evaluate(encode: Callable, config: StreamConfig, state: StreamState | None = None, *,
             actions_seen: int = 0) -> dict:
    """A run's analysis report for `encode(frames uint8 [E, L, 64, 64, 3], actions [E, L, A])
    -> latents [E, Z]`, plus "linear" (a least-squares probe's errors and R², per test set)
    and "error_names". `actions_seen`: how many of a sequence's first actions `encode` reads
    (0: frames only; a suite learner's: `config.actions_seen`); the distortion skips pairs whose
    inputs `encode` cannot tell apart."""
    stream, state, key, pi_rand_key = _prepare(config, state)
    chunks = _chunks(stream, state, key, pi_rand_key)
    latents = {k: np.concatenate([np.asarray(encode(jnp.asarray(c.frames),
                                                    jnp.asarray(c.actions))) for c in cs])
               for k, cs in chunks.items()}
    sets = {k: _test_set(stream, cs) for k, cs in chunks.items()}
    tests = {k: (latents[k], sets[k].states) for k in sets if k != "train"}
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
    return {
        "errors": {k: np.asarray(v).tolist() for k, v in errors.items()},
        "baseline": analysis._constant_levels(stream, sets["train"].states,
                                              {k: s for k, (_, s) in tests.items()}),
        "distortion": float(evaluation.distortion(
            latents["pi_rand"], rand.states[:, analysis.distortion_columns(stream)],
            inputs=inputs)),
        "irregularity": {"replay": analysis.irregularity(stream, latents["train"],
                                                         sets["train"].states),
                         "pi_rand": analysis.irregularity(stream, latents["pi_rand"],
                                                          rand.states)},
        "linear": linear_probe(latents["train"], sets["train"].states, tests,
                               normalize=stream.config.eval.regressor_normalize),
        "error_names": analysis.error_names(stream),
    }


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
