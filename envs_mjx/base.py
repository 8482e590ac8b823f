"""State and Env: pure, jittable, vmappable reset/step over MJX physics with LD state and pixels.

The interface is Brax's (`brax.envs.base.Env` / `State`), so Brax's training wrappers and acting
code drive these envs unchanged. Per-env randomization (colours, incline angle, mass, friction)
lives in `state.info` as arrays; `Env.physics_model(info)` turns it into batched `mjx.Model`
fields, and the pixels function receives `info` to read per-env appearance.

Per-env appearance field (read by pixel functions): `info["geom_rgba"]`, float32 [ngeom, 4], the
RGBA of every geom for this episode (the colour scheme drawn at reset). Appearance beyond colours
(MeshOnIncline's textures and object mesh) goes into the render context per env through
`Env._render_context`. `Env.reset_batch` resets a batch of env slots; a domain may give each slot
a fixed property (MeshOnIncline: object i mod N).

Non-finite actions: inside jit, a step whose action has any NaN/Inf is skipped entirely. The
returned state equals the input state (same physics, LD state, pixels, done, info), except that
`reward` is 0 and `metrics["nonfinite_action"]` is 1. This mirrors the paper-era suite, where a NaN
action returned the current observation without stepping, and loses no state.

Diverged physics: a step whose new qpos or qvel holds a NaN/Inf keeps the input state too, with
`reward` 0, `done` 1 and `info["truncation"]` 1 (the episode ends; auto-reset starts a fresh one),
and `metrics["nonfinite_physics"]` 1, so a solver blow-up in one env never reaches a learner.
"""

from __future__ import annotations

import copy
import importlib.util
import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.envs import base as brax_base
from flax import struct
from mujoco import mjx

from envs_mjx import brax_compat
from envs_mjx.config import EnvConfig

# Brax's trainers (`ppo.train(environment=envs_mjx.make(...))`) call a function JAX 0.10
# removed: restored where missing, nothing else changed (envs_mjx/brax_compat.py). Every env
# imports this module.
brax_compat.install()

PixelsFn = Callable[[mjx.Data, dict[str, Any]], jax.Array]


@struct.dataclass
class State(brax_base.State):
    """Brax's State plus the suite's outputs.

    pixels: uint8 [H, W, 3], the camera image after this step (zeros when no renderer is
      plugged in; then `info["pixels_valid"]` is False).
    ld_state: float32 [D], the true low-dimensional state, named by `Env.ld_state_names`.
    info["truncation"]: 1.0 when the episode ended by time limit rather than termination.
    """

    pixels: jax.Array | None = None
    ld_state: jax.Array | None = None


class PixelsUnavailableWarning(UserWarning):
    """Pixels were asked for but no renderer is installed: states carry zero images."""


# `mjx.step` behind one jit: every env program (reset's settle steps, each step's substeps, the
# stream's epoch loop, the analysis rollouts) calls the same traced and batched jaxpr, which JAX
# caches per input shapes, instead of re-tracing MJX's Python at each call site and
# re-batching it under every vmap level around a loop. XLA inlines the call, so the compiled
# program is unchanged; tracing and lowering take far less time (docs/notes/envs.md).
physics_step = jax.jit(mjx.step)


def renderer_available() -> bool:
    """Whether the JAX software renderer `envs_mjx.render` can be imported."""
    return importlib.util.find_spec("envs_mjx.render") is not None


def placeholder_pixels_fn(size: int) -> PixelsFn:
    """A pixels function that returns zeros: a marked stand-in, never a rendering."""

    def pixels_fn(data: mjx.Data, info: dict[str, Any]) -> jax.Array:
        del data, info
        return jnp.zeros((size, size, 3), jnp.uint8)

    pixels_fn.is_placeholder = True  # type: ignore[attr-defined]
    return pixels_fn


