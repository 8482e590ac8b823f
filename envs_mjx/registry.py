"""The domain registry: `make(name, **overrides)` and `ALL_ENVS` (MuJoCo Playground style)."""

from __future__ import annotations

from envs_mjx.base import Env, EnvConfig, PixelsFn
from envs_mjx.config import ALL_ENVS, configured, default_config
from envs_mjx.domains import (
    ant,
    cartpole,
    half_cheetah,
    incline,
    inverted_pendulum,
    mesh_incline,
    rearrange,
)

# name -> env class; the configs, `ALL_ENVS` and `default_config`: `envs_mjx.config`.
_CLASSES: dict[str, type[Env]] = {
    "CartPole": cartpole.CartPole,
    "InvertedPendulum": inverted_pendulum.InvertedPendulum,
    "HalfCheetah": half_cheetah.HalfCheetah,
    "Ant": ant.Ant,
    "GeomOnIncline": incline.GeomOnIncline,
    "MeshOnIncline": mesh_incline.MeshOnIncline,
    "RearrangeGeom": rearrange.RearrangeGeom,
    "RearrangeYCB": rearrange.RearrangeYCB,
}
assert tuple(_CLASSES) == ALL_ENVS


def make(name: str, pixels_fn: PixelsFn | None = None, **overrides) -> Env:
    """Builds the named env; keyword overrides replace fields of its default config.

    `pixels_fn(data, info) -> uint8 [H, W, 3]` replaces the default pixel source (the
    `envs_mjx.render` renderer when importable). Unknown names or override keys raise ValueError
    (`envs_mjx.config.configured`, which also reads JSON lists as tuples).
    """
    config = configured(name, **overrides)
    return _CLASSES[name](config, pixels_fn=pixels_fn)


def load(name: str, config: EnvConfig | None = None, config_overrides: dict | None = None,
         pixels_fn: PixelsFn | None = None) -> Env:
    """MuJoCo Playground's `registry.load`: the env from `config` (default: `default_config(name)`)
    with `config_overrides` applied."""
    base = default_config(name)
    if config is not None and type(config) is not type(base):
        raise ValueError(f"{name} needs a {type(base).__name__}, got {type(config).__name__}")
    config = configured(name, config, **(config_overrides or {}))
    return _CLASSES[name](config, pixels_fn=pixels_fn)
