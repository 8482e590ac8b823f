"""Gymnasium interface: `to_gymnasium(name, num_envs, seed=0, **overrides)`, and versioned ids.

Importing this module registers every domain as `jaml/NAME-v0` (`GYM_IDS`), single and vector:
`gym.make("jaml/CartPole-v0", seed=0, **overrides)` and `gym.make_vec("jaml/CartPole-v0", 8,
vectorization_mode="vector_entry_point")` build what `to_gymnasium` builds; without importing
envs_mjx.gym first, Gymnasium's module prefix does it: `gym.make("envs_mjx.gym:jaml/CartPole-v0")`.
The version changes when a domain's dynamics, observations or rewards change.

`num_envs=None` gives a `gymnasium.Env` (`MjxGymEnv`), `num_envs=N` a `gymnasium.vector.VectorEnv`
(`MjxVectorEnv`) stepping N envs in one jitted, vmapped call. Observations are the uint8
[S, S, 3] frames (`state.pixels`); with `observation="dict"`, a Dict of those frames ("pixels")
and the true low-dimensional state ("ld_state", float32 [D]), for agents that read both. Actions
are float32 in [-1, 1]; `info["ld_state"]` is the LD state either way (float32 [D] or [N, D]),
named by `info["ld_state_names"]`. `metadata["render_fps"]` is the env's steps per simulated
second (1 / `env.dt`).

PRNG keys are explicit: `reset(seed=s)` sets the key to `jax.random.PRNGKey(s)` (the constructor's
`seed` when the first reset has none); every reset then does `key, sub = jax.random.split(key)` and
resets from `sub` (`env.reset(sub)`, or `env.reset_batch(sub, N)` for the vector env). The vector
env also splits its key on every `step`, and resets the envs that ended on the previous step from
`env.reset_batch(sub, N)` (NEXT_STEP autoreset).

Terminated vs truncated: the envs follow Brax, where `state.done` is set for both and
`state.info["truncation"]` is 1 for a time-limit end; here `truncated = truncation > 0` and
`terminated = done and not truncated`.

Speed on a CPU: the single env makes one small jitted call per step, and XLA:CPU's thread pool
spends more handing that call's work between cores than it saves, so a single env is slower
than PyBullet's (docs/notes/render.md, "One env on one core"); pinning the process to one core
(`taskset -c 0`) helps. The vector env's batched call is what the pool is for.
"""

from __future__ import annotations

import functools
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from envs_mjx.base import Env
from envs_mjx.compile import compiler_options
from envs_mjx.config import ALL_ENVS
from envs_mjx.registry import make

# Registry name -> Gymnasium id (registered at import, `register_envs`).
GYM_IDS: dict[str, str] = {name: f"jaml/{name}-v0" for name in ALL_ENVS}


# What an observation is (`to_gymnasium`'s `observation`): the frames, or a Dict of the frames
# and the LD state.
OBSERVATIONS = ("pixels", "dict")


def to_gymnasium(name: str, num_envs: int | None, seed: int = 0, observation: str = "pixels",
                 **overrides):
    """The named domain (`envs_mjx.make(name, **overrides)`) as a Gymnasium env.

    `num_envs=None`: a single `gymnasium.Env`; an int: a `gymnasium.vector.VectorEnv` of that many
    envs with NEXT_STEP autoreset. `seed` seeds the PRNG key until `reset(seed=...)` replaces it.
    `observation`: "pixels" (the frames) or "dict" (frames and LD state, `OBSERVATIONS`).
    """
    env = make(name, **overrides)
    if num_envs is None:
        return MjxGymEnv(env, seed=seed, observation=observation)
    return MjxVectorEnv(env, num_envs, seed=seed, observation=observation)


def _single(name: str, seed: int = 0, render_mode: str | None = None,
            observation: str = "pixels", **overrides):
    """gym.make's entry point: `to_gymnasium(name, None, seed, observation, **overrides)`."""
    return MjxGymEnv(make(name, **overrides), seed=seed, render_mode=render_mode,
                     observation=observation)


def _vector(name: str, num_envs: int, seed: int = 0, render_mode: str | None = None,
            observation: str = "pixels", **overrides):
    """gym.make_vec's entry point: `to_gymnasium(name, num_envs, seed, observation, ...)`."""
    del render_mode  # the vector env renders no window; frames are its observations
    return MjxVectorEnv(make(name, **overrides), num_envs, seed=seed, observation=observation)


def register_envs() -> None:
    """Registers `GYM_IDS` with Gymnasium (idempotent)."""
    for name, env_id in GYM_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(env_id, entry_point=functools.partial(_single, name),
                               vector_entry_point=functools.partial(_vector, name))


