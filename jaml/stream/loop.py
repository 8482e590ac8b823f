"""The learning loop (paper §2.1): PPO collects frames, the replay keeps them, a learner trains.

One epoch, a pure jitted function of `StreamState`:
  1. every env acts for `rollout_len` steps under the current policy (PPO on the LD state, or
     uniform random actions), rendering a 64×64 frame per step;
  2. PPO updates on that rollout;
  3. the rollout's columns go into the replay;
  4. once the replay is full (reference §3), the learner takes `learner_steps` gradient steps,
     each on `frames_per_batch // L` sequences of L frames sampled from the replay.
`Stream.run_epochs(state, n)` runs n epochs: device loops of up to 32 epochs on GPU/TPU, a host
loop of jitted pieces on CPU. `Stream.evaluate` is the
periodic analysis (reference §5): encode sequences from the replay (regressor training set) and
from fresh rollouts of a random policy (π_rand, the same set every time: a fixed key) and of the
current policy (π_curr), then fit a fresh regressor latents → LD state of each sequence's last
input frame and report its per-dimension test error, plus the distortion ρ on π_rand.

Shapes: E envs, T rollout_len, L = learner.seq_len, B sequences per learner batch, Z latent.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

import envs_mjx
from envs_mjx.base import Env, State
from jaml import evaluation, learners
from jaml.stream import collect
from jaml.stream import ppo as ppo_lib
from jaml.stream import replay as replay_lib
from jaml.stream.collect import Episodes
from jaml.stream.config import StreamConfig


@struct.dataclass
class StreamState:
    """Everything a run needs to continue: checkpointed whole. `key` is a raw uint32 key."""

    epoch: jax.Array
    key: jax.Array
    env: State
    episodes: Episodes
    ppo: ppo_lib.PPOState
    learner: learners.TrainState
    replay: replay_lib.Replay


@dataclasses.dataclass(frozen=True, eq=False)
class Stream:
    """A configured loop: env, learner, PPO and replay geometry, with pure epoch functions.

    A static argument of the module's jitted functions, so it hashes by what the traced code
    depends on: its parts by identity and its config without the seed, which only the run's
    keys use. Streams that `build` makes for configs differing only in the seed share their
    parts, hence one compilation for all seeds of an experiment.
    """

    config: StreamConfig
    env: Env
    learner: learners.Learner
    ppo: ppo_lib.PPO
    optimizer: Any
    train_step: Any
    keep_fraction: float

    def __post_init__(self):
        parts = (self.env, self.learner, self.ppo, self.optimizer, self.train_step)
        object.__setattr__(self, "_key", (self.config.program_key(), *map(id, parts),
                                          self.keep_fraction))

    def __hash__(self) -> int:
        return hash(self._key)

    def __eq__(self, other) -> bool:
        return isinstance(other, Stream) and self._key == other._key

    @property
    def seq_len(self) -> int:
        return self.learner.seq_len

    @property
    def hist(self) -> int:
        """Frames the learner takes as input; the alignment target is the last one's LD state."""
        return self.learner.config.hist

    @property
    def batch_sequences(self) -> int:
        return self.config.frames_per_batch // self.seq_len

    # -- state --------------------------------------------------------------------------------

    def init(self, key: jax.Array) -> StreamState:
        """A fresh run from a raw uint32 key (`jax.random.PRNGKey(seed)`)."""
        cfg = self.config
        key, k_env, k_ppo, k_learner = jax.random.split(key, 4)
        frames = jnp.zeros((self.batch_sequences, self.seq_len, *learners.learner.FRAME_SHAPE),
                           jnp.uint8)
        actions = jnp.zeros((self.batch_sequences, self.seq_len, self.env.action_size))
        state = StreamState(
            epoch=jnp.zeros((), jnp.int32),
            key=key,
            env=jax.jit(collect.reset, static_argnums=(0, 2))(self.env, k_env, cfg.num_envs),
            episodes=Episodes.zeros(cfg.num_envs),
            ppo=jax.jit(self.ppo.init)(k_ppo),
            learner=learners.init_train_state(self.learner, self.optimizer, k_learner,
                                              (frames, actions)),
            replay=replay_lib.init(
                cfg.replay_slots, cfg.rollout_len + 1, learners.learner.FRAME_SHAPE,
                self.env.action_size, len(self.env.ld_state_names), self.keep_fraction,
            ),
        )
        # Distinct buffers for every leaf: `run_epochs` donates the state, and a buffer shared
        # by two leaves (one zeros array, say) cannot be donated twice.
        return jax.tree.map(lambda x: jnp.array(x, copy=True), state)

    def policy(self, ppo_state: ppo_lib.PPOState):
        """The behaviour policy: PPO's stochastic policy, or uniform actions."""
        if self.config.policy == "random":
            return ppo_lib.random_policy(self.env.action_size)
        return self.ppo.policy(ppo_state)

    def test_policy(self, ppo_state: ppo_lib.PPOState, random: jax.Array):
        """π_rand where the traced flag `random` is set, else the current policy (π_curr).

        A traced choice, so both test sets share one compilation of the rollout code."""
        if self.config.policy == "random":
            return self.policy(ppo_state)
        current, uniform = self.policy(ppo_state), ppo_lib.random_policy(self.env.action_size)

        def policy(obs, key):
            return jnp.where(random, uniform(obs, key)[0], current(obs, key)[0]), {}

        return policy

    # -- one epoch ----------------------------------------------------------------------------

    def act(self, s: StreamState) -> tuple[StreamState, jax.Array, dict[str, jax.Array]]:
        """Collect a rollout, update PPO, add the columns to the replay (steps 1–3).

        Returns (state, the key of this epoch's learner steps, metrics)."""
        cfg = self.config
        key, k_roll, k_ppo, k_add, k_learn = jax.random.split(s.key, 5)
        env_state, transitions, columns, episodes = collect.rollout(
            self.env, s.env, self.policy(s.ppo), k_roll, cfg.rollout_len, s.episodes
        )
        metrics = dict(episodes.summary())
        ppo_state = s.ppo
        if cfg.policy == "ppo":
            ppo_state, ppo_metrics = self.ppo.update(s.ppo, transitions, k_ppo)
            metrics.update({f"ppo/{k}": v for k, v in ppo_metrics.items() if k in _PPO_METRICS})
        replay = replay_lib.add(s.replay, columns, k_add)
        metrics["learner/training"] = replay.full.astype(jnp.float32)
        new = StreamState(epoch=s.epoch + 1, key=key, env=env_state, episodes=episodes.cleared(),
                          ppo=ppo_state, learner=s.learner, replay=replay)
        return new, k_learn, metrics

    def learn_step(self, learner_state: learners.TrainState, replay: replay_lib.Replay,
                   key: jax.Array):
        """One learner gradient step on a batch sampled from the replay."""
        k_sample, k_step = jax.random.split(key)
        seqs = replay_lib.sample(replay, k_sample, self.batch_sequences, self.seq_len)
        return self.train_step(learner_state, (seqs.frames, seqs.actions), k_step)

    def learn_keys(self, key: jax.Array) -> jax.Array:
        return jax.random.split(key, self.config.learner_steps)

    def epoch(self, s: StreamState) -> tuple[StreamState, dict[str, jax.Array]]:
        """One whole epoch as a pure function (the learner trains once the replay is full)."""
        s, k_learn, metrics = self.act(s)

        def train(ls):
            ls, m = jax.lax.scan(lambda c, k: self.learn_step(c, s.replay, k), ls,
                                 self.learn_keys(k_learn))
            return ls, jax.tree.map(jnp.mean, m)

        def skip(ls):
            shapes = jax.eval_shape(train, ls)[1]
            return ls, jax.tree.map(lambda x: jnp.full(x.shape, jnp.nan, x.dtype), shapes)

        learner_state, learner_metrics = jax.lax.cond(s.replay.full, train, skip, s.learner)
        metrics.update({f"learner/{k}": v for k, v in learner_metrics.items()})
        return s.replace(learner=learner_state), metrics

    def run_epochs(self, s: StreamState, n: int) -> tuple[StreamState, dict[str, jax.Array]]:
        """n epochs; metrics stacked [n]. The state is donated (do not reuse the argument).

        On GPU/TPU the epochs run in jitted device loops of up to 32 epochs. On CPU they are a
        Python loop over jitted `act` and `learn_step` calls computing the same function with
        the same keys: XLA:CPU runs convolutions inside a while loop 20–40× slower than outside
        one (measured: two VAE steps 12.4 s in a scan vs 0.8 s unrolled, 2-core EPYC, jaxlib
        0.10.2).
        """
        if not _loops_on_host():
            blocks = []
            for start in range(0, n, _BLOCK):
                k = min(_BLOCK, n - start)
                s, metrics = _run_epochs(self, s, jnp.asarray(k, jnp.int32))
                blocks.append(jax.tree.map(lambda x, k=k: x[:k], metrics))
            return s, jax.tree.map(lambda *x: jnp.concatenate(x), *blocks)
        history = []
        for _ in range(n):
            s, k_learn, metrics = _act(self, s)
            if bool(s.replay.full):
                steps = [None] * self.config.learner_steps
                learner_state = s.learner
                for i, k in enumerate(self.learn_keys(k_learn)):
                    learner_state, steps[i] = _learn_step(self, learner_state, s.replay, k)
                s = s.replace(learner=learner_state)
                learner_metrics = jax.tree.map(lambda *v: jnp.mean(jnp.stack(v)), *steps)
            else:
                shapes = jax.eval_shape(self.learn_step, s.learner, s.replay, k_learn)[1]
                learner_metrics = jax.tree.map(lambda x: jnp.full(x.shape, jnp.nan), shapes)
            metrics.update({f"learner/{k}": v for k, v in learner_metrics.items()})
            history.append(metrics)
        return s, jax.tree.map(lambda *v: jnp.stack(v), *history)

    # -- analysis -----------------------------------------------------------------------------

    def encoded_replay(self, s: StreamState, key: jax.Array, num: int):
        """(latents [N, Z], LD targets [N, D]) of N ≈ num sequences sampled from the replay."""
        keys = jax.random.split(key, _chunks(num, self.config.num_envs))
        return _map_chunks(_replay_chunk, self, s, None, keys)

    def encoded_rollouts(self, s: StreamState, key: jax.Array, num: int, random: bool):
        """(latents, LD targets) of sequences cut from fresh rollouts: reset, `eval_transient`
        steps, then consecutive L-step rollouts per env (reference §5, start t = 0)."""
        k_start, k_chunks = jax.random.split(key)
        random = jnp.asarray(random)
        env_state = _rollout_start(self, s, k_start, random)
        keys = jax.random.split(k_chunks, _chunks(num, self.config.num_envs))
        return _map_chunks(_rollout_chunk, self, s, (env_state, random), keys)

    def evaluate(self, s: StreamState, key: jax.Array, pi_rand_key: jax.Array) -> dict:
        """Alignment errors [D] on π_rand (and π_curr under PPO), the held-out validation error,
        and the distortion of the π_rand latents. Host-side numbers (floats / lists)."""
        cfg = self.config
        k_train, k_curr, k_reg = jax.random.split(key, 3)
        train = self.encoded_replay(s, k_train, cfg.eval_train)
        tests = {"pi_rand": self.encoded_rollouts(s, pi_rand_key, cfg.eval_rand, random=True)}
        if cfg.policy == "ppo" and cfg.eval_curr > 0:
            tests["pi_curr"] = self.encoded_rollouts(s, k_curr, cfg.eval_curr, random=False)
        errors = evaluation.alignment_errors(
            *train, tests, seed=int(jax.random.randint(k_reg, (), 0, 2**31 - 1)),
            seq_len=self.seq_len, num_iterations=cfg.regressor_iterations,
            normalize=cfg.regressor_normalize,
        )
        lat, st = tests["pi_rand"]
        return {
            "errors": {k: np.asarray(v).tolist() for k, v in errors.items()},
            "distortion": float(evaluation.distortion(lat, st[:, self.distortion_columns])),
        }

    @property
    def distortion_columns(self) -> np.ndarray:
        """Indices of the LD state's τ^true entries for the distortion (all by default)."""
        names = list(self.env.ld_state_names)
        return np.asarray([names.index(n) for n in self.config.distortion_dims] or
                          range(len(names)))

    def reconstructions(self, s: StreamState, key: jax.Array, num: int = 8):
        """(true, decoded) last frames of `num` replay sequences, uint8 [num, 64, 64, 3] each."""
        seqs = replay_lib.sample(s.replay, key, num, self.seq_len)
        recon = _reconstruct(self, s.learner.variables, seqs.frames, seqs.actions)
        return (np.asarray(seqs.frames[:, -1]),
                np.asarray(jnp.round(recon[:, -1] * 255)).astype(np.uint8))


