"""Looking at the domains: `list_envs()` (names, action and LD-state sizes) and `show()`, a PNG grid
of the env's own rendered frames from random-action rollouts. Behind `jaml envs list|show`."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import envs_mjx


def list_envs() -> list[dict]:
    """One row per registered env: name, action_size, ld_size, ld_names (pixels off: cheap)."""
    rows = []
    for name in envs_mjx.ALL_ENVS:
        env = envs_mjx.make(name, pixels="off")
        rows.append(
            {
                "name": name,
                "action_size": env.action_size,
                "ld_size": len(env.ld_state_names),
                "ld_names": list(env.ld_state_names),
            }
        )
    return rows


def format_list(rows: list[dict]) -> str:
    lines = []
    for r in rows:
        lines.append(
            f"{r['name']}: action {r['action_size']}, LD state {r['ld_size']} "
            f"[{', '.join(r['ld_names'])}]"
        )
    return "\n".join(lines)


def rollout_frames(name: str, resets: int, steps: int, seed: int = 0) -> np.ndarray:
    """uint8 [resets, steps, H, W, 3]: frame 0 is the reset state, frame t the state after t
    uniform random actions in [-1, 1]; each row is a fresh reset (its own colours, angle, ...)."""
    if resets < 1 or steps < 1:
        raise ValueError(f"resets and steps must be >= 1, got {resets} and {steps}")
    env = envs_mjx.make(name, pixels="required", episode_length=None)

    def one(key):
        k_reset, k_act = jax.random.split(key)
        state = env.reset(k_reset)
        actions = jax.random.uniform(k_act, (steps - 1, env.action_size), minval=-1.0, maxval=1.0)

        def body(s, a):
            s = env.step(s, a)
            return s, s.pixels

        _, frames = jax.lax.scan(body, state, actions)
        return jnp.concatenate([state.pixels[None], frames], axis=0)

    keys = jax.random.split(jax.random.key(seed), resets)
    return np.asarray(jax.jit(jax.vmap(one))(keys))


def grid(frames: np.ndarray, gap: int = 2) -> np.ndarray:
    """[R, T, H, W, 3] -> one uint8 image, rows = resets, columns = time, white gaps."""
    r, t, h, w, c = frames.shape
    out = np.full((r * h + (r - 1) * gap, t * w + (t - 1) * gap, c), 255, np.uint8)
    for i in range(r):
        for j in range(t):
            y, x = i * (h + gap), j * (w + gap)
            out[y : y + h, x : x + w] = frames[i, j]
    return out


def show(name: str, out: str | Path, resets: int = 4, steps: int = 8, seed: int = 0) -> Path:
    """Writes the rollout grid of env `name` to the PNG `out`; returns its path."""
    from PIL import Image

    if name not in envs_mjx.ALL_ENVS:
        raise ValueError(f"unknown env {name!r}; valid names: {list(envs_mjx.ALL_ENVS)}")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(grid(rollout_frames(name, resets, steps, seed))).save(out)
    return out
