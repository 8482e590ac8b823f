"""`envs_mjx.compiler_options()`: what it asks of XLA on the CPU, that XLA still takes it (a
jaxlib that dropped the option would refuse to compile), and that an env program compiled with
it computes what the default options compute (only the code generator differs)."""

import jax
import jax.numpy as jnp
import numpy as np

import envs_mjx
from envs_mjx.compile import CPU_COMPILER_OPTIONS


def test_cpu_options_are_the_older_fusion_emitters():
    assert jax.default_backend() == "cpu"
    assert envs_mjx.compiler_options() == {"xla_cpu_use_fusion_emitters": False}
    # A copy: a caller adding its own options does not change the next caller's.
    envs_mjx.compiler_options()["extra"] = 1
    assert CPU_COMPILER_OPTIONS == {"xla_cpu_use_fusion_emitters": False}


def test_env_steps_compiled_with_the_options_match_the_defaults():
    env = envs_mjx.make("CartPole", pixels="off")
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 3))
    actions = jnp.linspace(-1.0, 1.0, 3 * 5).reshape(5, 3, 1)

    def roll(s):
        return jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a), None), s, actions)[0]

    ours = jax.jit(roll, compiler_options=envs_mjx.compiler_options())(states)
    default = jax.jit(roll)(states)
    for field in ("ld_state", "reward"):
        np.testing.assert_allclose(getattr(ours, field), getattr(default, field), rtol=1e-5,
                                   atol=1e-6, err_msg=field)
    np.testing.assert_allclose(ours.pipeline_state.qpos, default.pipeline_state.qpos,
                               rtol=1e-5, atol=1e-6)
