"""The learning loop (paper §2.1): PPO collects frames, the replay keeps them, a learner trains.

One epoch, a pure function of `StreamState`:
  1. every env acts for `rollout_len` steps under the current policy (PPO on the LD state, or
     uniform random actions), rendering a 64×64 frame per step;
  2. PPO updates on that rollout;
  3. the rollout's columns go into the replay;
  4. once the replay is full (docs/reference/suite.md §3), the learner takes `learner_steps`
     gradient steps, each on `frames_per_batch // L` sequences of L frames sampled from the
     replay.
Several independent runs of one Stream (configs that differ only in their seeds) stack along a
leading runs axis R and `Stream.epochs` vmaps the epoch over them (`Stream.host_epoch`: the same
epoch as jitted pieces called from the host); how epochs are executed (host loop, device blocks,
several devices) is `jaml.stream.executor`'s, the periodic analysis `jaml.stream.analysis`'s.

Shapes: R runs, E envs, T rollout_len, L = learner.seq_len, B sequences per learner batch.
"""

from __future__ import annotations

import dataclasses
import os
import weakref
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

import envs_mjx
from envs_mjx.base import Env, State
from jaml import learners
from jaml.configs.stream import (
    RunConfig,
    StreamConfig,
    one_program,
    resolve,
    resolve_runs,
)
from jaml.evaluation import rotation
from jaml.stream import collect
from jaml.stream import ppo as ppo_lib
from jaml.stream import replay as replay_lib
from jaml.stream.collect import Episodes
from jaml.stream.penalty import latent_penalty


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
    """A configured loop: env, learner, PPO and replay geometry, with pure epoch functions, and
    the programs compiled for it (`jit`), which it owns: they live and die with it.

    The seed enters only through a run's keys (traced inputs), so one Stream serves every seed
    of a config with one compilation (`jaml.stream.run.run_many` trains them stacked).
    """

    config: RunConfig
    env: Env
    learner: learners.Learner
    ppo: ppo_lib.PPO
    optimizer: Any
    train_step: Any
    cuda_graphs: bool = dataclasses.field(default_factory=lambda: cuda_graphs_wanted())
    programs: dict = dataclasses.field(default_factory=dict, init=False, repr=False)

    def jit(self, fun, *, graphs: bool = False, **options):
        """`jax.jit(options)` of `fun(self, *args)` as a function of `args` (the options'
        argument numbers count from the first of them), made once per (fun, graphs, options).
        `graphs` (top-level programs only: JAX refuses compiler options on a nested jit): on a
        CUDA GPU and with `cuda_graphs`, the loops' bodies run as CUDA graphs (`CUDA_GRAPHS`),
        decided when the program is made."""
        def make():
            if graphs and self.cuda_graphs and on_cuda():
                options["compiler_options"] = {**CUDA_GRAPHS,
                                               **(options.get("compiler_options") or {})}
            return jax.jit(_bound(self, fun), **options)

        return self.program((fun, graphs, _frozen(options)), make)

    def learner_jit(self, fun, **options):
        """`jit(fun, options)` of a top-level program (CUDA graphs where they apply) with the
        first argument (the states) donated unless `options` say otherwise, and the learner's
        compiler options (`learners.compiler_options()`: on the CPU convolutions take XLA's
        Eigen path, not YNNPACK's, which ran the VAE's train step slower; XLA's defaults
        elsewhere). Read at each call: the options depend on the backend."""
        return self.jit(fun, graphs=True, **{"donate_argnums": 0, **options},
                        compiler_options=learners.compiler_options())

    def program(self, key, make):
        """`make()` (a jitted function, an executable), made once per `key` and kept by this
        Stream alone: a program holds its Stream weakly (`_bound`), so when the Stream goes,
        its programs and their memory go with it (on XLA:CPU each compiled kernel maps memory
        of its own, and a process that kept every config's ran out of mappings)."""
        if key not in self.programs:
            self.programs[key] = make()
        return self.programs[key]

    def run_config(self, config: StreamConfig) -> RunConfig:
        """`config` resolved for this Stream's env and backend (`config.resolve`): one of its
        runs, which may differ from the Stream's own config only in the seed."""
        run = resolve(config, len(self.env.ld_state_names), jax.default_backend())
        one_program(run, self.config)
        return run

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
        env = jax.jit(collect.reset, static_argnums=(0, 2))(self.env, k_env, cfg.num_envs)
        ppo = jax.jit(self.ppo.init)(k_ppo)
        # The learner's shapes: one batch of frames and actions.
        frames = jnp.zeros((self.batch_sequences, self.seq_len, *learners.learner.FRAME_SHAPE),
                           jnp.uint8)
        actions = jnp.zeros((self.batch_sequences, self.seq_len, self.env.action_size))
        state = StreamState(
            epoch=jnp.zeros((), jnp.int32),
            key=key,
            env=env,
            episodes=Episodes.zeros(cfg.num_envs),
            ppo=ppo,
            learner=learners.init_train_state(self.learner, self.optimizer, k_learner,
                                              (frames, actions)),
            replay=replay_lib.init(
                cfg.replay.slots, cfg.rollout_len + 1, learners.learner.FRAME_SHAPE,
                self.env.action_size, len(self.env.ld_state_names), cfg.replay.keep_fraction,
            ),
        )
        # Distinct buffers for every leaf: the executor donates the state, and a buffer shared
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
        batch, k_step = self.sample_batch(replay, key)
        return self.train_step(learner_state, batch, k_step)

    def sample_batch(self, replay: replay_lib.Replay, key: jax.Array):
        """(frames, actions) of one learner batch from the replay, and the step's own key."""
        k_sample, k_step = jax.random.split(key)
        seqs = replay_lib.sample(replay, k_sample, self.batch_sequences, self.seq_len)
        return (seqs.frames, seqs.actions), k_step

    def learn_keys(self, key: jax.Array) -> jax.Array:
        return jax.random.split(key, self.config.learner_steps)

    def learn_runs(self, learner_state: learners.TrainState, replay: replay_lib.Replay,
                   keys: jax.Array):
        """The epoch's `learner_steps` gradient steps of R stacked runs (keys [R]); metrics [R],
        averaged over the steps.

        Each step samples every run's batch at once (vmapped), then takes the runs' gradient
        steps one after another (`lax.map`): vmapped, the runs' different conv weights become
        one grouped convolution, which GPU libraries run far slower than R ordinary ones
        (docs/notes/stream.md)."""

        def step(learner_state, step_keys):
            batch, k_step = jax.vmap(self.sample_batch)(replay, step_keys)
            return jax.lax.map(lambda args: self.train_step(*args),
                               (learner_state, batch, k_step))

        per_step = jax.vmap(self.learn_keys)(keys).swapaxes(0, 1)  # [learner_steps, R, 2]
        learner_state, m = jax.lax.scan(step, learner_state, per_step)
        return learner_state, jax.tree.map(lambda x: jnp.mean(x, axis=0), m)

    def epochs(self, states: StreamState) -> tuple[StreamState, dict[str, jax.Array]]:
        """One whole epoch of R stacked runs (leading axis R), as a pure function; metrics [R].

        Each run acts, then trains once its replay is full. The runs of one Stream fill their
        replays on the same epoch, so one branch (run 0's) serves all: a vmapped `cond` would
        run the learner steps on every epoch and select."""
        states, k_learn, metrics = jax.vmap(self.act)(states)

        def train(ls):
            return self.jit(Stream.learn_runs)(ls, states.replay, k_learn)

        def skip(ls):
            return ls, _skipped(self, states, k_learn)

        learner_state, learner_metrics = jax.lax.cond(_replays_full(states), train, skip,
                                                      states.learner)
        return states.replace(learner=learner_state), _with_learner(metrics, learner_metrics)

    def host_epoch(self, states: StreamState) -> tuple[StreamState, dict[str, jax.Array]]:
        """`epochs` as jitted pieces called from the host: the same function with the same keys,
        the runs acting in one program call and each learner step in one of its own (the CPU's
        host loop, `jaml.stream.executor`: XLA:CPU runs convolutions inside a while loop many
        times slower than outside one). The states are donated."""
        # The acting program neither reads nor writes the learner's state: left out of it, the
        # program is the same for every learner of one env and PPO (one compilation serves).
        learner = states.learner
        states, k_learn, metrics = self.jit(_act_runs, graphs=True, donate_argnums=0)(
            states.replace(learner=None))
        states = states.replace(learner=learner)
        if bool(_replays_full(states)):
            keys = jax.vmap(self.learn_keys)(k_learn)  # [R, learner_steps, 2]
            learner_state, steps = states.learner, []
            for i in range(self.config.learner_steps):
                learner_state, m = self.learner_jit(_learn_step_runs)(
                    learner_state, states.replay, keys[:, i])
                steps.append(m)
            states = states.replace(learner=learner_state)
            learner_metrics = jax.tree.map(lambda *v: jnp.mean(jnp.stack(v), axis=0), *steps)
        else:
            learner_metrics = _skipped(self, states, k_learn)
        return states, _with_learner(metrics, learner_metrics)


