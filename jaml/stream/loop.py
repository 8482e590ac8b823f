"""The learning loop (paper §2.1): PPO collects frames, the replay keeps them, a learner trains.

One epoch, a pure jitted function of `StreamState`:
  1. every env acts for `rollout_len` steps under the current policy (PPO on the LD state, or
     uniform random actions), rendering a 64×64 frame per step;
  2. PPO updates on that rollout;
  3. the rollout's columns go into the replay;
  4. once the replay is full (reference §3), the learner takes `learner_steps` gradient steps,
     each on `frames_per_batch // L` sequences of L frames sampled from the replay.
Several independent runs of one Stream (configs that differ only in their seeds) train as one
program: their states stack along a leading runs axis R, `Stream.epochs` vmaps the epoch over
them, and `run_stacked_epochs` runs n epochs in device loops of up to 32 (GPU/TPU; the runs
sharded across a device mesh) or a host loop of jitted pieces (CPU). `Stream.run_epochs` is the
one-run case. The periodic analysis is `jaml.stream.analysis`.

Shapes: R runs, E envs, T rollout_len, L = learner.seq_len, B sequences per learner batch.
"""

from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

import envs_mjx
from envs_mjx.base import Env, State
from jaml import learners
from jaml.evaluation import rotation
from jaml.stream import collect
from jaml.stream import ppo as ppo_lib
from jaml.stream import replay as replay_lib
from jaml.stream.collect import Episodes
from jaml.stream.config import StreamConfig
from jaml.stream.programs import on_release, stream_jit


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
    # The per-device executables of the multi-device loop, by (device, input avals). Shared by
    # the Streams that `build` makes for one config's seeds (`dataclasses.replace` keeps it).
    programs: dict = dataclasses.field(default_factory=dict, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "_program", (self.config.program_key(), self.keep_fraction))

    def _parts(self) -> tuple:
        return (self.env, self.learner, self.ppo, self.optimizer, self.train_step)

    def __hash__(self) -> int:
        return hash((self._program, *map(id, self._parts())))

    def __eq__(self, other) -> bool:
        # The parts by identity (they are closures and modules without value equality), held
        # by both Streams, so the comparison never relies on recycled ids.
        return (isinstance(other, Stream) and self._program == other._program
                and all(a is b for a, b in zip(self._parts(), other._parts(), strict=True)))

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
                cfg.replay_columns, cfg.rollout_len + 1, learners.learner.FRAME_SHAPE,
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
        (H100, VAE_rpl at the paper's batch: 6 runs vmapped trained 33K frames/s in all, one run
        alone 76K)."""

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
            return _learn_runs(self, ls, states.replay, k_learn)

        def skip(ls):
            return ls, _skipped(self, states, k_learn)

        learner_state, learner_metrics = jax.lax.cond(_replays_full(states), train, skip,
                                                      states.learner)
        metrics.update({f"learner/{k}": v for k, v in learner_metrics.items()})
        return states.replace(learner=learner_state), metrics

    def run_epochs(self, s: StreamState, n: int) -> tuple[StreamState, dict[str, jax.Array]]:
        """n epochs of one run; metrics stacked [n]. The state is donated (do not reuse the
        argument). `run_stacked_epochs` with R = 1: see it for the device and host loops."""
        states, metrics = run_stacked_epochs(self, stack_runs([s]), n)
        return unstack_runs(states)[0], jax.tree.map(lambda x: x[:, 0], metrics)


_PPO_METRICS = ("total_loss", "policy_loss", "v_loss", "entropy_loss", "kl_mean")


# -- several runs at once ---------------------------------------------------------------------

def stack_runs(states: list[StreamState]) -> StreamState:
    """R runs' states → one state whose leaves carry a leading runs axis [R, ...].

    Weak types are dropped (e.g. Brax's normaliser initialises `std_eps` from a Python float):
    the epoch loop returns strong types, and a leaf whose type changed between calls would
    re-trace and re-compile the loop on the second call."""
    return jax.tree.map(lambda *x: jax.lax.convert_element_type(jnp.stack(x), x[0].dtype),
                        *states)


def unstack_runs(states: StreamState) -> list[StreamState]:
    """The inverse of `stack_runs`: one state per run."""
    count = states.epoch.shape[0]
    return [jax.tree.map(lambda x, i=i: x[i], states) for i in range(count)]


def runs_mesh(num_runs: int, devices=None) -> Mesh:
    """A 1-D mesh ("runs") over the first min(num_runs, len(devices)) devices (default: all
    local devices of the default backend). With `jax.distributed` initialised, pass
    `jax.devices()` to span every host's devices."""
    devices = list(jax.local_devices() if devices is None else devices)
    return Mesh(np.asarray(devices[:max(1, min(num_runs, len(devices)))]), (RUNS_AXIS,))


RUNS_AXIS = "runs"


def run_stacked_epochs(stream: Stream, states: StreamState, n: int, *, mesh: Mesh | None = None,
                       host_loop: bool | None = None):
    """n epochs of R independent runs of one Stream, stacked along a leading axis.

    Returns (states, metrics [n, R] per name). The states are donated (do not reuse the
    argument). Every run computes exactly what it would alone (the same keys and functions),
    so one call trains R seeds with one compiled program.

    The device loop (default on GPU/TPU) runs up to 32 epochs per call inside `fori_loop`.
    With a mesh of several devices (default: `runs_mesh(R)`) the states are sharded along its
    "runs" axis and each device runs the same one-device program on its own runs, launched
    from one host thread per device so the devices work at once; nothing is communicated
    between them. R is padded to a multiple of the mesh size with copies of the first run,
    dropped afterwards.
    One program per device rather than one `shard_map` program: XLA's GPU compiler crashed
    (segfault, jaxlib 0.11.2, 2×H200) compiling the `shard_map` form of this loop, which XLA:CPU
    compiled and ran correctly.
    The host loop (default on CPU) is a Python loop over jitted, vmapped `act` and `learn_step`
    calls computing the same function with the same keys: XLA:CPU runs convolutions inside a
    while loop 20–40× slower than outside one (measured: two VAE steps 12.4 s in a scan vs
    0.8 s unrolled, 2-core EPYC, jaxlib 0.10.2).
    """
    count = int(states.epoch.shape[0])
    if host_loop is None:
        host_loop = jax.default_backend() == "cpu"
    if host_loop:
        return _host_loop(stream, states, n)
    mesh = runs_mesh(count) if mesh is None else mesh
    padded = -count % mesh.size
    if padded:
        states = jax.tree.map(
            lambda x: jnp.concatenate([x, jnp.repeat(x[:1], padded, axis=0)]), states)
    if mesh.size > 1:
        states = jax.device_put(states, NamedSharding(mesh, P(RUNS_AXIS)))
    blocks = []
    for start in range(0, n, _BLOCK):
        k = min(_BLOCK, n - start)
        states, metrics = _blocks_per_device(stream, mesh, states, k)
        blocks.append(jax.tree.map(lambda x, k=k: x[:k, :count], metrics))
    if padded:
        states = jax.tree.map(lambda x: x[:count], states)
    return states, jax.tree.map(lambda *x: jnp.concatenate(x), *blocks)


# Epochs per device call: the loop runs n ≤ _BLOCK epochs with n a traced bound, so one
# compilation serves every block length a run asks for.
_BLOCK = 32


def _blocks_per_device(stream: Stream, mesh: Mesh, states: StreamState, n: int):
    """`_block` on each device's runs; the states stay sharded as they came."""
    if mesh.size == 1:
        return _with_learner_options(_block)(stream, states, jnp.asarray(n, jnp.int32))
    leaves, treedef = jax.tree.flatten(states)
    devices = list(mesh.devices.flat)
    args = {d: (treedef.unflatten([next(s.data for s in x.addressable_shards if s.device == d)
                                   for x in leaves]),
                jax.device_put(jnp.asarray(n, jnp.int32), d)) for d in devices}
    # Each device gets its own executable (its inputs live there). Tracing runs here, in the
    # caller's thread, one device after another: Flax and JAX tracing state is not safe to share
    # between threads, and JAX's config contexts (e.g. `jax.threefry_partitionable`, which
    # decides the random bits) are thread-local, so the caller's are the ones that count. What
    # is thread safe, XLA compiling and running the executables, happens in one host thread per
    # device: a GPU while loop's trip test syncs with the thread that launched it, so a single
    # thread would run the devices one after another.
    avals = tuple(jax.typeof(x) for x in leaves)
    lowered = {d: _device_block_kept.lower(stream, *args[d]) for d in devices
               if (d, avals) not in stream.programs}

    def on(device):
        if device in lowered:
            stream.programs[device, avals] = lowered[device].compile(
                compiler_options=learners.compiler_options())
        return jax.block_until_ready(stream.programs[device, avals](*args[device]))

    with concurrent.futures.ThreadPoolExecutor(mesh.size) as pool:
        outs = list(pool.map(on, devices))
    sharding = NamedSharding(mesh, P(RUNS_AXIS))

    def gather(*parts):
        shape = (sum(p.shape[0] for p in parts), *parts[0].shape[1:])
        return jax.make_array_from_single_device_arrays(shape, sharding, list(parts))

    new = jax.tree.map(gather, *(o[0] for o in outs))
    metrics = jax.tree.map(lambda *m: np.concatenate([np.asarray(x) for x in m], axis=1),
                           *(o[1] for o in outs))
    return new, metrics


@functools.cache
def _with_learner_options(fn):
    """`fn(stream, states, ...)` jitted (the Stream static, the states donated) with the
    learner's compiler options (`learners.compiler_options()`: on the CPU convolutions take
    XLA's Eigen path, not YNNPACK's, which ran the VAE's train step ~1.5x slower; XLA's defaults
    elsewhere). Built at first use, not at import: the options depend on the backend."""
    return stream_jit(fn, static_argnums=0, donate_argnums=1,
                      compiler_options=learners.compiler_options())


def _block(stream: Stream, states: StreamState, n: jax.Array):
    """n (traced, ≤ _BLOCK) epochs of stacked runs; metrics in [_BLOCK, R] buffers, NaN past n."""
    shapes = jax.eval_shape(_epochs, stream, states)[1]
    buffers = jax.tree.map(lambda x: jnp.full((_BLOCK, *x.shape), jnp.nan, x.dtype), shapes)

    def body(i, carry):
        states, buffers = carry
        states, metrics = _epochs(stream, states)
        return states, jax.tree.map(lambda b, v: b.at[i].set(v), buffers, metrics)

    return jax.lax.fori_loop(0, n, body, (states, buffers))


# For one device's shard of sharded states: its buffers are views of the sharded arrays, which
# are not donated. Lowered and compiled explicitly, per device, into `Stream.programs`.
_device_block_kept = stream_jit(_block, static_argnums=0)


def _host_loop(stream: Stream, states: StreamState, n: int):
    history = []
    for _ in range(n):
        states, k_learn, metrics = _act_runs(stream, states)
        if bool(_replays_full(states)):
            keys = jax.vmap(stream.learn_keys)(k_learn)  # [R, learner_steps, 2]
            learner_state, steps = states.learner, []
            for i in range(stream.config.learner_steps):
                learner_state, m = _learn_step_runs(stream, learner_state, states.replay,
                                                    keys[:, i])
                steps.append(m)
            states = states.replace(learner=learner_state)
            learner_metrics = jax.tree.map(lambda *v: jnp.mean(jnp.stack(v), axis=0), *steps)
        else:
            learner_metrics = _skipped(stream, states, k_learn)
        metrics.update({f"learner/{k}": v for k, v in learner_metrics.items()})
        history.append(metrics)
    return states, jax.tree.map(lambda *v: jnp.stack(v), *history)


def _replays_full(states: StreamState) -> jax.Array:
    """Whether the stacked runs' replays are full (run 0's: they fill on the same epoch).
    Vmapped: the replay's sizes are properties of one run's shapes."""
    return jax.vmap(lambda replay: replay.full)(states.replay)[0]


# `Stream.epochs` and `Stream.learn_runs` behind jit, for their callers inside larger programs:
# JAX caches a jitted function's trace per input shapes, so the shape-only trace of the metrics
# (`jax.eval_shape`) and the traced call share one trace of the epoch (and of the learner steps,
# traced for `_skipped`'s shapes and for the train branch) instead of tracing it twice; the
# nested call is inlined by XLA. Fig3's SPAIR epoch block: tracing + lowering 39 -> 28.5 s.
_epochs = stream_jit(lambda stream, states: stream.epochs(states), static_argnums=0)
_learn_runs = stream_jit(lambda stream, *args: stream.learn_runs(*args), static_argnums=0)


def _skipped(stream: Stream, states: StreamState, k_learn: jax.Array):
    """NaN learner metrics [R] for an epoch without learner steps (the replay still fills)."""
    shapes = jax.eval_shape(_learn_runs, stream, states.learner, states.replay, k_learn)[1]
    return jax.tree.map(lambda x: jnp.full(x.shape, jnp.nan, x.dtype), shapes)


@stream_jit(static_argnums=0, donate_argnums=1)
def _act_runs(stream: Stream, states: StreamState):
    return jax.vmap(stream.act)(states)


def _learn_step_runs(stream: Stream, learner_state, replay, keys):
    return _with_learner_options(_vmapped_learn_step)(stream, learner_state, replay, keys)


def _vmapped_learn_step(stream: Stream, learner_state, replay, keys):
    return jax.vmap(stream.learn_step)(learner_state, replay, keys)


# The last few Streams built, by program: bounded, so a process that builds many configs (a
# sweep) does not keep every env and learner alive. What the jitted functions compiled for them
# stays in those functions' caches until `release_programs`.
_BUILT: collections.OrderedDict = collections.OrderedDict()
_BUILT_KEPT = 8


@on_release
def forget_built() -> None:
    """Drops the kept Streams and their per-device executables (`Stream.programs`, shared with
    the Streams made from them for other seeds); part of `release_programs`."""
    for stream in _BUILT.values():
        stream.programs.clear()
    _BUILT.clear()


def build(config: StreamConfig, latent_penalty=None) -> Stream:
    """A Stream for `config`; every size problem is reported here, before anything compiles.

    Building a config again in one process, or one that differs only in its seed, reuses the
    same env, learner and PPO (of the last `_BUILT_KEPT` programs built), so jitted functions
    compiled for one serve the other (see `Stream`)."""
    cache_key = (config.program_key(), latent_penalty)
    if cache_key not in _BUILT:
        _BUILT[cache_key] = _build(config.replace(seed=0), latent_penalty)
        while len(_BUILT) > _BUILT_KEPT:
            _BUILT.popitem(last=False)
    _BUILT.move_to_end(cache_key)
    base = _BUILT[cache_key]
    return base if base.config == config else dataclasses.replace(base, config=config)


def make_learner(name: str, ld_dim: int, overrides: dict) -> learners.Learner:
    """A registry learner, or your own: "MODULE:FACTORY" names `factory(ld_dim=D, **overrides)`
    returning a `jaml.learners.Learner` (the protocol: docs/own_learner.md)."""
    if ":" not in name:
        return learners.make(name, ld_dim=ld_dim, **overrides)
    import importlib

    module, _, attr = name.partition(":")
    try:
        factory = getattr(importlib.import_module(module), attr)
    except (ImportError, AttributeError) as error:
        raise ValueError(f"learner {name!r}: cannot import {attr} from {module} ({error}); give "
                         "MODULE:FACTORY with MODULE importable (on PYTHONPATH)") from None
    learner = factory(ld_dim=ld_dim, **overrides)
    if not isinstance(learner, learners.Learner):
        raise ValueError(f"learner {name!r}: {attr}(ld_dim=...) returned a "
                         f"{type(learner).__name__}, not a jaml.learners.Learner")
    return learner


def _build(config: StreamConfig, latent_penalty) -> Stream:
    if config.env not in envs_mjx.ALL_ENVS:
        raise ValueError(f"unknown env {config.env!r}; valid names: {list(envs_mjx.ALL_ENVS)}")
    if config.learner not in learners.ALL_LEARNERS and ":" not in config.learner:
        raise ValueError(f"unknown learner {config.learner!r}; valid names: "
                         f"{list(learners.ALL_LEARNERS)}, or your own as MODULE:FACTORY")
    env = envs_mjx.make(config.env, **config.env_overrides)
    ld_dim = len(env.ld_state_names)
    unknown = sorted(set(config.distortion_dims) - set(env.ld_state_names))
    if unknown:
        raise ValueError(f"distortion_dims {unknown} are not LD-state names of {config.env}: "
                         f"{list(env.ld_state_names)}")
    learner = make_learner(config.learner, ld_dim, config.learner_overrides)
    problems = []
    if config.regressor_normalize and rotation.ld_blocks(env.ld_state_names,
                                                         env.ld_state_groups)[0]:
        problems.append(f"{config.env}'s rotation blocks are scored on the LD state as is "
                        "(reference §5): set regressor_normalize=False")
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
    columns = config.replay_columns
    if config.num_envs > columns - int(keep * columns):
        problems.append(
            f"each epoch adds {config.num_envs} columns but only "
            f"{columns - int(keep * columns)} replay slots are replaceable"
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