def _spaces(env: Env, observation: str) -> tuple[spaces.Space, spaces.Box]:
    """(observation space, action space) of one env."""
    if observation not in OBSERVATIONS:
        raise ValueError(f"observation must be one of {OBSERVATIONS}, got {observation!r}")
    size = int(env.config.image_size)
    obs = spaces.Box(0, 255, (size, size, 3), np.uint8)
    if observation == "dict":
        ld = spaces.Box(-np.inf, np.inf, (len(env.ld_state_names),), np.float32)
        obs = spaces.Dict({"pixels": obs, "ld_state": ld})
    act = spaces.Box(-1.0, 1.0, (env.action_size,), np.float32)
    return obs, act


def _metadata(env: Env) -> dict[str, Any]:
    """Gymnasium's metadata: frames (rgb_array) at the env's rate, 1 / dt steps a second."""
    return {"render_modes": ["rgb_array"], "render_fps": round(1.0 / env.dt)}


class _Packing:
    """An env state as one flat buffer per dtype, and back (exactly: slices and reshapes).

    A jitted call pays a fixed cost per argument and result buffer, more than a small env's
    step (docs/notes/envs.md). The envs run one call per Gymnasium step, so they pass their
    state packed: four buffers (float32, int32, bool, uint8) instead of 95."""

    def __init__(self, example):
        leaves, self.treedef = jax.tree.flatten(example)
        self.layout = [(np.dtype(x.dtype), tuple(x.shape)) for x in leaves]
        self.dtypes = sorted({d for d, _ in self.layout}, key=str)

    def pack(self, state) -> tuple[jax.Array, ...]:
        leaves = jax.tree.leaves(state)
        return tuple(jnp.concatenate([jnp.ravel(x) for x, (d, _) in zip(leaves, self.layout,
                                                                         strict=True) if d == dt])
                     for dt in self.dtypes)

    def unpack(self, buffers):
        by_dtype = dict(zip(self.dtypes, buffers, strict=True))
        offsets = dict.fromkeys(self.dtypes, 0)
        leaves = []
        for dtype, shape in self.layout:
            size, start = int(np.prod(shape)), offsets[dtype]
            leaves.append(by_dtype[dtype][start:start + size].reshape(shape))
            offsets[dtype] += size
        return jax.tree.unflatten(self.treedef, leaves)


class _Report:
    """What a step reports (frames, LD state, reward, done, truncation) as one uint8 buffer on
    the device, and back on the host: one transfer per step instead of five. The state may be
    batched (leading axes on every field).

    The buffer is the frames' bytes, then per env the float32 LD state, reward, done and
    truncation as bytes (the device's byte order: little-endian, as the host's here)."""

    def __init__(self, example):
        self.frame_shape = tuple(example.pixels.shape)
        self.frame_size = int(np.prod(self.frame_shape))
        self.float_shape = (*example.ld_state.shape[:-1], example.ld_state.shape[-1] + 3)

    @staticmethod
    def encode(state) -> jax.Array:
        scalars = jnp.stack([state.reward, state.done, state.info["truncation"]], -1)
        floats = jnp.concatenate([state.ld_state, scalars], -1).astype(jnp.float32)
        return jnp.concatenate([jnp.ravel(state.pixels),
                                jnp.ravel(jax.lax.bitcast_convert_type(floats, jnp.uint8))])

    def decode(self, buffer) -> tuple[np.ndarray, np.ndarray]:
        """(uint8 frames, float32 [..., D + 3]: LD state, reward, done, truncation) as numpy.

        Plain numpy from here on, no `jax.device_get` (its tree map and host-value machinery)
        and, in the single env, Python scalars for the flags: both cost a small env's step
        noticeably (docs/notes/envs.md)."""
        report = np.asarray(buffer)
        n = self.frame_size
        return (report[:n].reshape(self.frame_shape),
                report[n:].view(np.float32).reshape(self.float_shape))


class _KeyedState:
    """What both env kinds share: the explicit PRNG key, resets from it, the packed state on
    the device and the last report on the host."""

    def _reset_state(self, seed: int | None) -> None:
        if seed is not None:
            self._key = jax.random.PRNGKey(seed)
        self._key, sub = jax.random.split(self._key)
        self._take(*self._reset_fn(sub))

    def _take(self, packed, reported) -> None:
        """Keep the packed state on the device and the report on the host (one transfer)."""
        self._state = packed
        self._frames, self._floats = self._report.decode(reported)

    def _obs_info(self) -> tuple[np.ndarray | dict[str, np.ndarray], dict[str, Any]]:
        ld = self._floats[..., :-3]
        info = {"ld_state": ld, "ld_state_names": self.env.ld_state_names}
        if self._observation == "dict":
            return {"pixels": self._frames, "ld_state": ld.copy()}, info
        return self._frames, info

    def _compile(self, env: Env, reset, step, example) -> None:
        """The jitted reset and step, taking and returning the state packed (`_Packing`), each
        also returning the report (`_Report`) of the state it leaves."""
        packing, self._report = _Packing(example), _Report(example)

        def reset_packed(key):
            state = reset(key)
            return packing.pack(state), self._report.encode(state)

        def step_packed(packed, *args):
            state, *rest = step(packing.unpack(packed), *args)
            return packing.pack(state), self._report.encode(state), *rest

        options = compiler_options(env)
        self._reset_fn = jax.jit(reset_packed, compiler_options=options)
        self._step_fn = jax.jit(step_packed, compiler_options=options)
        self._state = None


