"""PPO (Brax pieces) learns CartPole from its LD state on CPU; the random policy is uniform."""

import functools

import jax
import numpy as np
import pytest

import envs_mjx
from jaml.stream import collect
from jaml.stream import ppo as ppo_lib

# A uniform random policy keeps CartPole up for ≈ 48 steps on average (64 envs × 200 steps,
# measured with `ppo_lib.random_policy`); an episode lasts at most 200.
THRESHOLD = 150.0


@pytest.mark.slow  # ~80 s on two cores; the update and the value targets are checked below
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


def test_ppo_config_defaults_are_the_reference_settings():
    """docs/reference/suite.md §3 (pytorch-a2c-ppo-acktr on the pendulums)."""
    c = ppo_lib.PPOConfig()
    assert (c.learning_rate, c.lr_decay, c.discounting, c.gae_lambda) == (1e-4, True, 0.99, 1.0)
    assert (c.clipping_epsilon, c.vf_coefficient, c.entropy_cost, c.max_grad_norm) == (
        0.2, 0.5, 0.01, 0.5)
    assert (c.hidden, c.num_updates, c.num_minibatches) == ((64, 64), 3, 8)


def test_lambda_one_gives_discounted_returns_bootstrapped_at_the_rollouts_end():
    """λ = 1 (the reference's "no GAE"): Brax's value targets are the plain discounted returns,
    v_t = Σ_k γ^k r_{t+k} + γ^(T−t) V(s_T), computed here by a backward loop."""
    from brax.training.agents.ppo import losses as ppo_losses

    rng = np.random.default_rng(0)
    t_len, envs, gamma = 7, 3, 0.99
    rewards = rng.normal(size=(t_len, envs)).astype(np.float32)
    values = rng.normal(size=(t_len, envs)).astype(np.float32)
    bootstrap = rng.normal(size=envs).astype(np.float32)
    zeros = np.zeros_like(rewards)
    vs, _ = ppo_losses.compute_gae(truncation=zeros, termination=zeros, rewards=rewards,
                                   values=values, bootstrap_value=bootstrap, lambda_=1.0,
                                   discount=gamma)
    expected, ret = np.zeros_like(rewards), bootstrap.astype(np.float64)
    for t in reversed(range(t_len)):
        ret = rewards[t] + gamma * ret
        expected[t] = ret
    np.testing.assert_allclose(vs, expected, rtol=1e-5, atol=1e-5)


@functools.cache
def _rollout_program(obs_size, action_size, hidden, normalize, num_envs=4, length=6):
    """One jitted CartPole reset + rollout per policy network: a policy is a function of the
    PPO state's (normaliser, parameters) and of its networks' sizes alone, so the two update
    tests (agents that differ in their optimiser settings) share one compiled program."""
    env = envs_mjx.make("CartPole", pixels="off")
    networks = ppo_lib.make(obs_size, action_size, ppo_lib.PPOConfig(
        hidden=hidden, normalize_observations=normalize))

    def run(normalizer, params, key):
        state = ppo_lib.PPOState(params=params, normalizer=normalizer, opt_state=None)
        start = collect.reset(env, key, num_envs)
        return collect.rollout(env, start, networks.policy(state), key, length)[1]

    return jax.jit(run)


def _rollout(agent, ppo_state):
    cfg = agent.config
    program = _rollout_program(agent.obs_size, agent.action_size, cfg.hidden,
                               cfg.normalize_observations)
    return program(ppo_state.normalizer, ppo_state.params, jax.random.PRNGKey(3))


def test_one_update_is_a_clipped_adam_step_on_brax_s_loss_after_the_normaliser_update():
    """num_updates = num_minibatches = 1: the normaliser takes the rollout's observations
    (mean checked against NumPy), then one step: Brax's loss gradient on the whole rollout,
    clipped to global norm 0.5, then Adam's first bias-corrected step, lr · g / (|g| + ε),
    written out here without optax. Entropy cost 0, so the loss does not depend on its key."""
    from brax.training.agents.ppo import losses as ppo_losses

    config = ppo_lib.PPOConfig(num_updates=1, num_minibatches=1, entropy_cost=0.0,
                               learning_rate=1e-3, lr_decay=False)
    agent = ppo_lib.make(4, 1, config)
    state = agent.init(jax.random.PRNGKey(0))
    data = _rollout(agent, state)
    new, _ = jax.jit(agent.update)(state, data, jax.random.PRNGKey(1))

    obs = np.asarray(data.observation).reshape(-1, 4)
    np.testing.assert_allclose(new.normalizer.mean, obs.mean(0), rtol=1e-5, atol=1e-6)
    # Brax's loss gradient, jitted (run eagerly, each of its ops compiled apart, it was most of
    # this test's time); the Adam step below is written out in NumPy.
    loss = functools.partial(
        ppo_losses.compute_ppo_loss, ppo_network=agent.networks, entropy_cost=0.0,
        discounting=config.discounting, reward_scaling=1.0, gae_lambda=config.gae_lambda,
        clipping_epsilon=config.clipping_epsilon, normalize_advantage=True,
        vf_coefficient=config.vf_coefficient)
    grads, _ = jax.jit(jax.grad(loss, has_aux=True))(
        state.params, new.normalizer, data, jax.random.PRNGKey(2))
    leaves = [np.asarray(g, np.float64) for g in jax.tree.leaves(grads)]
    norm = np.sqrt(sum((g ** 2).sum() for g in leaves))
    assert norm > config.max_grad_norm  # the clip is exercised
    scale = config.max_grad_norm / norm
    expected = [np.asarray(p) - 1e-3 * (g * scale) / (np.abs(g * scale) + 1e-8)
                for p, g in zip(jax.tree.leaves(state.params), leaves, strict=True)]
    for got, want in zip(jax.tree.leaves(new.params), expected, strict=True):
        np.testing.assert_allclose(got, want, rtol=0, atol=2e-6)


def test_the_learning_rate_decays_to_zero_over_the_run():
    """lr_decay over total_updates = 2 updates of one step each: the first two updates move the
    parameters, the third (lr 0) leaves them where they are."""
    config = ppo_lib.PPOConfig(num_updates=1, num_minibatches=1, learning_rate=1e-3)
    agent = ppo_lib.make(4, 1, config, total_updates=2)
    state = agent.init(jax.random.PRNGKey(0))
    data = _rollout(agent, state)
    update = jax.jit(agent.update)
    moved = []
    for i in range(3):
        new, _ = update(state, data, jax.random.PRNGKey(i))
        moved.append(max(float(np.abs(a - b).max()) for a, b in
                         zip(jax.tree.leaves(new.params), jax.tree.leaves(state.params),
                             strict=True)))
        state = new
    assert moved[0] > 1e-4 and moved[1] > 1e-4 and moved[2] == 0.0
