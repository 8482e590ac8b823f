"""The domain registry: `make(name, **overrides)` and `ALL_ENVS` (MuJoCo Playground style)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from envs_mjx.base import Env, EnvConfig, PixelsFn
from envs_mjx.domains import (
    ant,
    cartpole,
    half_cheetah,
    incline,
    inverted_pendulum,
    mesh_incline,
    rearrange,
)

# name -> (env class, default_config)
_REGISTRY: dict[str, tuple[type[Env], Callable[[], EnvConfig]]] = {
    "CartPole": (cartpole.CartPole, cartpole.default_config),
    "InvertedPendulum": (inverted_pendulum.InvertedPendulum, inverted_pendulum.default_config),
    "HalfCheetah": (half_cheetah.HalfCheetah, half_cheetah.default_config),
    "Ant": (ant.Ant, ant.default_config),
    "GeomOnIncline": (incline.GeomOnIncline, incline.default_config),
    "MeshOnIncline": (mesh_incline.MeshOnIncline, mesh_incline.default_config),
    # arm="reacher" (default) | "franka"; version=0..11 or a batch of versions (i mod 4).
    "RearrangeGeom": (rearrange.RearrangeGeom, rearrange.default_config),
    "RearrangeYCB": (rearrange.RearrangeYCB, rearrange.default_config),
}
ALL_ENVS: tuple[str, ...] = tuple(_REGISTRY)


def default_config(name: str) -> EnvConfig:
    """The named domain's default config (reproduces the reference settings)."""
    return _lookup(name)[1]()


def make(name: str, pixels_fn: PixelsFn | None = None, **overrides) -> Env:
    """Builds the named env; keyword overrides replace fields of its default config.

    `pixels_fn(data, info) -> uint8 [H, W, 3]` replaces the default pixel source (the
    `envs_mjx.render` renderer when importable). Unknown names or override keys raise ValueError.
    A list value becomes a tuple (overrides read back from a run's JSON config arrive as lists;
    configs stay hashable and compare equal to the ones they were written from).
    """
    cls, config_fn = _lookup(name)
    config = config_fn()
    valid = {f.name for f in dataclasses.fields(config)}
    unknown = sorted(set(overrides) - valid)
    if unknown:
        raise ValueError(f"{name}: unknown config overrides {unknown}; valid: {sorted(valid)}")
    overrides = {k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()}
    return cls(dataclasses.replace(config, **overrides), pixels_fn=pixels_fn)


def load(name: str, config: EnvConfig | None = None, config_overrides: dict | None = None,
         pixels_fn: PixelsFn | None = None) -> Env:
    """MuJoCo Playground's `registry.load`: the env from `config` (default: `default_config(name)`)
    with `config_overrides` applied."""
    config = default_config(name) if config is None else config
    base = default_config(name)
    if type(config) is not type(base):
        raise ValueError(f"{name} needs a {type(base).__name__}, got {type(config).__name__}")
    changed = {f.name: getattr(config, f.name) for f in dataclasses.fields(config)
               if getattr(config, f.name) != getattr(base, f.name)}
    return make(name, pixels_fn=pixels_fn, **changed, **(config_overrides or {}))


def _lookup(name: str):
    try:
        return _REGISTRY[name]
    except KeyError:
        raise ValueError(f"unknown env {name!r}; valid names: {list(ALL_ENVS)}") from None
