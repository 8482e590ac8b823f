"""PPO (Brax pieces) learns CartPole from its LD state on CPU; the random policy is uniform."""

import jax
import numpy as np
import pytest

import envs_mjx
from jaml.stream import collect
from jaml.stream import ppo as ppo_lib

# A uniform random policy keeps CartPole up for ≈ 48 steps on average (64 envs × 200 steps,
# measured with `ppo_lib.random_policy`); an episode lasts at most 200.
THRESHOLD = 150.0


@pytest.mark.slow  # ~80 s on two cores; the losses and update are checked by the fast tests
def test_ppo_learns_cartpole_from_the_ld_state():
    env = envs_mjx.make("CartPole", pixels="off")
    # Reference settings except a 3× learning rate without decay, to learn in a short run.
    agent = ppo_lib.make(4, env.action_size, ppo_lib.PPOConfig(learning_rate=3e-4, lr_decay=False))
    num_envs, length = 32, 32

    @jax.jit
    def epoch(carry, key):
        state, ppo_state, episodes = carry
        k_roll, k_update = jax.random.split(key)
        state, transitions, _, episodes = collect.rollout(
            env, state, agent.policy(ppo_state), k_roll, length, episodes
        )
        ppo_state, _ = agent.update(ppo_state, transitions, k_update)
        return (state, ppo_state, episodes.cleared()), episodes.summary()

    key = jax.random.PRNGKey(0)
    carry = (collect.reset(env, key, num_envs), agent.init(key), collect.Episodes.zeros(num_envs))
    lengths = []
    for i in range(50):
        carry, summary = epoch(carry, jax.random.fold_in(key, i))
        lengths.append(float(summary["episode_length"]))
    late = np.nanmean(lengths[-10:])
    assert late >= THRESHOLD, f"mean episode length {late:.1f} over the last 10 epochs: {lengths}"


def test_random_policy_is_uniform_in_the_action_box():
    policy = ppo_lib.random_policy(3)
    actions, extras = policy(np.zeros((20000, 5), np.float32), jax.random.PRNGKey(0))
    actions = np.asarray(actions)
    assert actions.shape == (20000, 3) and extras == {}
    assert actions.min() >= -1 and actions.max() <= 1
    np.testing.assert_allclose(actions.mean(0), 0.0, atol=0.02)
    np.testing.assert_allclose(actions.var(0), 1 / 3, atol=0.01)  # Var U(−1, 1) = 1/3


def test_ppo_config_rejects_bad_values():
    with pytest.raises(ValueError, match="learning_rate"):
        ppo_lib.PPOConfig(learning_rate=0.0)
    with pytest.raises(ValueError, match="num_updates"):
        ppo_lib.PPOConfig(num_updates=0)