_PPO_METRICS = ("total_loss", "policy_loss", "v_loss", "entropy_loss", "kl_mean")


def _loops_on_host() -> bool:
    return jax.default_backend() == "cpu"


def _chunks(num: int, num_envs: int) -> int:
    return max(1, math.ceil(num / num_envs))


# Epochs per device call: the loop runs n ≤ _BLOCK epochs with n a traced bound, so one
# compilation serves every block length a run asks for.
_BLOCK = 32


@jax.jit(static_argnums=0, donate_argnums=1)
def _run_epochs(stream: Stream, s: StreamState, n: jax.Array):
    """n (traced, ≤ _BLOCK) epochs; metrics in [_BLOCK] buffers, NaN past n."""
    shapes = jax.eval_shape(stream.epoch, s)[1]
    buffers = jax.tree.map(lambda x: jnp.full((_BLOCK, *x.shape), jnp.nan, x.dtype), shapes)

    def body(i, carry):
        s, buffers = carry
        s, metrics = stream.epoch(s)
        return s, jax.tree.map(lambda b, v: b.at[i].set(v), buffers, metrics)

    return jax.lax.fori_loop(0, n, body, (s, buffers))


@jax.jit(static_argnums=0, donate_argnums=1)
def _act(stream: Stream, s: StreamState):
    return stream.act(s)


