"""The evaluation suite's domains: MJCF models stepped in MJX, with LD state and pixels."""

import importlib

from envs_mjx import _quiet
from envs_mjx.config import ALL_ENVS, EnvConfig, default_config

_quiet.install()  # mujoco.mjx's MuJoCo Warp probe off stdout, however MJX is first imported

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

# The rest, imported from their modules on first use (PEP 562). `envs_mjx.config` is jaml's
# (and the command line's) way to the env names and configs, and importing it imports this
# package: a plain import of the domains here would put JAX and MuJoCo under every `--help`.
# Gymnasium is imported on first use of `to_gymnasium` only: the domains, the learning loop and
# the benchmarks do not need it (and a GPU image without it still runs them).
_EXPORTS = {
    "Env": "base",
    "State": "base",
    "compiler_options": "compile",
    "load": "registry",
    "make": "registry",
    "to_gymnasium": "gym",
}


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'envs_mjx' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"envs_mjx.{_EXPORTS[name]}"), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))
