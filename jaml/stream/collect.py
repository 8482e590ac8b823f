"""Acting in a batch of envs: rollouts that feed PPO (Brax transitions) and the replay (columns).

Envs reset themselves when an episode ends. Each rollout draws one fresh reset state per env up
front (a new key, so a new colour scheme / incline / mass) and swaps it in wherever `done` is set
during the rollout; an env that ends two episodes in one rollout starts both from that same state.
This keeps one reset per env per rollout instead of one per step (Brax's AutoResetWrapper reuses
the *first* reset state forever, which would freeze the per-reset randomisation).

The transition for a step is built by Brax's `acting.actor_step` before the swap, so its
`next_observation` is the step's true observation, not the next episode's first (Brax's loss
masks truncated steps and bootstraps only from the rollout's last `next_observation`). The
replay records the frame seen *before* each action (act[t] is executed after frame t, reference
§3); the final frame of an episode is not recorded, the next episode's first is.

Shapes: E envs, T steps, H×W×3 frames, A actions, D LD state.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from brax.envs.wrappers.training import VmapWrapper
from brax.training import acting
from brax.training import types as brax_types
from flax import struct

from envs_mjx.base import Env, State
from jaml.stream.replay import Columns


@struct.dataclass
class Episodes:
    """Running per-env episode return and length, and the sums over episodes that finished."""

    ret: jax.Array
    length: jax.Array
    finished: jax.Array
    finished_return: jax.Array
    finished_length: jax.Array

    @staticmethod
    def zeros(num_envs: int) -> Episodes:
        z = jnp.zeros((num_envs,), jnp.float32)
        return Episodes(z, z, jnp.zeros(()), jnp.zeros(()), jnp.zeros(()))

    def step(self, reward: jax.Array, done: jax.Array) -> Episodes:
        ret, length = self.ret + reward, self.length + 1
        return Episodes(
            ret=jnp.where(done, 0.0, ret),
            length=jnp.where(done, 0.0, length),
            finished=self.finished + done.sum(),
            finished_return=self.finished_return + jnp.where(done, ret, 0.0).sum(),
            finished_length=self.finished_length + jnp.where(done, length, 0.0).sum(),
        )

    def summary(self) -> dict[str, jax.Array]:
        """Means over episodes finished since the counters were last cleared (NaN if none)."""
        n = self.finished
        safe = jnp.maximum(n, 1.0)
        nan = jnp.full((), jnp.nan)
        return {
            "episodes": n,
            "episode_return": jnp.where(n > 0, self.finished_return / safe, nan),
            "episode_length": jnp.where(n > 0, self.finished_length / safe, nan),
        }

    def cleared(self) -> Episodes:
        z = jnp.zeros(())
        return self.replace(finished=z, finished_return=z, finished_length=z)


def reset(env: Env, key: jax.Array, num_envs: int) -> State:
    """A batch of `num_envs` independent resets; env slot i gets what `env.reset_batch` gives
    slot i (MeshOnIncline: object i mod N), so a slot keeps it across the resets swapped in."""
    if not isinstance(env, Env):  # e.g. a Brax wrapper, whose reset reset_batch would bypass
        return jax.vmap(env.reset)(jax.random.split(key, num_envs))
    return env.reset_batch(key, num_envs)


def _swap_in(done: jax.Array, fresh: State, state: State) -> State:
    def pick(a, b):
        return jnp.where(done.reshape(done.shape + (1,) * (a.ndim - 1)), a, b)

    return jax.tree.map(pick, fresh, state)


def rollout(env: Env, state: State, policy: brax_types.Policy, key: jax.Array, length: int,
            episodes: Episodes | None = None):
    """`length` steps of every env under `policy`.

    Returns (final state, Brax Transition [E, T], Columns [E, T + 1], episodes). The columns hold
    the T frames acted on plus the final state's frame (whose action is unknown and left 0, the
    reference's dummy current action), so consecutive rollouts overlap by one frame.
    """
    num_envs = state.reward.shape[0]
    venv = VmapWrapper(env)
    k_reset, k_steps = jax.random.split(key)
    fresh = reset(env, k_reset, num_envs)
    episodes = Episodes.zeros(num_envs) if episodes is None else episodes

    def body(carry, k):
        state, episodes = carry
        nstate, transition = acting.actor_step(venv, state, policy, k, ("truncation",))
        done = nstate.done > 0
        record = (state.pixels, transition.action, state.ld_state, state.info["t"] == 0)
        episodes = episodes.step(nstate.reward, done)
        return (_swap_in(done, fresh, nstate), episodes), (transition, record)

    (state, episodes), (transitions, (frames, actions, ld, starts)) = jax.lax.scan(
        body, (state, episodes), jax.random.split(k_steps, length)
    )

    def columns_of(steps, last):  # [T, E, ...] + [E, ...] -> [E, T + 1, ...]
        return jnp.swapaxes(jnp.concatenate([steps, last[None]], axis=0), 0, 1)

    columns = Columns(
        frames=columns_of(frames, state.pixels),
        actions=columns_of(actions, jnp.zeros_like(actions[0])),
        ld=columns_of(ld, state.ld_state),
        starts=columns_of(starts, state.info["t"] == 0),
    )
    transitions = jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), transitions)
    return state, transitions, columns, episodes
