"""The rollout harness the envs_mjx tests share (test_domains, test_rearrange): one env, a jitted
batched reset and a jitted batched rollout that records per step what their checks read."""

import functools

import jax
import numpy as np

from envs_mjx.compile import CPU_COMPILER_OPTIONS

# Tests run a few hundred steps, so LLVM's backend optimizations cost far more (compile time on
# 2 CPU cores) than they save; this roughly halves each MJX compile. With the options of jaml's
# env programs (`envs_mjx.compiler_options()` on the CPU: the older fusion emitters, which
# compile env programs faster and run the Franka's kinematics ~100x faster). Per jit, not global.
FAST_COMPILE = {"xla_backend_optimization_level": 0, **CPU_COMPILER_OPTIONS}

# Recordable fields of a State; any other name is read from its physics data (qpos, ctrl, ...).
STATE_FIELDS = {
    "ld_state": lambda s: s.ld_state,
    "obs": lambda s: s.obs,
    "reward": lambda s: s.reward,
    "done": lambda s: s.done,
    "truncation": lambda s: s.info["truncation"],
    "nonfinite": lambda s: s.metrics["nonfinite_action"],
    "diverged": lambda s: s.metrics["nonfinite_physics"],
    "contact_dist": lambda s: s.pipeline_state._impl.contact.dist,
}
RECORD = ("ld_state", "reward", "done", "qpos", "qvel", "nonfinite")


class Harness:
    """`env` with `reset` and `rollout(state [B], actions [T, B, A])` -> (final state,
    {field: [T, B, ...]}), both jitted over a batch of B env slots.

    `reset` takes B keys (vmap of env.reset) or, with `reset_batch`, one key
    (env.reset_batch(key, B), for domains whose env slots differ). `record` names the fields
    each step keeps."""

    def __init__(self, env, batch, steps, *, record=RECORD, reset_batch=False,
                 compiler_options=FAST_COMPILE):
        self.env, self.batch, self.steps, self.reset_batch = env, batch, steps, reset_batch
        if reset_batch:
            self.reset = jax.jit(lambda k: env.reset_batch(k, batch),
                                 compiler_options=compiler_options)
        else:
            self.reset = jax.jit(jax.vmap(env.reset), compiler_options=compiler_options)

        def rollout(state, actions):
            def body(s, a):
                s = env.step(s, a)
                d = s.pipeline_state
                rec = {k: STATE_FIELDS[k](s) if k in STATE_FIELDS else getattr(d, k)
                       for k in record}
                return s, rec

            return jax.lax.scan(body, state, actions)

        self.rollout = jax.jit(
            jax.vmap(rollout, in_axes=(0, 1), out_axes=(0, 1)), compiler_options=compiler_options
        )

    @functools.cached_property
    def random_run(self):
        """(initial state, actions [T, B, A], final state, trajectory [T, B, ...] as numpy)."""
        key = jax.random.key(0)
        state0 = self.reset(key if self.reset_batch else jax.random.split(key, self.batch))
        shape = (self.steps, self.batch, self.env.action_size)
        actions = jax.random.uniform(jax.random.key(1), shape, minval=-1.0, maxval=1.0)
        final, traj = self.rollout(state0, actions)
        return state0, actions, final, jax.tree.map(np.asarray, traj)
