"""The domain registry: `make(name, **overrides)` and `load` (MuJoCo Playground style) over
`envs_mjx.config.ENVS`, the table of names, configs and env classes."""

from __future__ import annotations

import pkgutil

from envs_mjx.base import Env, EnvConfig, PixelsFn
from envs_mjx.config import configured, registered


def make(name: str, pixels_fn: PixelsFn | None = None, **overrides) -> Env:
    """Builds the named env; keyword overrides replace fields of its default config.

    `pixels_fn(data, info) -> uint8 [H, W, 3]` replaces the default pixel source (the
    `envs_mjx.render` renderer when importable). Unknown names or override keys raise ValueError
    (`envs_mjx.config.configured`, which also reads JSON lists as tuples).
    """
    return load(name, config_overrides=overrides, pixels_fn=pixels_fn)


def load(name: str, config: EnvConfig | None = None, config_overrides: dict | None = None,
         pixels_fn: PixelsFn | None = None) -> Env:
    """MuJoCo Playground's `registry.load`: the env from `config` (default: `default_config(name)`;
    else of the name's config class) with `config_overrides` applied."""
    config = configured(name, config, **(config_overrides or {}))
    return pkgutil.resolve_name(registered(name)[1])(config, pixels_fn=pixels_fn)
