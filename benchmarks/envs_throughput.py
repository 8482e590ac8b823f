"""Throughput of the envs_mjx domains, with their peers measured in the same run.

(a) Physics substeps/s (no pixels), three peers on the same MJCF model:
    env      jit(vmap(scan(env.step))) with pixels="off" (per-env model fields, LD state, reward)
    mjx      jit(vmap(scan(mjx.step))) on env.mjx_model (raw physics, shared model)
    C        mujoco.rollout, 1 thread, random controls (CartPole, InvertedPendulum, HalfCheetah,
             Ant); the incline's only input is an external force, so it runs a Python mj_step loop
(b) Frames/s of physics + rendering: jit(vmap(scan(env.step))) with pixels on (64x64
    envs_mjx.render), batch 1, 64 and 1024 (256 on CPU).
Compile time (first call: trace + XLA compile + one run) is reported apart from steady state.

Quoted anchors (not measured here; perf_anchors.md §2, "[2-core]" rows, 1 core, pybullet 3.2.7):
PyBullet TinyRenderer 64x64 + stepSimulation, cartpole 698 frames/s; r2d2 455 frames/s.

Run from the repo root: PYTHONPATH=. python benchmarks/envs_throughput.py [--quick]
[--envs CartPole Ant] [--pixel-batches 1024 4096] [--no-record]. Results go to
benchmarks/results.jsonl unless --no-record (use it on a loaded or shared machine).
"""

from __future__ import annotations

import argparse
import time

import jax
import mujoco
import numpy as np
from mujoco import mjx

import envs_mjx
from benchmarks.harness import measure, record

ANCHOR_FPS = {"CartPole": ("PyBullet TinyRenderer 64x64 cartpole, 1 core (quoted)", 698.0)}


def _random_actions(key, steps, batch, size):
    return jax.random.uniform(key, (steps, batch, size), minval=-1.0, maxval=1.0)


def _env_rollout(env):
    def roll(state, actions):
        def body(s, a):
            s = env.step(s, a)
            return s, s.pixels[0, 0, 0]  # keep pixels live without storing them

        return jax.lax.scan(body, state, actions)

    return jax.jit(jax.vmap(roll, in_axes=(0, 1)))


def bench_env_physics(name, batch, steps, repeats):
    env = envs_mjx.make(name, pixels="off")
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), batch))
    actions = _random_actions(jax.random.key(1), steps, batch, env.action_size)
    fn = _env_rollout(env)
    t = measure(fn, states, actions, repeats=repeats)
    substeps = batch * steps * env.n_frames
    return {"substeps_per_s": substeps / t["median_s"], "compile_s": t["compile_s"], **t}


def bench_raw_mjx(name, batch, steps, repeats):
    env = envs_mjx.make(name, pixels="off")
    model = env.mjx_model
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), batch))
    data = states.pipeline_state
    n = steps * env.n_frames
    ctrl = _random_actions(jax.random.key(1), n, batch, model.nu) if model.nu else None

    def roll(d, c):
        def body(d, ci):
            if ci is not None:
                d = d.replace(ctrl=ci)
            return mjx.step(model, d), None

        return jax.lax.scan(body, d, c, length=n)[0]

    fn = jax.jit(jax.vmap(roll, in_axes=(0, 1 if ctrl is not None else None)))
    t = measure(fn, data, ctrl, repeats=repeats)
    return {"substeps_per_s": batch * n / t["median_s"], **t}


