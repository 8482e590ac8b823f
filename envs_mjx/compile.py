"""XLA options for programs that step and render envs: `jax.jit(f, compiler_options=...)`.

On the CPU, XLA's newer fusion emitters (`xla_cpu_use_fusion_emitters`, on by default in jaxlib
0.10) generate pathologically slow code for MJX's kinematics of a deep kinematic chain. XLA
fuses each level of the body tree into the next, duplicating the parent's pose computation into
every consumer (MJX's 471 multiplies in the Franka scene's `mjx.kinematics` become 3,475 after
fusion), and the new emitters run those fusions ~100× slower than the older elemental emitters.
Measured on a 2-core Intel Xeon (the project's machine of 2026-11-25), jaxlib 0.10.2, one
process per setting, alternated; default emitters → older emitters:

- `mjx.kinematics`, RearrangeGeom with the Franka, one env: 12.5 ms → 0.12 ms.
- `vmap(env.step)`, RearrangeGeom with the Franka, 8 envs, pixels off: 1.89 s → 0.024 s.
- `vmap(env.step)`, RearrangeGeom with the reacher, 64 envs, pixels off: 0.155 s → 0.141 s.
- 10 × `vmap(env.step)` with 64×64 pixels, 64 envs, CartPole / HalfCheetah / Ant: 15.6K /
  4.4K / 3.2K → 15.8K / 4.4K / 3.2K frames/s; compiling it 4.8 / 10.8 / 11.5 s → 3.2 / 7.3 /
  8.0 s.

Recorded side by side in one process through the harness (`python -m
benchmarks.envs_throughput --envs RearrangeGeom:arm=franka RearrangeGeom HalfCheetah CartPole
--parts options --rounds 5`, benchmark "env_compiler_options" in benchmarks/RESULTS.md; same
machine, commit ed8572c): physics alone at 8 envs, jaml's options over XLA's defaults, the Franka
scene 89× (rounds 83–94×; 2,578 against 29 substeps/s; compile 18 against 50 s), the reacher
scene 1.02× (0.99–1.13), HalfCheetah 0.97× (0.90–0.99), CartPole 1.05× (0.81–1.15); every
compile shorter (reacher 11.6 against 15.9 s, HalfCheetah 6.9 against 8.5 s).

The learners' convolutional train steps went the other way (VAE_rpl 0.86×, PRED 0.77× the
frames/s), so the option is for env programs (stepping, rendering, rollouts) only; the
learners keep `jaml.learners.compiler_options()`. Elsewhere (GPU) XLA's defaults are used.
jaml's own top-level env programs take them: the Gymnasium envs (`envs_mjx.gym`), `jaml envs
show` and `benchmarks/envs_throughput.py`. The learning loop's programs (`jaml.stream`) are not
changed: its epoch blocks hold the learner's steps, and its analysis rollouts are compiled by
module-level jits with XLA's defaults.

The older emitters are slower for the renderer's mesh tests, so they are asked for only where
the physics needs them, by the env's depth (`compiler_options(env)`). Measured on the same
machine (2026-11-25, one process, alternated, XLA's defaults against the older emitters): the
renderer alone on the Franka scene's meshes, 64 envs, 1,043 against 141 frames/s (7.4×);
MeshOnIncline's `env.step` with 64×64 pixels, 64 envs, 1,768 against 556 frames/s (3.2×). The
mesh test's scan over triangles alone (a one-off microbenchmark, 16 × 4096 pixels × 1024
triangles) ran 1.24 against 0.15 ns per triangle-pixel pair, and 1.5–1.6 against 0.16–0.29 with a
float-only carry or a max in place of the select: the older emitters' code for that loop is
slower whatever its form, so the choice is made per env rather than in the renderer. For
the Franka scene with MJX's physics the physics decides (89× the other way, above): its
`env.step` with pixels keeps the older emitters and is render-bound at ≈ 103 frames/s (batch
256); with `physics="c"` it takes XLA's defaults.

Options belong to the outermost `jax.jit` (JAX refuses them on a nested one), so functions that
callers jit inside their own programs, such as the MJX incline sources' `sample`
(`jaml.sources`), keep plain jits, and an env step inside a user's own jit compiles with that
jit's options: pass these there too,

    step = jax.jit(jax.vmap(env.step), compiler_options=envs_mjx.compiler_options(env))
"""

from __future__ import annotations

from typing import Any

import jax
import mujoco
import numpy as np

CPU_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}

# Bodies deep, world excluded, from which the duplication above makes XLA's default emitters the
# slower ones: the Franka scenes are 10 deep; every other domain is at most 4 (HalfCheetah), and
# there XLA's defaults were as fast or faster.
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
