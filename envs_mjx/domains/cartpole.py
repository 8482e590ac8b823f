"""CartPole (docs/reference/suite.md §2): a pole on a cart, pushed by a +-10 N slider force.

Action: a continuous a in [-1, 1] (Brax convention) stands in for the reference's Discrete(2).
With `action_mode="sign"` (default, the reference's bang-bang control) the force is
10 N * sign(a): a > 0 is the reference's action 1 (+10 N), a < 0 its action 0 (-10 N); a == 0
exactly gives no force. With `action_mode="linear"` the force is 10 N * clip(a, -1, 1).
LD state: [theta, theta_dot, x, x_dot]. Done when |x| > 0.4 m or |theta| > 12 degrees; reward
1/200 a step (the reference's: 1 per step divided by the 200-step episode), so an episode's
return is at most 1. `conventions="gymnasium"` takes Gymnasium's CartPole-v1 values instead
(500 steps, reward 1 a step, |x| ≤ 2.4 m; `CartPoleConfig`). Reset: all four state entries
~U(+-0.05).
Multicolor: cart = scheme's base colour, pole = its pole colour; otherwise yellow cart, blue pole.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco

from envs_mjx.base import BASE, POLE, Env, geom_ids, random_colour_scheme
from envs_mjx.config import CartPoleConfig
from envs_mjx.domains._assets import asset


def default_config() -> CartPoleConfig:
    return CartPoleConfig()


class CartPole(Env):
    """Cart-pole with the reference's slow-falling pole (inertia diag(1,1,1))."""

    def __init__(self, config: CartPoleConfig | None = None, pixels_fn=None):
        config = config or default_config()
        if config.action_mode not in ("sign", "linear"):
            raise ValueError(f"action_mode must be 'sign' or 'linear', got {config.action_mode!r}")
        mj_model = mujoco.MjModel.from_xml_path(asset("cartpole.xml"))
        self._slots = [geom_ids(mj_model, ["cart"]), geom_ids(mj_model, ["pole"])]
        super().__init__(config, mj_model, ("theta", "theta_dot", "x", "x_dot"), pixels_fn)

    def _ld_groups(self):
        return ("position", "velocity", "position", "velocity")

    def _sample_reset(self, rng):
        k_state, k_colour = jax.random.split(rng)
        s = jax.random.uniform(k_state, (4,), minval=-1.0, maxval=1.0) * self.config.reset_noise
        qpos = jnp.stack([s[2], s[0]])  # model order: slider x, hinge theta
        qvel = jnp.stack([s[3], s[1]])
        scheme = random_colour_scheme(k_colour)
        rgba = self._rgba_with_scheme(
            self._slots, jnp.stack([scheme[BASE], scheme[POLE]]), self.config.multicolor
        )
        return qpos, qvel, {"geom_rgba": rgba}

    def _apply_action(self, data, action, info):
        a = action[0]
        ctrl = jnp.sign(a) if self.config.action_mode == "sign" else jnp.clip(a, -1.0, 1.0)
        return data.replace(ctrl=ctrl[None])

    def _ld_state(self, data, info):
        return jnp.stack([data.qpos[1], data.qvel[1], data.qpos[0], data.qvel[0]])

    def _reward_done(self, prev, data, action, info):
        x, theta = data.qpos[0], data.qpos[1]
        terminated = (jnp.abs(x) > self.config.x_threshold) | (
            jnp.abs(theta) > self.config.theta_threshold
        )
        return jnp.ones(()), terminated, {}
