"""XLA options for programs that step and render envs: `jax.jit(f, compiler_options=...)`.

On the CPU, XLA's newer fusion emitters duplicate each parent's pose into every child of a deep
kinematic chain and run MJX's kinematics of the Franka scenes far slower than the older
emitters; the older emitters are in turn slower for the renderer's mesh tests and the learners'
convolutions, so they are asked for per env, only where MJX physics runs on a deep body tree.
Measurements: docs/notes/envs.md, "XLA options for env programs".

Options belong to the outermost `jax.jit` (JAX refuses them on a nested one), so an env step
inside a user's own jit needs them passed there:

    step = jax.jit(jax.vmap(env.step), compiler_options=envs_mjx.compiler_options(env))
"""

from __future__ import annotations

from typing import Any

import jax
import mujoco
import numpy as np

CPU_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}

# Bodies deep, world excluded, from which XLA's default emitters are the slower ones: the Franka
# scenes are 10 deep, every other domain at most 4 (HalfCheetah); see docs/notes/envs.md.
DEEP_CHAIN = 6


def body_tree_depth(mj_model: mujoco.MjModel) -> int:
    """Bodies on the longest path from the world body to a leaf (the world not counted)."""
    depth = np.zeros(mj_model.nbody, int)
    for b in range(1, mj_model.nbody):  # parents come before their children
        depth[b] = depth[mj_model.body_parentid[b]] + 1
    return int(depth.max())


def compiler_options(env: Any) -> dict[str, bool] | None:
    """`compiler_options` for a jitted program that steps or renders `env` on the default backend:
    on the CPU, the older fusion emitters where `env` runs MJX's physics on a body tree at least
    DEEP_CHAIN deep (the Franka scenes), None (XLA's defaults) everywhere else, the GPU included.
    A `physics="c"` env's step runs its physics in C, and the renderer's mesh tests run faster
    with the default emitters (see the module docstring)."""
    if jax.default_backend() != "cpu":
        return None
    if getattr(getattr(env, "config", None), "physics", "mjx") == "c":
        return None
    if body_tree_depth(env.mj_model) < DEEP_CHAIN:
        return None
    return dict(CPU_COMPILER_OPTIONS)