def renderer_pixels_fn(
    mj_model: mujoco.MjModel, camera: str, size: int, customise: Callable | None = None
) -> PixelsFn:
    """Pixels from `envs_mjx.render`: one context built here, `render(ctx, data).rgb` per call.

    The context's per-geom colour (`geom_rgb` [ngeom, 3] in the jaml renderer, or a `geom_rgba`
    field) is replaced by `info["geom_rgba"]` each call, so the episode's colours reach the image;
    then `customise(ctx, info) -> ctx`, when given, sets the rest of the episode's appearance
    (e.g. which texture a geom shows).
    """
    from envs_mjx import render  # local: the renderer is an optional, separately built module

    ctx = render.make_context(mj_model, camera, size, size)
    field = next((f for f in ("geom_rgb", "geom_rgba") if hasattr(ctx, f)), None)
    if field is None or not hasattr(ctx, "replace"):
        warnings.warn(
            "render context has no geom_rgb(a) field: per-episode colour schemes are not drawn",
            stacklevel=2,
        )

    def pixels_fn(data: mjx.Data, info: dict[str, Any]) -> jax.Array:
        c = ctx
        if field == "geom_rgb":
            c = ctx.replace(geom_rgb=info["geom_rgba"][:, :3])
        elif field == "geom_rgba":
            c = ctx.replace(geom_rgba=info["geom_rgba"])
        if customise is not None:
            c = customise(c, info)
        return render.render(c, data).rgb

    # Jitted for the trace cache, as `physics_step`: a reset and a step draw with one trace
    # (docs/notes/envs.md).
    return jax.jit(pixels_fn)


def contact_flags(data: mjx.Data, floor_geom: int, geoms: np.ndarray) -> jax.Array:
    """float32 [len(geoms)]: 1 where geom i touches (distance <= 0) the floor geom."""
    contact = data._impl.contact
    g = contact.geom  # [ncon, 2]
    touching = contact.dist <= 0.0
    geoms = jnp.asarray(geoms)[:, None]
    pair = ((g[None, :, 0] == floor_geom) & (g[None, :, 1] == geoms)) | (
        (g[None, :, 1] == floor_geom) & (g[None, :, 0] == geoms)
    )
    return jnp.any(pair & touching[None], axis=1).astype(jnp.float32)


# "orientation": rotation-matrix entries (Rearrange's objects), scored by the reference's
# rotation error (docs/reference/suite.md §5), not by L1 like positions.
LD_GROUPS = ("position", "velocity", "contact", "orientation", "other")


def drawn_rgba(mj_model: mujoco.MjModel) -> np.ndarray:
    """float32 [ngeom, 4]: each geom's colour as drawn, its material's where it has one
    (MuJoCo's rule)."""
    rgba = np.array(mj_model.geom_rgba, np.float32)
    has_mat = np.asarray(mj_model.geom_matid) >= 0
    rgba[has_mat] = mj_model.mat_rgba[mj_model.geom_matid[has_mat]]
    return rgba


