"""Looking at the domains: `list_envs()` (names, action and LD-state sizes) and `show()`, a PNG grid
of the env's own rendered frames from random-action rollouts. Behind `jaml envs list|show`."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from PIL import Image

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


def rollout_frames(name: str, resets: int, steps: int, seed: int = 0, **overrides) -> np.ndarray:
    """uint8 [resets, steps, H, W, 3]: frame 0 is the reset state, frame t the state after t
    uniform random actions in [-1, 1]; each row is a fresh reset (its own colours, angle, ...),
    from the env's batch reset (`Env.reset_batch`: row i is env slot i, e.g. Rearrange's
    version i mod 4). `overrides` go to `envs_mjx.make` (e.g. arm="franka")."""
    if resets < 1 or steps < 1:
        raise ValueError(f"resets and steps must be >= 1, got {resets} and {steps}")
    env = envs_mjx.make(name, pixels="required", episode_length=None, **overrides)

    def run(key):
        k_reset, k_act = jax.random.split(key)
        states = env.reset_batch(k_reset, resets)
        shape = (steps - 1, resets, env.action_size)
        actions = jax.random.uniform(k_act, shape, minval=-1.0, maxval=1.0)

        def body(s, a):
            s = jax.vmap(env.step)(s, a)
            return s, s.pixels

        _, frames = jax.lax.scan(body, states, actions)  # [steps - 1, resets, ...]
        return jnp.concatenate([states.pixels[:, None], jnp.swapaxes(frames, 0, 1)], axis=1)

    return np.asarray(jax.jit(run, compiler_options=envs_mjx.compiler_options(env))(
        jax.random.key(seed)))


def grid(frames: np.ndarray, gap: int = 2) -> np.ndarray:
    """[R, T, H, W, 3] -> one uint8 image, rows = resets, columns = time, white gaps."""
    r, t, h, w, c = frames.shape
    out = np.full((r * h + (r - 1) * gap, t * w + (t - 1) * gap, c), 255, np.uint8)
    for i in range(r):
        for j in range(t):
            y, x = i * (h + gap), j * (w + gap)
            out[y : y + h, x : x + w] = frames[i, j]
    return out


def check_png_path(out: str | Path) -> Path:
    """`out` as a Path, refused before any rendering unless it names a writable .png file."""
    out = Path(out)
    if out.suffix.lower() != ".png":
        raise ValueError(f"--out {out}: the grid is written as PNG; give a path ending in .png")
    if out.is_dir():
        raise ValueError(f"--out {out} is a directory; give a file path ending in .png")
    out.parent.mkdir(parents=True, exist_ok=True)
    if not os.access(out.parent, os.W_OK):
        raise ValueError(f"--out {out}: {out.parent} is not writable; choose another folder")
    return out


def show(
    name: str, out: str | Path, resets: int = 4, steps: int = 8, seed: int = 0, **overrides
) -> Path:
    """Writes the rollout grid of env `name` (config `overrides`) to the PNG `out`; returns its
    path."""
    if name not in envs_mjx.ALL_ENVS:
        raise ValueError(f"unknown env {name!r}; valid names: {list(envs_mjx.ALL_ENVS)}")
    out = check_png_path(out)
    Image.fromarray(grid(rollout_frames(name, resets, steps, seed, **overrides))).save(out)
    return out


def main(argv: list[str] | None = None) -> int:
    """`python -m envs_mjx.show NAME --out PNG [--arm franka] [--version V] ...`"""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("name")
    parser.add_argument("--out", required=True)
    parser.add_argument("--resets", type=int, default=4)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--arm", help="Rearrange: reacher or franka")
    parser.add_argument("--version", type=int, help="Rearrange: one version 0-11 for every row")
    args = parser.parse_args(argv)
    overrides = {k: getattr(args, k) for k in ("arm", "version") if getattr(args, k) is not None}
    print(show(args.name, args.out, args.resets, args.steps, args.seed, **overrides))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
