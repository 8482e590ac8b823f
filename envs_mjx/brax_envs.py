"""Brax's registry: importing this module registers every domain as `jaml/NAME` (`BRAX_NAMES`).

`brax.envs.get_environment("jaml/CartPole", pixels="off")` (and Brax's `envs.create`, which
wraps it for training) is `envs_mjx.make("CartPole", pixels="off")`: the keyword arguments are
the domain's config overrides. For Brax's trainers give `pixels="off"`: PPO and SAC read the LD
state (`state.obs`), and frames rendered at every step that nothing reads slow training down.
"""

from __future__ import annotations

import functools

from brax import envs as brax_envs

from envs_mjx.config import ALL_ENVS
from envs_mjx.registry import make

# Registry name -> the name Brax's registry knows it by.
BRAX_NAMES: dict[str, str] = {name: f"jaml/{name}" for name in ALL_ENVS}


def register_brax_envs() -> None:
    """Registers `BRAX_NAMES` with Brax (idempotent): each a factory of config overrides."""
    for name, brax_name in BRAX_NAMES.items():
        brax_envs.register_environment(brax_name, functools.partial(make, name))


register_brax_envs()