@jax.jit(static_argnums=0, donate_argnums=1)
def _learn_step(stream: Stream, learner_state, replay, key):
    return stream.learn_step(learner_state, replay, key)


def _map_chunks(producer, stream: Stream, s: StreamState, carry, keys):
    """For each key, `producer(stream, s, carry, key) -> (carry, Columns [E, L])`, encoded;
    returns (latents [N, Z], LD targets [N, D]) with N = E · len(keys).

    A host loop over one jitted producer and one jitted encoder on every backend: a scan over
    the chunks would compile the encoder once per data set (its length is static), and the
    per-chunk dispatch costs milliseconds against seconds of compilation (and XLA:CPU runs
    convolutions inside loops slowly, see `Stream.run_epochs`)."""
    outs = []
    for k in keys:
        carry, seqs = producer(stream, s, carry, k)
        outs.append(_encode(stream, s.learner.variables, seqs))
    return tuple(jnp.concatenate(x) for x in zip(*outs, strict=True))


@jax.jit(static_argnums=0)
def _reconstruct(stream: Stream, variables, frames, actions):
    # Module level, keyed on the Stream: a `jax.jit` made per call would recompile per analysis.
    return stream.learner.reconstruct(variables, frames, actions)


@jax.jit(static_argnums=0)
def _encode(stream: Stream, variables, seqs: replay_lib.Columns):
    z = stream.learner.encode(variables, seqs.frames, seqs.actions)
    return z, seqs.ld[:, stream.hist - 1]


