"""Brax's own PPO trainer on the suite's envs (jax 0.10, brax 0.14: envs_mjx.brax_compat)."""

import jax
import numpy as np
import pytest
from brax.training.agents.ppo import train as ppo

import envs_mjx
from envs_mjx import base, brax_compat  # noqa: F401  (base installs the compat)


def test_device_put_replicated_copies_each_leaf_to_every_device():
    devices = jax.local_devices()
    tree = {"a": np.arange(6.0).reshape(2, 3), "b": np.int32(7)}
    out = brax_compat.device_put_replicated(tree, devices)
    assert out["a"].shape == (len(devices), 2, 3) and out["b"].shape == (len(devices),)
    for shard in out["a"].addressable_shards:
        np.testing.assert_array_equal(np.asarray(shard.data)[0], tree["a"])
    assert {s.device for s in out["a"].addressable_shards} == set(devices)
    assert not brax_compat.install()  # installed by `envs_mjx.base`: not twice
    if jax.__version_info__[:2] == (0, 10):  # the pinned JAX has none of its own
        assert jax.device_put_replicated is brax_compat.device_put_replicated


# ~75 s of the default suite on two cores (Brax compiles its pmapped training and evaluation
# programs): slow-marked. The default suite keeps the compat shim's test above and Brax's
# training wrappers driving an env (test_domains::test_brax_training_wrappers_drive_the_env).
@pytest.mark.slow
def test_brax_ppo_train_runs_on_an_envs_mjx_env():
    """A few PPO steps of Brax's trainer, all local devices (pmap), evaluation included."""
    env = envs_mjx.make("CartPole", pixels="off", episode_length=8)
    steps = []
    _, params, metrics = ppo.train(
        environment=env, num_timesteps=2 * 8 * 2, episode_length=8, num_envs=8, batch_size=8,
        num_minibatches=2, unroll_length=2, num_updates_per_batch=1, num_evals=2,
        num_eval_envs=8, seed=0, progress_fn=lambda step, m: steps.append(step))
    assert steps[0] == 0 and steps[-1] >= 2 * 8 * 2
    assert np.isfinite(float(metrics["training/total_loss"]))
    # CartPole's reward: 1 / episode_length per step alive, so an 8-step episode sums to ≤ 1.
    assert 0 < float(metrics["eval/episode_reward"]) <= 1.0 + 1e-6
    assert metrics["eval/avg_episode_length"] <= 8
    assert params is not None
