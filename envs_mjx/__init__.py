"""The evaluation suite's domains: MJCF models stepped in MJX, with LD state and pixels."""

from envs_mjx import brax_compat
from envs_mjx.base import Env, EnvConfig, State
from envs_mjx.compile import compiler_options
from envs_mjx.registry import ALL_ENVS, default_config, load, make

__all__ = [
    "ALL_ENVS",
    "Env",
    "EnvConfig",
    "State",
    "compiler_options",
    "default_config",
    "load",
    "make",
    "to_gymnasium",
]

# Brax's trainers (`ppo.train(environment=envs_mjx.make(...))`) call a function JAX 0.10
# removed: restored where missing, nothing else changed (envs_mjx/brax_compat.py).
brax_compat.install()


def __getattr__(name: str):
    # Gymnasium is imported on first use of `to_gymnasium` only: the domains, the learning loop
    # and the benchmarks do not need it (and a GPU image without it still runs them).
    if name == "to_gymnasium":
        from envs_mjx.gym import to_gymnasium

        return to_gymnasium
    raise AttributeError(f"module 'envs_mjx' has no attribute {name!r}")