@jax.jit(static_argnums=0)
def _replay_chunk(stream: Stream, s: StreamState, carry, key):
    return carry, replay_lib.sample(s.replay, key, stream.config.num_envs, stream.seq_len)


@jax.jit(static_argnums=0)
def _rollout_chunk(stream: Stream, s: StreamState, carry, key):
    """carry (env state, traced π_rand flag) → L steps, one test sequence per env."""
    env_state, random = carry
    L = stream.seq_len
    env_state, _, columns, _ = collect.rollout(stream.env, env_state,
                                               stream.test_policy(s.ppo, random), key, L)
    return (env_state, random), jax.vmap(replay_lib.window, (0, None, None))(columns, 0, L)


@jax.jit(static_argnums=0)
def _rollout_start(stream: Stream, s: StreamState, key: jax.Array, random: jax.Array) -> State:
    k_reset, k_transient = jax.random.split(key)
    env_state = collect.reset(stream.env, k_reset, stream.config.num_envs)
    if stream.config.eval_transient:
        env_state = _steps(stream.env, env_state, stream.test_policy(s.ppo, random), k_transient,
                           stream.config.eval_transient)
    return env_state


def _steps(env: Env, state: State, policy, key: jax.Array, n: int) -> State:
    """n steps with auto-reset, recording nothing (transients before test sequences)."""
    k_reset, k_steps = jax.random.split(key)
    fresh = collect.reset(env, k_reset, state.reward.shape[0])

    def body(state, k):
        actions, _ = policy(state.obs, k)
        nstate = jax.vmap(env.step)(state, actions)
        return collect._swap_in(nstate.done > 0, fresh, nstate), None

    return jax.lax.scan(body, state, jax.random.split(k_steps, n))[0]