class Env(brax_base.Env):
    """A domain: MJCF model, n_frames substeps per action, LD state, reward and termination.

    Subclasses implement `_sample_reset`, `_ld_state` and `_reward_done`, and may override
    `_model_fields` (per-env physics fields) and `_apply_action` (action -> ctrl / forces).
    """

    camera: str = "pixels"
    reset_contacts: bool = False  # whether reset must run collision detection (contact LD entries)

    def __init__(
        self,
        config: EnvConfig,
        mj_model: mujoco.MjModel,
        ld_state_names: tuple[str, ...],
        pixels_fn: PixelsFn | None = None,
    ):
        self.config = config
        self.mj_model = mj_model
        # On this process's first device: MJX's default, `jax.devices()[0]`, belongs to process 0
        # when several processes share a mesh (`jax.distributed`).
        device = jax.local_devices()[0]
        self.mjx_model = mjx.put_model(mj_model, device=device)
        self._data0 = mjx.make_data(self.mjx_model, device=device)
        self._ld_state_names = tuple(ld_state_names)
        self._base_rgba = drawn_rgba(mj_model)
        self.pixels_fn, self.pixels_valid = self._build_pixels_fn(pixels_fn)

    # -- Brax interface -------------------------------------------------------------------------

    @property
    def observation_size(self) -> int:
        return len(self._ld_state_names)

    @property
    def action_size(self) -> int:
        return int(self.mj_model.nu)

    @property
    def backend(self) -> str:
        return "mjx"

    @property
    def dt(self) -> float:
        """Seconds of simulated time per env step."""
        return float(self.mj_model.opt.timestep) * self.n_frames

    @property
    def n_frames(self) -> int:
        return int(self.config.n_frames)

    @property
    def ld_state_names(self) -> tuple[str, ...]:
        return self._ld_state_names

    @property
    def ld_state_groups(self) -> tuple[str, ...]:
        """Per LD dimension, one of LD_GROUPS: what the paper aggregates alignment over
        (position, velocity and contacts for locomotion, Fig. 2); "other" for scene parameters
        such as a texture id."""
        groups = tuple(self._ld_groups())
        if len(groups) != len(self._ld_state_names) or not set(groups) <= set(LD_GROUPS):
            raise ValueError(f"{type(self).__name__}: ld_state_groups must give one of "
                             f"{LD_GROUPS} per LD dimension, got {groups}")
        return groups

    def _ld_groups(self) -> tuple[str, ...]:
        raise NotImplementedError(f"{type(self).__name__} declares no LD-state groups")

    def reset(self, rng: jax.Array) -> State:
        """Samples an initial state (and the episode's randomized model fields) from `rng`."""
        return self._reset_from(*self._sample_reset(rng))

    def reset_batch(self, rng: jax.Array, num_envs: int) -> State:
        """`num_envs` resets with a leading batch axis: env slot i of a batch.

        `vmap(reset)` over split keys by default; a domain whose env slots keep a property
        across their resets (MeshOnIncline's object, i mod N) overrides it. Rollouts draw their
        fresh reset states through this (`jaml.stream.collect.reset`)."""
        return jax.vmap(self.reset)(jax.random.split(rng, num_envs))

    def _reset_from(self, qpos: jax.Array, qvel: jax.Array, info: dict[str, Any]) -> State:
        """The initial State from `_sample_reset`'s (qpos, qvel, info)."""
        info = {**info, "t": jnp.zeros((), jnp.int32), "truncation": jnp.zeros(())}
        info["pixels_valid"] = jnp.asarray(self.pixels_valid)
        model = self.physics_model(info)
        data = self._initial_data(model, qpos, qvel)
        data, info = self._settle(model, data, info)
        info = self._after_reset(data, info)
        ld = self._ld_state(data, info)
        _, _, metrics = self._reward_done(data, data, jnp.zeros(self.action_size), info)
        metrics = {**jax.tree.map(jnp.zeros_like, metrics), "nonfinite_action": jnp.zeros(()),
                   "nonfinite_physics": jnp.zeros(())}
        return State(
            pipeline_state=data,
            obs=ld,
            reward=jnp.zeros(()),
            done=jnp.zeros(()),
            metrics=metrics,
            info=info,
            pixels=self.pixels_fn(data, info),
            ld_state=ld,
        )

    def step(self, state: State, action: jax.Array) -> State:
        """Applies `action` (float [action_size], in [-1, 1]) for n_frames physics substeps."""
        action = self._check_action(action)
        finite = jnp.all(jnp.isfinite(action))
        action = jnp.where(finite, action, 0.0)
        info = dict(state.info)
        model = self.physics_model(info)
        prev = state.pipeline_state
        data = self._advance(model, prev, action, info)
        ld = self._ld_state(data, info)
        reward, terminated, metrics = self._reward_done(prev, data, action, info)
        t = info["t"] + 1
        truncated = (
            jnp.zeros((), bool)
            if self.config.episode_length is None
            else t >= self.config.episode_length
        )
        info["t"] = t
        info["truncation"] = (truncated & ~terminated).astype(jnp.float32)
        new = State(
            pipeline_state=data,
            obs=ld,
            reward=jnp.asarray(reward * self.config.reward_multiplier, jnp.float32),
            done=(terminated | truncated).astype(jnp.float32),
            # Entries a wrapper added (Brax's EvalWrapper keeps "reward" there) pass through,
            # as Brax's own envs' `state.metrics.update(...)` keeps them.
            metrics={**state.metrics, **metrics, "nonfinite_action": jnp.zeros(()),
                     "nonfinite_physics": jnp.zeros(())},
            info=info,
            pixels=self.pixels_fn(data, info),
            ld_state=ld,
        )
        # Physics that diverged (a NaN or inf in qpos / qvel) must not reach a learner (one NaN
        # observation poisons PPO's running normaliser, and with it every env's policy): the
        # env keeps its previous, finite state and the episode ends as truncated (not a task
        # termination, so a value bootstrap reads that finite state); auto-reset replaces it.
        # A non-finite action keeps the previous state too, without ending the episode.
        diverged = finite & ~(jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel)))
        stepped = finite & ~diverged
        new = jax.tree.map(lambda n, o: jnp.where(stepped, n, o), new, state)
        return new.replace(
            reward=jnp.where(stepped, new.reward, 0.0),
            done=jnp.where(diverged, 1.0, new.done),
            info={**new.info, "truncation": jnp.where(diverged, 1.0, new.info["truncation"])},
            metrics={**new.metrics, "nonfinite_action": 1.0 - finite.astype(jnp.float32),
                     "nonfinite_physics": diverged.astype(jnp.float32)},
        )

    # -- per-env model ----------------------------------------------------------------------------

    def physics_model(self, info: dict[str, Any]) -> mjx.Model:
        """The mjx.Model for one env: the shared model with this episode's fields swapped in."""
        fields = self._model_fields(info)
        return self.mjx_model.replace(**fields) if fields else self.mjx_model

    def mj_model_for(self, info: dict[str, Any]) -> mujoco.MjModel:
        """A C MjModel copy carrying one env's randomized fields (for C MuJoCo / checks)."""
        m = copy.deepcopy(self.mj_model)
        for name, value in self._model_fields(info).items():
            getattr(m, name)[...] = np.asarray(value)
        return m

    # -- hooks ------------------------------------------------------------------------------------

    def _initial_data(self, model: mjx.Model, qpos: jax.Array, qvel: jax.Array) -> mjx.Data:
        """Data at (qpos, qvel) with what the LD state and pixels read: body / geom / camera poses,
        and contacts when `reset_contacts` is set. Not a full mjx.forward: the next mjx.step
        recomputes everything from qpos / qvel, and skipping the constraint solve here roughly
        halves the compile time of `reset`."""
        data = self._data0.replace(qpos=qpos, qvel=qvel)
        data = mjx.kinematics(model, data)
        data = mjx.com_pos(model, data)
        data = mjx.camlight(model, data)
        if self.reset_contacts:
            data = mjx.collision(model, data)
        return data

    def _settle(
        self, model: mjx.Model, data: mjx.Data, info: dict[str, Any]
    ) -> tuple[mjx.Data, dict[str, Any]]:
        """Physics a reset runs before its first state (Rearrange's settle and random-torque
        steps); may take reset-only entries out of info. Default: none."""
        return data, info

    def _advance(
        self, model: mjx.Model, data: mjx.Data, action: jax.Array, info: dict[str, Any]
    ) -> mjx.Data:
        """One env step's physics: `_apply_action`, then n_frames mjx.step substeps."""
        data = self._apply_action(data, action, info)
        return jax.lax.fori_loop(0, self.n_frames, lambda _, d: physics_step(model, d), data)

    def _sample_reset(self, rng: jax.Array) -> tuple[jax.Array, jax.Array, dict[str, Any]]:
        """Returns (qpos, qvel, info); info must hold "geom_rgba" [ngeom, 4]."""
        raise NotImplementedError

    def _after_reset(self, data: mjx.Data, info: dict[str, Any]) -> dict[str, Any]:
        """Records quantities of the initial state in info (e.g. the initial height)."""
        del data
        return info

    def _render_context(self, ctx: Any, info: dict[str, Any]) -> Any:
        """The render context for one env's frame, after `info["geom_rgba"]` is applied (see
        `renderer_pixels_fn`). Default: unchanged."""
        del info
        return ctx

    def _model_fields(self, info: dict[str, Any]) -> dict[str, jax.Array]:
        """Per-env physics fields of mjx.Model (name -> value) derived from info."""
        del info
        return {}

    def _apply_action(self, data: mjx.Data, action: jax.Array, info: dict[str, Any]) -> mjx.Data:
        """Default: motors with ctrlrange [-1, 1] take the clipped action as ctrl."""
        del info
        return data.replace(ctrl=jnp.clip(action, -1.0, 1.0))

    def _ld_state(self, data: mjx.Data, info: dict[str, Any]) -> jax.Array:
        raise NotImplementedError

    def _reward_done(
        self, prev: mjx.Data, data: mjx.Data, action: jax.Array, info: dict[str, Any]
    ) -> tuple[jax.Array, jax.Array, dict[str, jax.Array]]:
        """Returns (unscaled reward, terminated bool, metrics)."""
        raise NotImplementedError

    # -- helpers ----------------------------------------------------------------------------------

    def _check_action(self, action: jax.Array) -> jax.Array:
        """Shape and dtype are static under jit/vmap, so bad ones fail here, at trace time."""
        shape = getattr(action, "shape", None)
        if shape != (self.action_size,):
            hint = " (batched? wrap the env in jax.vmap)" if shape and len(shape) > 1 else ""
            raise ValueError(
                f"{type(self).__name__}.step: action must have shape ({self.action_size},), "
                f"got {shape}{hint}"
            )
        if not jnp.issubdtype(action.dtype, jnp.floating):
            raise TypeError(
                f"{type(self).__name__}.step: action must be floating point, got {action.dtype}"
            )
        return jnp.asarray(action, jnp.float32)

    def _build_pixels_fn(self, pixels_fn: PixelsFn | None) -> tuple[PixelsFn, bool]:
        mode = self.config.pixels
        size = self.config.image_size
        if mode not in ("auto", "required", "off"):
            raise ValueError(f"pixels must be 'auto', 'required' or 'off', got {mode!r}")
        if pixels_fn is not None:
            return pixels_fn, True
        if mode == "off":
            return placeholder_pixels_fn(size), False
        if renderer_available():
            return renderer_pixels_fn(self.mj_model, self.camera, size, self._render_context), True
        if mode == "required":
            raise ImportError(
                f"{type(self).__name__}: pixels='required' but envs_mjx.render is not installed"
            )
        warnings.warn(
            f"{type(self).__name__}: envs_mjx.render is not importable; states carry ZERO "
            "images (info['pixels_valid'] is False). Pass pixels='off' to silence this, or "
            "pixels_fn=... to plug in a renderer.",
            PixelsUnavailableWarning,
            stacklevel=3,
        )
        return placeholder_pixels_fn(size), False

    def _rgba_with_scheme(
        self, slots: list[np.ndarray], colours: jax.Array, enabled: bool
    ) -> jax.Array:
        """geom_rgba with the geoms of slot i painted colours[i] (RGB), when enabled."""
        rgba = jnp.asarray(self._base_rgba)
        if not enabled:
            return rgba
        for geoms, rgb in zip(slots, colours, strict=True):
            rgba = rgba.at[geoms, :3].set(jnp.broadcast_to(rgb, (len(geoms), 3)))
        return rgba


