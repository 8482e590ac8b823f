"""`envs_mjx.compiler_options(env)`: which envs it asks the older emitters for on the CPU, that XLA
still takes them (a jaxlib that dropped the option would refuse to compile), and that an env
program compiled with them computes what the default options compute (only the code generator
differs)."""

import jax
import jax.numpy as jnp
import numpy as np

import envs_mjx
from envs_mjx.compile import CPU_COMPILER_OPTIONS, DEEP_CHAIN, body_tree_depth


def test_the_older_emitters_go_to_mjx_physics_on_a_deep_body_tree_only():
    assert jax.default_backend() == "cpu"
    franka = envs_mjx.make("RearrangeGeom", arm="franka", pixels="off")
    # world -> link0 ... link7 -> hand -> finger: 10 bodies deep; the cart-pole's pole is 2.
    assert body_tree_depth(franka.mj_model) == 10
    assert envs_mjx.compiler_options(franka) == {"xla_cpu_use_fusion_emitters": False}
    # A copy: a caller adding its own options does not change the next caller's.
    envs_mjx.compiler_options(franka)["extra"] = 1
    assert CPU_COMPILER_OPTIONS == {"xla_cpu_use_fusion_emitters": False}
    # The same arm with C MuJoCo's physics, and shallow trees, keep XLA's defaults (the
    # renderer's mesh tests are faster with them).
    franka_c = envs_mjx.make("RearrangeGeom", arm="franka", physics="c", pixels="off")
    assert envs_mjx.compiler_options(franka_c) is None
    for name, depth in (("CartPole", 2), ("MeshOnIncline", 1), ("HalfCheetah", 4)):
        env = envs_mjx.make(name, pixels="off")
        assert body_tree_depth(env.mj_model) == depth < DEEP_CHAIN
        assert envs_mjx.compiler_options(env) is None


def test_env_steps_compiled_with_the_options_match_the_defaults():
    env = envs_mjx.make("CartPole", pixels="off")
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), 3))
    actions = jnp.linspace(-1.0, 1.0, 3 * 5).reshape(5, 3, 1)

    def roll(s):
        return jax.lax.scan(lambda s, a: (jax.vmap(env.step)(s, a), None), s, actions)[0]

    ours = jax.jit(roll, compiler_options=CPU_COMPILER_OPTIONS)(states)
    # XLA's default emitters asked for by name: the test modules compile with the older ones
    # (tests/conftest.py), so a plain jit here would compare the program with itself.
    default = jax.jit(roll, compiler_options={"xla_cpu_use_fusion_emitters": True})(states)
    for field in ("ld_state", "reward"):
        np.testing.assert_allclose(getattr(ours, field), getattr(default, field), rtol=1e-5,
                                   atol=1e-6, err_msg=field)
    np.testing.assert_allclose(ours.pipeline_state.qpos, default.pipeline_state.qpos,
                               rtol=1e-5, atol=1e-6)