class MjxGymEnv(_KeyedState, gymnasium.Env):
    """One MJX env as a `gymnasium.Env`: pixels in, actions in [-1, 1] out.

    Each reset / step is one jitted call that takes and returns the state packed (`_Packing`)
    and returns what the step reports (`_Report`: frame, LD state, reward, done, truncation),
    fetched to the host together."""

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"]}  # noqa: RUF012

    def __init__(self, env: Env, seed: int = 0, render_mode: str | None = None,
                 observation: str = "pixels"):
        self.env = env
        self.observation_space, self.action_space = _spaces(env, observation)
        self._observation = observation
        self.metadata = _metadata(env)
        self.render_mode = render_mode
        self._key = jax.random.PRNGKey(seed)
        self._compile(env, env.reset, lambda state, action: (env.step(state, action),),
                      jax.eval_shape(env.reset, self._key))

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self._reset_state(seed)
        return self._obs_info()

    def step(self, action):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action, np.float32).reshape(self.action_space.shape)
        self._take(*self._step_fn(self._state, action))
        obs, info = self._obs_info()
        reward, done, truncation = self._floats[-3:].tolist()
        truncated = truncation > 0  # Brax's done covers both; truncation says which
        return obs, reward, done > 0 and not truncated, truncated, info

    def render(self):
        return None if self._state is None else self._frames


class MjxVectorEnv(_KeyedState, VectorEnv):
    """N copies of an MJX env in one jitted, vmapped step, with NEXT_STEP autoreset.

    Autoreset (Gymnasium's NEXT_STEP mode): an env that ends (terminated or truncated) on step t
    is reset on step t + 1, whose action it ignores; that step returns its reset observation and
    info with reward 0 and terminated / truncated False. The state travels packed and the
    report comes back in one transfer, as the single env's (`MjxGymEnv`), which pays most for
    few envs (docs/notes/envs.md).
    """

    def __init__(self, env: Env, num_envs: int, seed: int = 0, observation: str = "pixels"):
        self.env = env
        self.num_envs = int(num_envs)
        self.single_observation_space, self.single_action_space = _spaces(env, observation)
        self._observation = observation
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.metadata = {**_metadata(env), "autoreset_mode": AutoresetMode.NEXT_STEP}
        self.render_mode = None
        self._key = jax.random.PRNGKey(seed)
        self._autoreset = np.zeros(self.num_envs, bool)

        n = self.num_envs
        if hasattr(env, "reset_batch"):

            def reset_batch(key):
                return env.reset_batch(key, n)
        else:

            def reset_batch(key):
                return jax.vmap(env.reset)(jax.random.split(key, n))

        def step(state, actions, autoreset, key):
            key, sub = jax.random.split(key)
            stepped = jax.vmap(env.step)(state, actions)

            def merge():
                fresh = reset_batch(sub)

                def pick(f, s):
                    mask = autoreset.reshape((n,) + (1,) * (s.ndim - 1))
                    return jnp.where(mask, f, s)

                return jax.tree.map(pick, fresh, stepped)

            state = jax.lax.cond(jnp.any(autoreset), merge, lambda: stepped)
            return state, key

        self._compile(env, reset_batch, step, jax.eval_shape(reset_batch, self._key))

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self._reset_state(seed)
        self._autoreset = np.zeros(self.num_envs, bool)
        return self._obs_info()

    def step(self, actions):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions, np.float32).reshape(self.action_space.shape)
        packed, reported, self._key = self._step_fn(self._state, actions, self._autoreset,
                                                    self._key)
        self._take(packed, reported)
        obs, info = self._obs_info()
        terminated, truncated = _flags(self._floats)
        self._autoreset = terminated | truncated
        return obs, self._floats[:, -3], terminated, truncated, info


def _flags(floats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(terminated, truncated) bools from a report's floats [..., D + 3]: Brax's done covers
    both ends of an episode, truncation says which."""
    truncated = floats[..., -1] > 0
    return (floats[..., -2] > 0) & ~truncated, truncated


register_envs()