# XLA's default command buffers (CUDA graphs) plus the bodies of loops and conditionals: a
# rollout launches thousands of small kernels an epoch (a physics step, a frame, the policy),
# and their launches, not the kernels, bound it (docs/notes/stream.md, "CUDA graphs of the loops").
CUDA_GRAPHS = {
    "xla_gpu_enable_command_buffer":
        "FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,DYNAMIC_SLICE_FUSION,WHILE,CONDITIONAL",
    "xla_gpu_graph_min_graph_size": 1,
}


def cuda_graphs_wanted() -> bool:
    """A new Stream's `cuda_graphs`: on unless JAML_CUDA_GRAPHS=0 (the command line's way out)."""
    setting = os.environ.get("JAML_CUDA_GRAPHS", "1")
    if setting not in ("0", "1"):
        raise ValueError(f"JAML_CUDA_GRAPHS must be 0 or 1, got {setting!r}")
    return setting == "1"


def on_cuda() -> bool:
    """Whether JAX's first local device is an NVIDIA GPU (CUDA graphs apply there alone)."""
    device = jax.local_devices()[0]
    return device.platform == "gpu" and "cuda" in device.client.platform_version.lower()


_PPO_METRICS = ("total_loss", "policy_loss", "v_loss", "entropy_loss", "kl_mean")


