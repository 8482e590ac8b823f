"""PPO on the true LD state, assembled from Brax's PPO pieces (docs/reference/suite.md §3 settings).

Brax supplies the networks (`ppo.networks.make_ppo_networks`, tanh-normal policy), the loss
(`ppo.losses.compute_ppo_loss`), acting (`acting.actor_step`, in `jaml.stream.collect`) and the
observation normaliser (`acme.running_statistics`). `brax.training.agents.ppo.train` is not used:
it owns the environment loop, and here the loop also renders frames, fills the replay and trains a
learner between PPO updates. The update below is Brax's `sgd_step`/`minibatch_step` restated for
one rollout [num_envs, T]: `num_updates` passes, each a shuffle of the envs into `num_minibatches`
minibatches of whole env trajectories.

Reference settings (pytorch-a2c-ppo-acktr in the paper's suite): lr 1e-4 decayed linearly to 0,
γ 0.99, no GAE (λ = 1: discounted returns bootstrapped from the value at the rollout's end), clip
0.2, value-loss coefficient 0.5, entropy 0.01, gradient norm clipped at 0.5; an MLP of 64 units
with 3 passes × 8 minibatches on the pendulums, 256 units otherwise.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import optax
from brax.training import types as brax_types
from brax.training.acme import running_statistics
from brax.training.agents.ppo import losses as ppo_losses
from brax.training.agents.ppo import networks as ppo_networks
from flax import linen, struct

from jaml.configs.stream import PPOConfig


@struct.dataclass
class PPOState:
    """params: Brax's PPONetworkParams(policy, value); normalizer: running statistics."""

    params: ppo_losses.PPONetworkParams
    normalizer: running_statistics.RunningStatisticsState
    opt_state: Any


@dataclasses.dataclass(frozen=True)
class PPO:
    """The PPO agent's pure functions for one observation/action size and schedule."""

    config: PPOConfig
    networks: ppo_networks.PPONetworks
    optimizer: optax.GradientTransformation
    obs_size: int
    action_size: int

    def init(self, key: jax.Array) -> PPOState:
        k_policy, k_value = jax.random.split(key)
        params = ppo_losses.PPONetworkParams(
            policy=self.networks.policy_network.init(k_policy),
            value=self.networks.value_network.init(k_value),
        )
        normalizer = running_statistics.init_state(
            jax.ShapeDtypeStruct((self.obs_size,), jnp.float32)
        )
        return PPOState(params=params, normalizer=normalizer,
                        opt_state=self.optimizer.init(params))

    def policy(self, state: PPOState, deterministic: bool = False) -> brax_types.Policy:
        """Brax policy `(obs [B, D], key) -> (actions [B, A], extras)`."""
        make = ppo_networks.make_inference_fn(self.networks)
        return make((state.normalizer, state.params.policy, state.params.value), deterministic)

    def update(self, state: PPOState, data: brax_types.Transition, key: jax.Array):
        """One PPO update on a rollout with leading [num_envs, T]; returns (state, metrics)."""
        cfg = self.config
        num_envs = data.reward.shape[0]
        if num_envs % cfg.num_minibatches:
            raise ValueError(
                f"ppo: {num_envs} envs do not split into {cfg.num_minibatches} minibatches"
            )
        normalizer = state.normalizer
        if cfg.normalize_observations:
            normalizer = running_statistics.update(normalizer, data.observation)
        loss_fn = functools.partial(
            ppo_losses.compute_ppo_loss,
            ppo_network=self.networks,
            entropy_cost=cfg.entropy_cost,
            discounting=cfg.discounting,
            reward_scaling=cfg.reward_scaling,
            gae_lambda=cfg.gae_lambda,
            clipping_epsilon=cfg.clipping_epsilon,
            normalize_advantage=cfg.normalize_advantage,
            vf_coefficient=cfg.vf_coefficient,
        )
        grad_fn = jax.grad(loss_fn, has_aux=True)

        def minibatch(carry, mb):
            params, opt_state, key = carry
            key, k_loss = jax.random.split(key)
            grads, metrics = grad_fn(params, normalizer, mb, k_loss)
            updates, opt_state = self.optimizer.update(grads, opt_state, params)
            return (optax.apply_updates(params, updates), opt_state, key), metrics

        def sgd_pass(carry, key):
            k_perm, k_mb = jax.random.split(key)
            perm = jax.random.permutation(k_perm, num_envs)
            shuffled = jax.tree.map(
                lambda x: x[perm].reshape(cfg.num_minibatches, -1, *x.shape[1:]), data
            )
            params, opt_state, _ = carry
            return jax.lax.scan(minibatch, (params, opt_state, k_mb), shuffled)

        (params, opt_state, _), metrics = jax.lax.scan(
            sgd_pass, (state.params, state.opt_state, key),
            jax.random.split(key, cfg.num_updates),
        )
        metrics = jax.tree.map(jnp.mean, metrics)
        return PPOState(params=params, normalizer=normalizer, opt_state=opt_state), metrics


def make(obs_size: int, action_size: int, config: PPOConfig | None = None,
         total_updates: int | None = None) -> PPO:
    """PPO for `obs_size` LD states; with lr_decay the rate falls linearly to 0 over
    `total_updates` PPO updates (each = num_updates · num_minibatches optimizer steps)."""
    config = config or PPOConfig()
    networks = ppo_networks.make_ppo_networks(
        obs_size,
        action_size,
        preprocess_observations_fn=(
            running_statistics.normalize
            if config.normalize_observations
            else brax_types.identity_observation_preprocessor
        ),
        policy_hidden_layer_sizes=config.hidden,
        value_hidden_layer_sizes=config.hidden,
        activation=linen.tanh,
    )
    lr: Any = config.learning_rate
    if config.lr_decay and total_updates:
        lr = optax.linear_schedule(
            config.learning_rate, 0.0, total_updates * config.num_updates * config.num_minibatches
        )
    optimizer = optax.chain(optax.clip_by_global_norm(config.max_grad_norm), optax.adam(lr))
    return PPO(config, networks, optimizer, obs_size, action_size)


def random_policy(action_size: int) -> brax_types.Policy:
    """Uniform actions in [-1, 1] (the reference's `Random` agent), as a Brax policy."""

    def policy(obs: jax.Array, key: jax.Array):
        return jax.random.uniform(key, (*obs.shape[:-1], action_size), minval=-1.0, maxval=1.0), {}

    return policy