# The suite's colour schemes (docs/reference/suite.md §1: four): rows are schemes, columns are the
# slots (base, pole, pole2, pole3), RGB in [0, 1].
COLOUR_SCHEMES = np.array(
    [
        [[1, 1, 0], [0, 0, 1], [1, 0, 0], [0.8, 0.8, 0.8]],
        [[0, 1, 1], [0, 0, 0], [0, 0, 1], [0.7, 0, 0.7]],
        [[1, 0, 1], [0, 1, 0], [1, 1, 0], [0.7, 0, 0]],
        [[0, 0, 1], [1, 0, 0], [0, 0, 0], [0, 0.8, 0.8]],
    ],
    np.float32,
)
BASE, POLE, POLE2, POLE3 = range(COLOUR_SCHEMES.shape[1])


def random_colour_scheme(key: jax.Array) -> jax.Array:
    """One of COLOUR_SCHEMES, uniformly: [slots, 3] RGB (the multicolor domains' reset)."""
    return jnp.asarray(COLOUR_SCHEMES)[jax.random.randint(key, (), 0, len(COLOUR_SCHEMES))]


def geom_ids(mj_model: mujoco.MjModel, names: list[str]) -> np.ndarray:
    """Geom ids by name; raises KeyError naming a missing geom."""
    ids = [mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in names]
    missing = [n for n, i in zip(names, ids, strict=True) if i < 0]
    if missing:
        raise KeyError(f"geoms not in model: {missing}")
    return np.asarray(ids, np.int32)


def body_geom_ids(mj_model: mujoco.MjModel, body: str) -> np.ndarray:
    """Ids of all geoms attached to the named body."""
    b = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_BODY, body)
    if b < 0:
        raise KeyError(f"body not in model: {body}")
    return np.flatnonzero(np.asarray(mj_model.geom_bodyid) == b).astype(np.int32)