def bench_c(name, batch, steps, repeats):
    """MuJoCo C on the env's model, 1 thread: mujoco.rollout when the env acts through ctrl."""
    env = envs_mjx.make(name, pixels="off")
    m = env.mj_model
    n = steps * env.n_frames
    rng = np.random.default_rng(0)
    d = mujoco.MjData(m)
    state0 = np.empty(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(m, d, state0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    if m.nu:
        from mujoco import rollout

        init = np.tile(state0, (batch, 1))
        ctrl = rng.uniform(-1, 1, (batch, n, m.nu))
        times = []
        for _ in range(repeats + 1):
            start = time.perf_counter()
            rollout.rollout(m, d, init, ctrl)
            times.append(time.perf_counter() - start)
        how = "mujoco.rollout, 1 thread"
    else:
        force = rng.uniform(-1, 1, (n, 3))
        times = []
        for _ in range(repeats + 1):
            start = time.perf_counter()
            for _ in range(batch):
                mujoco.mj_setState(m, d, state0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
                for k in range(n):
                    d.xfrc_applied[-1, :3] = force[k]
                    mujoco.mj_step(m, d)
            times.append(time.perf_counter() - start)
        how = "Python mj_step loop, 1 thread"
    median = float(np.median(times[1:]))
    return {"substeps_per_s": batch * n / median, "median_s": median, "how": how}


def bench_pixels(name, batch, steps, repeats):
    env = envs_mjx.make(name, pixels="required")
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.key(0), batch))
    actions = _random_actions(jax.random.key(1), steps, batch, env.action_size)
    t = measure(_env_rollout(env), states, actions, repeats=repeats)
    return {"frames_per_s": batch * steps / t["median_s"], **t}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--envs", nargs="+", default=list(envs_mjx.ALL_ENVS))
    parser.add_argument("--quick", action="store_true", help="small batches, few steps, 2 reps")
    parser.add_argument("--no-record", action="store_true", help="print only")
    parser.add_argument("--pixel-batches", type=int, nargs="+",
                        help="batches of the physics + rendering case (default 1 64 1024; "
                             "256 in place of 1024 on CPU)")
    args = parser.parse_args(argv)
    for name in args.envs:
        if name not in envs_mjx.ALL_ENVS:
            parser.error(f"unknown env {name!r}; valid: {list(envs_mjx.ALL_ENVS)}")
    cpu = jax.devices()[0].platform == "cpu"
    if args.quick:
        phys_batch, phys_steps, pix_batches, pix_steps, reps = 64, 10, (1, 64), 2, 2
    else:
        phys_batch, phys_steps, reps = 1024, 50, 5
        pix_batches, pix_steps = (1, 64, 256 if cpu else 1024), 10
    pix_batches = tuple(args.pixel_batches or pix_batches)
    print(f"jax {jax.__version__}, mujoco {mujoco.__version__}, device {jax.devices()[0]}")
    all_rows = []
    for name in args.envs:
        rows = []  # recorded per env, so a run cut short keeps the domains it finished
        print(f"== {name} ==", flush=True)
        env_r = bench_env_physics(name, phys_batch, phys_steps, reps)
        mjx_r = bench_raw_mjx(name, phys_batch, phys_steps, reps)
        c_r = bench_c(name, phys_batch, phys_steps, reps)
        print(
            f"  physics substeps/s, batch {phys_batch}: env.step {env_r['substeps_per_s']:,.0f} "
            f"(compile {env_r['compile_s']:.1f} s) | raw mjx.step {mjx_r['substeps_per_s']:,.0f} "
            f"(compile {mjx_r['compile_s']:.1f} s) | C {c_r['substeps_per_s']:,.0f} ({c_r['how']})"
            f" | env/mjx {env_r['substeps_per_s'] / mjx_r['substeps_per_s']:.2f}, "
            f"env/C {env_r['substeps_per_s'] / c_r['substeps_per_s']:.3f}",
            flush=True,
        )
        rows.append(
            {
                "case": f"{name}/physics/b{phys_batch}",
                "env_substeps_per_s": env_r["substeps_per_s"],
                "mjx_substeps_per_s": mjx_r["substeps_per_s"],
                "c_substeps_per_s": c_r["substeps_per_s"],
                "c_how": c_r["how"],
                "env_compile_s": env_r["compile_s"],
                "mjx_compile_s": mjx_r["compile_s"],
            }
        )
        for b in pix_batches:
            p = bench_pixels(name, b, pix_steps, reps)
            line = (
                f"  physics+render 64x64, batch {b}: {p['frames_per_s']:,.1f} frames/s "
                f"(compile {p['compile_s']:.1f} s)"
            )
            if name in ANCHOR_FPS:
                label, fps = ANCHOR_FPS[name]
                line += f" = {p['frames_per_s'] / fps:.2f}x {label} {fps:.0f}"
            print(line, flush=True)
            rows.append(
                {
                    "case": f"{name}/pixels/b{b}",
                    "frames_per_s": p["frames_per_s"],
                    "compile_s": p["compile_s"],
                }
            )
        if not args.no_record:
            record("envs_throughput", rows, notes="quick" if args.quick else "")
        all_rows += rows
    return all_rows


if __name__ == "__main__":
    main()