_BUILT: dict = {}


def build(config: StreamConfig, latent_penalty=None) -> Stream:
    """A Stream for `config`; every size problem is reported here, before anything compiles.

    Building a config again in one process, or one that differs only in its seed, reuses the
    same env, learner and PPO, so jitted functions compiled for one serve the other (see
    `Stream`)."""
    cache_key = (config.program_key(), latent_penalty)
    if cache_key not in _BUILT:
        _BUILT[cache_key] = _build(config.replace(seed=0), latent_penalty)
    base = _BUILT[cache_key]
    return base if base.config == config else dataclasses.replace(base, config=config)


def _build(config: StreamConfig, latent_penalty) -> Stream:
    if config.env not in envs_mjx.ALL_ENVS:
        raise ValueError(f"unknown env {config.env!r}; valid names: {list(envs_mjx.ALL_ENVS)}")
    if config.learner not in learners.ALL_LEARNERS:
        raise ValueError(f"unknown learner {config.learner!r}; valid names: "
                         f"{list(learners.ALL_LEARNERS)}")
    env = envs_mjx.make(config.env, **config.env_overrides)
    ld_dim = len(env.ld_state_names)
    unknown = sorted(set(config.distortion_dims) - set(env.ld_state_names))
    if unknown:
        raise ValueError(f"distortion_dims {unknown} are not LD-state names of {config.env}: "
                         f"{list(env.ld_state_names)}")
    learner = learners.make(config.learner, ld_dim=ld_dim, **config.learner_overrides)
    problems = []
    column = config.rollout_len + 1
    if learner.seq_len > column:
        problems.append(
            f"{config.learner} needs sequences of {learner.seq_len} frames but replay columns "
            f"hold rollout_len + 1 = {column}; raise rollout_len or shorten the learner's window"
        )
    if config.frames_per_batch < learner.seq_len:
        problems.append(
            f"frames_per_batch ({config.frames_per_batch}) holds no {learner.seq_len}-frame "
            "sequence"
        )
    keep = (learner.config.replay_keep_fraction if config.replay_keep_fraction is None
            else config.replay_keep_fraction)
    if config.num_envs > config.replay_slots - int(keep * config.replay_slots):
        problems.append(
            f"each epoch adds {config.num_envs} columns but only "
            f"{config.replay_slots - int(keep * config.replay_slots)} replay slots are replaceable"
        )
    if config.epochs < config.fill_epochs:
        problems.append(
            f"epochs ({config.epochs}) end before the replay fills ({config.fill_epochs} epochs "
            "= replay_slots / num_envs); the learner would never train"
        )
    if problems:
        raise ValueError("; ".join(problems))
    ppo = ppo_lib.make(ld_dim, env.action_size, config.ppo, total_updates=config.epochs)
    optimizer = learners.default_optimizer(learner)
    train_step = learners.make_train_step(learner, optimizer, latent_penalty)
    return Stream(config, env, learner, ppo, optimizer, train_step, float(keep))
