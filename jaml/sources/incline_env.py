"""AML rows from the MJX incline domains (paper §5): θ, position and velocity at two env steps.

A row is τ = (theta, s0, v0, a0, s1, v1): the incline angle, the object's position and velocity
along the plank at env step t, the action applied over the step, and position and velocity at
step t + 1 (one env step = n_frames × 5 ms = 0.04 s by default). Units are the domain's LD state
(`envs_mjx.domains.incline`; with normalize_ld, the default):
  theta: (θ − lo) / (hi − lo) over the config's theta_range, in [0, 1];
  s0, s1: position / POSITION_SCALE (1.27 m), clipped to [0, 1];
  v0, v1: velocity / VELOCITY_SCALE (3.1 m/s), clipped to [−1, 1];
  a0: the action in [−1, 1], a force of force_scale · a0 N (2 N) along the downhill direction.
With normalize_ld=False they are rad, m, m/s and the action.

Rows come from batches of envs that reset and step under uniform random actions, as the stream's
rollouts do (`jaml.stream.collect`): an env whose episode ends (terminated or truncated) is
swapped for a fresh reset, and the step that ended it gives no row (its next state belongs to
no continuing episode, as the replay never records an episode's final frame). Unlike `collect`,
a fresh reset is drawn every step rather than once per rollout, so an env that ends several
episodes in one rollout does not repeat its angle, mass and friction. Rows are drawn at random
from the valid steps of `rollout_steps` steps of ⌈n / (rollout_steps · MIN_VALID_FRACTION)⌉
envs; shapes never depend on the data.

An MJX rollout per training batch would be far too slow, so these sources set `pool_size`:
`relations.fit` draws that many rows once and trains on them as on user rows.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp

import envs_mjx
from envs_mjx.base import Env, State

DIM_NAMES = ("theta", "s0", "v0", "a0", "s1", "v1")
# Fraction of env steps assumed to give a row (the rest end an episode). Measured ≈ 0.93 for
# both domains under uniform actions in [−1, 1]; 0.75 leaves room for slower-ending settings.
MIN_VALID_FRACTION = 0.75
# The source's own options; every other keyword of `make` is an env config override.
SOURCE_OPTIONS = ("action_range", "rollout_steps", "pool_size", "drop_clipped", "units", "name")
# "env": the domain's normalised LD units (module docstring). "reference": the released code's
# source rows (docs/reference/fig9.md §4): position as the distance travelled from where the episode
# began (its object is dropped there; ours starts at rest on the plank) ÷ 1.27 m, velocity as
# the unsigned speed ÷ 3.1 m/s, the action as the force in N (±2).
UNITS = ("env", "reference")


class InclineEnvSource:
    """A `jaml.sources.Source` of (θ, s0, v0, a0, s1, v1) rows from an MJX incline domain.

    Args:
      env_name: "GeomOnIncline" or "MeshOnIncline" (any env whose LD state names theta,
        position and velocity, with one action).
      action_range: (lo, hi) of the uniform random action; (0, 0) for zero actions.
      rollout_steps: env steps per rollout; rows come from every step of a rollout.
      pool_size: rows `relations.fit` draws once and trains on (None: a rollout per batch).
      drop_clipped: with normalize_ld, also drop rows in which a position or velocity sits at
        its clip bound (the LD state stops following the dynamics there; ≈ 2% of rows).
      units: "env" (default) or "reference" (`UNITS`).
      name: the source's name.
      **env_overrides: fields of the env's config (`envs_mjx.make`); pixels default to "off".
    """

    def __init__(
        self,
        env_name: str,
        *,
        action_range: tuple[float, float] = (-1.0, 1.0),
        rollout_steps: int = 64,
        pool_size: int | None = 131_072,
        drop_clipped: bool = True,
        units: str = "env",
        name: str | None = None,
        **env_overrides: Any,
    ):
        lo, hi = action_range
        if not -1.0 <= lo <= hi <= 1.0:
            raise ValueError(f"action_range must satisfy -1 ≤ lo ≤ hi ≤ 1, got {action_range}")
        if rollout_steps < 1:
            raise ValueError(f"rollout_steps must be ≥ 1, got {rollout_steps}")
        if pool_size is not None and pool_size < 2:
            raise ValueError(f"pool_size must be None or ≥ 2, got {pool_size}")
        if units not in UNITS:
            raise ValueError(f"units must be one of {UNITS}, got {units!r}")
        # A 1 × 1 placeholder image: states carry no 64 × 64 zeros through the rollout.
        env_overrides = {"pixels": "off", "image_size": 1, **env_overrides}
        self.env: Env = envs_mjx.make(env_name, **env_overrides)
        if self.env.action_size != 1:
            raise ValueError(f"{env_name} has {self.env.action_size} actions; expected 1")
        names = self.env.ld_state_names
        missing = [q for q in ("theta", "position", "velocity") if q not in names]
        if missing:
            raise ValueError(f"{env_name}'s LD state {names} lacks {missing}")
        self._columns = tuple(names.index(q) for q in ("theta", "position", "velocity"))
        self.env_name = env_name
        self.env_overrides = env_overrides
        self.action_range = (float(lo), float(hi))
        self.rollout_steps = int(rollout_steps)
        self.pool_size = pool_size
        normalised = bool(getattr(self.env.config, "normalize_ld", False))
        self.drop_clipped = bool(drop_clipped) and normalised
        self.units = units
        self.name = name or env_name
        self.sample = jax.jit(self._sample, static_argnums=1)

    @property
    def dim_names(self) -> tuple[str, ...]:
        return DIM_NAMES

    @property
    def dt(self) -> float:
        """Seconds of simulated time between the two states of a row."""
        return self.env.dt

    def num_envs(self, n: int) -> int:
        """Envs stepped to draw n rows."""
        return max(1, math.ceil(n / (self.rollout_steps * MIN_VALID_FRACTION)))

    def rollout(self, key: jax.Array, num_envs: int) -> tuple[jax.Array, jax.Array]:
        """Rows [T, E, 6] of every step of `num_envs` envs and whether each is valid [T, E]."""
        env = self.env
        lo, hi = self.action_range
        theta, pos, vel = self._columns
        k_reset, k_steps = jax.random.split(key)
        reset = jax.vmap(env.reset)
        step = jax.vmap(env.step)

        def body(carry, key):
            state, origin = carry
            k_action, k_fresh = jax.random.split(key)
            action = jax.random.uniform(k_action, (num_envs, 1), minval=lo, maxval=hi)
            nstate = step(state, action)
            before, after = state.ld_state, nstate.ld_state
            row = jnp.stack(
                [
                    before[:, theta],
                    before[:, pos],
                    before[:, vel],
                    action[:, 0],
                    after[:, pos],
                    after[:, vel],
                ],
                axis=-1,
            )
            keep = nstate.done == 0
            if self.drop_clipped:
                keep &= ~_clipped(row)
            if self.units == "reference":
                row = to_reference_units(row, origin, self.env.config.force_scale)
            done = nstate.done > 0
            fresh = reset(jax.random.split(k_fresh, num_envs))
            origin = jnp.where(done, fresh.ld_state[:, pos], origin)
            return (_swap_in(done, fresh, nstate), origin), (row, keep)

        state = reset(jax.random.split(k_reset, num_envs))
        _, (rows, valid) = jax.lax.scan(body, (state, state.ld_state[:, pos]),
                                        jax.random.split(k_steps, self.rollout_steps))
        return rows, valid

    def _sample(self, key: jax.Array, n: int) -> jax.Array:
        k_roll, k_pick = jax.random.split(key)
        rows, valid = self.rollout(k_roll, self.num_envs(n))
        return pick_valid(k_pick, rows.reshape(-1, rows.shape[-1]), valid.reshape(-1), n)

    def __repr__(self) -> str:
        options = ", ".join(f"{k}={v!r}" for k, v in self.env_overrides.items())
        return (
            f"InclineEnvSource({self.env_name!r}, action_range={self.action_range}, "
            f"rollout_steps={self.rollout_steps}, pool_size={self.pool_size}, "
            f"units={self.units!r}, {options})"
        )


def pick_valid(key: jax.Array, rows: jax.Array, valid: jax.Array, n: int) -> jax.Array:
    """n of the valid rows [N, D], in random order, without a data-dependent shape.

    Valid rows are ranked by random keys; should fewer than n be valid, the shortfall repeats
    valid rows (never an invalid one). With no valid row at all the result is NaN.
    """
    scores = jax.random.uniform(key, valid.shape) + jnp.where(valid, 0.0, 2.0)
    order = jnp.argsort(scores)
    count = jnp.sum(valid)
    i = jnp.arange(n)
    picked = rows[order[jnp.where(i < count, i, i % jnp.maximum(count, 1))]]
    return jnp.where(count > 0, picked, jnp.nan)


def to_reference_units(row: jax.Array, origin: jax.Array, force_scale: float) -> jax.Array:
    """[E, 6] rows (θ, s0, v0, a0, s1, v1) in normalised units → the released code's: distance
    from the episode's start position `origin` [E], unsigned speed, the force in N."""
    theta, s0, v0, a0, s1, v1 = (row[:, i] for i in range(6))
    return jnp.stack([theta, jnp.abs(s0 - origin), jnp.abs(v0), force_scale * a0,
                      jnp.abs(s1 - origin), jnp.abs(v1)], axis=-1)


def _clipped(row: jax.Array) -> jax.Array:
    """[E] whether a normalised position (clip [0, 1]) or velocity (clip [−1, 1]) is at a bound."""
    s, v = row[:, jnp.array([1, 4])], row[:, jnp.array([2, 5])]
    return jnp.any((s <= 0.0) | (s >= 1.0), axis=1) | jnp.any(jnp.abs(v) >= 1.0, axis=1)


def _swap_in(done: jax.Array, fresh: State, state: State) -> State:
    def pick(a, b):
        return jnp.where(done.reshape(done.shape + (1,) * (a.ndim - 1)), a, b)

    return jax.tree.map(pick, fresh, state)


ENV_SOURCES = {"geom-on-incline": "GeomOnIncline", "mesh-on-incline": "MeshOnIncline"}


def make(name: str, **options: Any) -> InclineEnvSource:
    """The source `name` in ENV_SOURCES; options are SOURCE_OPTIONS or env config overrides."""
    if name not in ENV_SOURCES:
        raise ValueError(f"unknown incline env source {name!r}; valid: {sorted(ENV_SOURCES)}")
    return InclineEnvSource(ENV_SOURCES[name], **{"name": name, **options})
