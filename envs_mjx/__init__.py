"""The evaluation suite's domains: MJCF models stepped in MJX, with LD state and pixels."""

from envs_mjx.base import Env, EnvConfig, State
from envs_mjx.gym import to_gymnasium
from envs_mjx.registry import ALL_ENVS, default_config, make

__all__ = ["ALL_ENVS", "Env", "EnvConfig", "State", "default_config", "make", "to_gymnasium"]