def _replays_full(states: StreamState) -> jax.Array:
    """Whether the stacked runs' replays are full (run 0's: they fill on the same epoch).
    Vmapped: the replay's sizes are properties of one run's shapes."""
    return jax.vmap(lambda replay: replay.full)(states.replay)[0]


def _skipped(stream: Stream, states: StreamState, k_learn: jax.Array):
    """NaN learner metrics [R] for an epoch without learner steps (the replay still fills).

    The shape-only trace goes through the jitted learner steps that `Stream.epochs`'s train
    branch calls: both share one trace of them."""
    shapes = jax.eval_shape(stream.jit(Stream.learn_runs), states.learner, states.replay,
                            k_learn)[1]
    return jax.tree.map(lambda x: jnp.full(x.shape, jnp.nan, x.dtype), shapes)


def _with_learner(metrics: dict, learner_metrics: dict) -> dict:
    """An epoch's metrics: the acting's, then the learner's as "learner/NAME"."""
    return metrics | {f"learner/{k}": v for k, v in learner_metrics.items()}


def _act_runs(stream: Stream, states: StreamState):
    return jax.vmap(stream.act)(states)


def _learn_step_runs(stream: Stream, learner_state, replay, keys):
    return jax.vmap(stream.learn_step)(learner_state, replay, keys)


def build(config: StreamConfig) -> Stream:
    """A new Stream for `config`, its config `config` resolved for its env and JAX's backend
    (`config.resolve`), its penalty built from `config.penalty`; every size problem is reported
    here, before anything compiles. Build one per config and keep it while its programs serve:
    another Stream compiles its own."""
    return build_runs([config])[0]


def build_runs(configs: list[StreamConfig]) -> tuple[Stream, list[RunConfig]]:
    """`build` of the first of `configs`, and every config resolved as one of its runs
    (`config.resolve_runs`: they may differ only in their seeds), before anything compiles."""
    config = configs[0]
    if config.env not in envs_mjx.ALL_ENVS:
        raise ValueError(f"unknown env {config.env!r}; valid names: {list(envs_mjx.ALL_ENVS)}")
    if config.learner not in learners.ALL_LEARNERS and ":" not in config.learner:
        raise ValueError(f"unknown learner {config.learner!r}; valid names: "
                         f"{list(learners.ALL_LEARNERS)}, or your own as MODULE:FACTORY")
    env = envs_mjx.load(config.env, config.env_config)
    ld_dim = len(env.ld_state_names)
    runs = resolve_runs(configs, ld_dim, jax.default_backend())  # the learner's ld_dim the env's
    config = runs[0]
    unknown = sorted(set(config.eval.distortion_dims) - set(env.ld_state_names))
    if unknown:
        raise ValueError(f"eval.distortion_dims {unknown} are not LD-state names of "
                         f"{config.env}: {list(env.ld_state_names)}")
    learner = learners.make(config.learner, config.learner_config, ld_dim=ld_dim)
    ppo = ppo_lib.make(ld_dim, env.action_size, config.ppo, total_updates=config.epochs)
    problems = []
    if config.eval.regressor_normalize and rotation.ld_blocks(env.ld_state_names,
                                                              env.ld_state_groups)[0]:
        problems.append(f"{config.env}'s rotation blocks are scored on the LD state as is "
                        "(docs/reference/suite.md §5): set eval.regressor_normalize=False")
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
    keep, columns = config.replay.keep_fraction, config.replay.slots
    if config.num_envs > columns - int(keep * columns):
        problems.append(
            f"each epoch adds {config.num_envs} columns but only "
            f"{columns - int(keep * columns)} replay slots are replaceable"
        )
    if config.epochs < config.fill_epochs:
        problems.append(
            f"epochs ({config.epochs}) end before the replay fills ({config.fill_epochs} epochs "
            "= replay.slots / num_envs); the learner would never train"
        )
    if problems:
        raise ValueError("; ".join(problems))
    optimizer = learners.default_optimizer(learner)
    penalty = None if config.penalty is None else latent_penalty(config.penalty, learner, env)
    train_step = learners.make_train_step(learner, optimizer, penalty)
    return Stream(config, env, learner, ppo, optimizer, train_step), runs


def _bound(stream: Stream, fun):
    """`fun(stream, *args)` as a function of `args`, holding `stream` weakly: the program that
    jits it is kept by the Stream, and a strong reference back would keep both alive until
    Python's cycle collector ran."""
    ref = weakref.ref(stream)

    def call(*args):
        return fun(ref(), *args)

    call.__name__ = call.__qualname__ = getattr(fun, "__name__", "program")
    return call


def _frozen(options: dict) -> tuple:
    """jit options as a hashable key (compiler_options is a dict)."""
    return tuple(sorted((k, tuple(sorted(v.items())) if isinstance(v, dict) else v)
                        for k, v in options.items()))
