"""InvertedPendulum (docs/reference/suite.md §2): balance a capsule pole on a cart.

Action a in [-1, 1]: force 100 N * clip(a). LD state: [x, x_dot, cos theta, sin theta,
theta_dot]. Done when |theta| > 0.2 rad; reward 1 per step (times reward_scale). Reset:
theta ~U(+-0.1), everything else 0. Multicolor: cart = base colour, pole = pole colour.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco

from envs_mjx.base import BASE, POLE, Env, geom_ids, random_colour_scheme
from envs_mjx.config import InvertedPendulumConfig
from envs_mjx.domains._assets import asset


def default_config() -> InvertedPendulumConfig:
    return InvertedPendulumConfig()


class InvertedPendulum(Env):
    """Cart + capsule pole at density 1000 (about 15.5 kg), 100 N slider motor."""

    def __init__(self, config: InvertedPendulumConfig | None = None, pixels_fn=None):
        config = config or default_config()
        mj_model = mujoco.MjModel.from_xml_path(asset("inverted_pendulum.xml"))
        self._slots = [geom_ids(mj_model, ["cart"]), geom_ids(mj_model, ["pole"])]
        names = ("x", "x_dot", "cos_theta", "sin_theta", "theta_dot")
        super().__init__(config, mj_model, names, pixels_fn)

    def _ld_groups(self):
        return ("position", "velocity", "position", "position", "velocity")

    def _sample_reset(self, rng):
        k_theta, k_colour = jax.random.split(rng)
        noise = self.config.reset_noise
        theta = jax.random.uniform(k_theta, (), minval=-noise, maxval=noise)
        qpos = jnp.stack([jnp.zeros(()), theta])
        scheme = random_colour_scheme(k_colour)
        rgba = self._rgba_with_scheme(
            self._slots, jnp.stack([scheme[BASE], scheme[POLE]]), self.config.multicolor
        )
        return qpos, jnp.zeros(2), {"geom_rgba": rgba}

    def _ld_state(self, data, info):
        x, theta = data.qpos[0], data.qpos[1]
        return jnp.stack([x, data.qvel[0], jnp.cos(theta), jnp.sin(theta), data.qvel[1]])

    def _reward_done(self, prev, data, action, info):
        return jnp.ones(()), jnp.abs(data.qpos[1]) > self.config.theta_threshold, {}
