"""The periodic analysis of a run (reference §5): alignment of its latents with the true state.

Encode sequences from the replay (the regressor's training set) and from fresh rollouts of a
random policy (π_rand, the same set at every analysis: a fixed key) and of the current policy
(π_curr); fit a fresh regressor latents → LD state of each sequence's last input frame and report
its per-dimension test error, plus the distortion ρ on π_rand. All functions take one run's
(unstacked) `StreamState`.

Shapes: E envs, L = learner.seq_len, N sequences, Z latent, D LD state.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from envs_mjx.base import Env, State
from jaml import evaluation
from jaml.stream import collect
from jaml.stream import replay as replay_lib
from jaml.stream.loop import Stream, StreamState


def encoded_replay(stream: Stream, s: StreamState, key: jax.Array, num: int):
    """(latents [N, Z], LD targets [N, D]) of N ≈ num sequences sampled from the replay."""
    keys = jax.random.split(key, _chunks(num, stream.config.num_envs))
    return _map_chunks(_replay_chunk, stream, s, None, keys)


def encoded_rollouts(stream: Stream, s: StreamState, key: jax.Array, num: int, random: bool):
    """(latents, LD targets) of sequences cut from fresh rollouts: reset, `eval_transient`
    steps, then consecutive L-step rollouts per env (reference §5, start t = 0)."""
    k_start, k_chunks = jax.random.split(key)
    random = jnp.asarray(random)
    env_state = _rollout_start(stream, s, k_start, random)
    keys = jax.random.split(k_chunks, _chunks(num, stream.config.num_envs))
    return _map_chunks(_rollout_chunk, stream, s, (env_state, random), keys)


def evaluate(stream: Stream, s: StreamState, key: jax.Array, pi_rand_key: jax.Array) -> dict:
    """Alignment errors [D] on π_rand (and π_curr under PPO), the held-out validation error,
    and the distortion of the π_rand latents. Host-side numbers (floats / lists)."""
    cfg = stream.config
    k_train, k_curr, k_reg = jax.random.split(key, 3)
    train = encoded_replay(stream, s, k_train, cfg.eval_train)
    tests = {"pi_rand": encoded_rollouts(stream, s, pi_rand_key, cfg.eval_rand, random=True)}
    if cfg.policy == "ppo" and cfg.eval_curr > 0:
        tests["pi_curr"] = encoded_rollouts(stream, s, k_curr, cfg.eval_curr, random=False)
    errors = evaluation.alignment_errors(
        *train, tests, seed=int(jax.random.randint(k_reg, (), 0, 2**31 - 1)),
        seq_len=stream.seq_len, num_iterations=cfg.regressor_iterations,
        normalize=cfg.regressor_normalize,
    )
    lat, st = tests["pi_rand"]
    return {
        "errors": {k: np.asarray(v).tolist() for k, v in errors.items()},
        "distortion": float(evaluation.distortion(lat, st[:, distortion_columns(stream)])),
    }


def distortion_columns(stream: Stream) -> np.ndarray:
    """Indices of the LD state's τ^true entries for the distortion (all by default)."""
    names = list(stream.env.ld_state_names)
    return np.asarray([names.index(n) for n in stream.config.distortion_dims] or
                      range(len(names)))


def reconstructions(stream: Stream, s: StreamState, key: jax.Array, num: int = 8):
    """(true, decoded) last frames of `num` replay sequences, uint8 [num, 64, 64, 3] each."""
    seqs = replay_lib.sample(s.replay, key, num, stream.seq_len)
    recon = _reconstruct(stream, s.learner.variables, seqs.frames, seqs.actions)
    return (np.asarray(seqs.frames[:, -1]),
            np.asarray(jnp.round(recon[:, -1] * 255)).astype(np.uint8))


def _chunks(num: int, num_envs: int) -> int:
    return max(1, math.ceil(num / num_envs))


def _map_chunks(producer, stream: Stream, s: StreamState, carry, keys):
    """For each key, `producer(stream, s, carry, key) -> (carry, Columns [E, L])`, encoded;
    returns (latents [N, Z], LD targets [N, D]) with N = E · len(keys).

    A host loop over one jitted producer and one jitted encoder on every backend: a scan over
    the chunks would compile the encoder once per data set (its length is static), and the
    per-chunk dispatch costs milliseconds against seconds of compilation (and XLA:CPU runs
    convolutions inside loops slowly, see `jaml.stream.loop.run_epochs`)."""
    outs = []
    for k in keys:
        carry, seqs = producer(stream, s, carry, k)
        outs.append(_encode(stream, s.learner.variables, seqs))
    return tuple(jnp.concatenate(x) for x in zip(*outs, strict=True))


# Module-level jitted functions keyed on the Stream: a `jax.jit` made per call would recompile
# at every analysis.
@jax.jit(static_argnums=0)
def _reconstruct(stream: Stream, variables, frames, actions):
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
