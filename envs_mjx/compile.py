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

Options belong to the outermost `jax.jit` (JAX refuses them on a nested one), so functions that
callers jit inside their own programs, such as the MJX incline sources' `sample`
(`jaml.sources`), keep plain jits, and an env step inside a user's own jit compiles with that
jit's options: pass these there too,

    step = jax.jit(jax.vmap(env.step), compiler_options=envs_mjx.compiler_options())
"""

from __future__ import annotations

import jax

CPU_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}


def compiler_options() -> dict[str, bool] | None:
    """`compiler_options` for a jitted env program on the default backend: the older fusion
    emitters on the CPU (see the module docstring), None (XLA's defaults) elsewhere."""
    return dict(CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else None
