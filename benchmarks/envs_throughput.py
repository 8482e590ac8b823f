"""Throughput of the envs_mjx domains, with their peers measured in the same run.

(a) Physics substeps/s (no pixels), three peers on the same MJCF model:
    env      jit(vmap(scan(env.step))) with pixels="off" (per-env model fields, LD state, reward),
             compiled with `envs_mjx.compiler_options(env)` as every jaml env program (on the
             CPU XLA's older fusion emitters for the Franka scenes: envs_mjx/compile.py)
    mjx      jit(vmap(scan(mjx.step))) on env.mjx_model (raw physics, shared model), XLA's
             default options, as a user's own jit
    warp     the same scan on MuJoCo Warp (MJX's impl="warp"; needs the warp-lang package, the
             `bench` extra), from the same start states with the same controls: the GPU peer a
             user would otherwise pick. Every contact kept, up to WARP_CONTACTS per env.
    C        mujoco.rollout, 1 thread, random controls (CartPole, InvertedPendulum, HalfCheetah,
             Ant); the incline's only input is an external force, so it runs a Python mj_step loop
(b) Frames/s of physics + rendering: jit(vmap(scan(env.step))) with pixels on (64x64
    envs_mjx.render), batch 1, 64 and 1024 (256 on CPU).
(c) Side by side with the paper's stack (benchmark "envs_vs_pybullet"): the same env with
    pixels at the largest pixel batch against benchmarks/peers/pybullet_envs.py (PyBullet
    stepping the reference's scene + a 64x64 TinyRenderer frame per step made as the reference
    made it, one process per core), and batch 1 against one process (blocks of 200 steps, so
    that the steps and not a call's fixed cost are timed), for the domains that have a PyBullet
    scene. The two alternate block by block in one process (jaml's calls on all
    cores, then the PyBullet workers on all cores), so load from other processes falls on both;
    the row holds both medians, their ratio, the spread of the per-round ratios and each
    side's frames per CPU second (a per-core view that load from other processes does not
    lower; jaml's counts all its threads, spinning included). With `--fresh-processes K` each
    pair runs in K new processes one after another and the row is the median process's, with
    every process's ratio and jaml rate beside it.
(c') `--parts render`: the env's renderer alone (its pixels function, as env.step calls it) on
    reset states at the pixel batches, so that a physics + pixels row splits into its two parts.
(d) `--parts options`: physics alone (pixels off) at a small batch, the env's rollout compiled
    with XLA:CPU's older fusion emitters against XLA's defaults, alternated in one process, and
    which of the two jaml uses for the env (benchmark "env_compiler_options";
    envs_mjx/compile.py says why).
Compile time (first call: trace + XLA compile + one run) and PyBullet's scene loading are
reported apart from steady state.

Quoted anchors are kept in their own column (`quoted_…`), never divided into:
docs/reference/perf_anchors.md §2, "[2-core]" rows, 1 core, pybullet 3.2.7, PyBullet TinyRenderer
64x64 + stepSimulation, cartpole 698 frames/s (quoted, not measured here).

Run from the repo root: PYTHONPATH=. python benchmarks/envs_throughput.py [--quick]
[--envs CartPole Ant RearrangeGeom:arm=franka] [--pixel-batches 1024 4096]
[--parts physics pixels render pybullet] [--physics-batch 4096] [--rounds 7]
[--fresh-processes K] [--no-record].
Results go to benchmarks/results.jsonl unless --no-record (use it on a loaded or shared machine
for the absolute rows; the side-by-side ratio holds there too).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

import envs_mjx
from benchmarks.harness import block, child_result, measure, parse_env, record, usable_cores
from benchmarks.peers import pybullet_envs
from envs_mjx.compile import CPU_COMPILER_OPTIONS
from jaml import _huge_pages

# Quoted, not measured: docs/reference/perf_anchors.md §2 [2-core], pybullet 3.2.7, 1 core.
QUOTED_FPS = {"CartPole": (698.0, "docs/reference/perf_anchors.md §2 [2-core]: PyBullet "
                                  "TinyRenderer 64x64 + stepSimulation, cartpole.urdf, 1 core")}


def _random_actions(key, steps, batch, size):
    return jax.random.uniform(key, (steps, batch, size), minval=-1.0, maxval=1.0)


def _env_rollout(env, whole_frame=False):
    """jit(vmap(scan(env.step))) over [T, B, A] actions, compiled as jaml's own env programs
    (`envs_mjx.compiler_options(env)`)."""
    return _rollout_with(env, envs_mjx.compiler_options(env), whole_frame)


def _rollout_with(env, options, whole_frame=False):
    """`_env_rollout` compiled with the given XLA `options` (None: XLA's defaults)."""
    def roll(state, actions):
        def body(s, a):
            s = env.step(s, a)
            # Keep pixels live without storing them; whole_frame sums every pixel, so XLA
            # cannot narrow the frame to the one pixel read (the side-by-side case uses it).
            return s, (s.pixels.sum(dtype=jnp.int32) if whole_frame else s.pixels[0, 0, 0])

        return jax.lax.scan(body, state, actions)

    return jax.jit(jax.vmap(roll, in_axes=(0, 1)), compiler_options=options)


def _reset(env, batch):
    """`batch` env states from key 0, compiled as jaml's env programs are."""
    reset = jax.jit(jax.vmap(env.reset), compiler_options=envs_mjx.compiler_options(env))
    return reset(jax.random.split(jax.random.key(0), batch))


def make_env(spec: str, **kwargs):
    name, overrides = parse_env(spec)
    return envs_mjx.make(name, **overrides, **kwargs)


def bench_env_physics(name, batch, steps, repeats):
    env = make_env(name, pixels="off")
    states = _reset(env, batch)
    actions = _random_actions(jax.random.key(1), steps, batch, env.action_size)
    fn = _env_rollout(env)
    t = measure(fn, states, actions, repeats=repeats)
    substeps = batch * steps * env.n_frames
    # frames/s from the frame count, not converted by hand: an action (one frame) is
    # env.n_frames substeps, 8 on the Rearrange scenes.
    return {"substeps_per_s": substeps / t["median_s"],
            "frames_per_s": batch * steps / t["median_s"], "substeps_per_frame": env.n_frames,
            "compile_s": t["compile_s"], **t}


def _time_steps(model, data, n, repeats):
    """Substeps/s of jit(vmap(scan of n mjx.step)) from the batched `data`, random controls
    (key 1, the same for every backend)."""
    batch = data.qpos.shape[0]
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


def bench_raw_mjx(name, batch, steps, repeats):
    env = make_env(name, pixels="off")
    model = env.mjx_model
    states = _reset(env, batch)
    data = states.pipeline_state
    return _time_steps(model, data, steps * env.n_frames, repeats)


# MuJoCo Warp keeps every contact in one buffer shared by the batch (`naconmax`), sized here
# as this many per env (MJX's capped Rearrange scenes keep 32), and 4 constraint rows per
# contact per env (`njmax`: a pyramidal friction cone of condim 3).
WARP_CONTACTS = 32


def warp_available() -> bool:
    try:
        import warp  # noqa: F401
    except ImportError:
        return False
    return True


def bench_raw_warp(name, batch, steps, repeats):
    """`bench_raw_mjx` on MuJoCo Warp: the env's MjModel put with impl="warp"."""
    import warp

    warp.config.quiet = True  # no line per kernel module loaded
    env = make_env(name, pixels="off")
    model = mjx.put_model(env.mj_model, impl="warp")
    # Warp warns on every step whose solver stops at its iteration limit (Rearrange's 6 Newton
    # iterations, as the JAX path runs them): the benchmark keeps the limit and the quiet.
    from mujoco.mjx.third_party.mujoco_warp._src.types import OverflowType

    quiet = int(OverflowType.ALL & ~(OverflowType.ITERATIONS | OverflowType.LS_ITERATIONS))
    model = model.tree_replace({"opt._impl.warn_overflow": quiet})
    data0 = mjx.make_data(env.mj_model, impl="warp", naconmax=batch * WARP_CONTACTS,
                          njmax=4 * WARP_CONTACTS)
    states = _reset(env, batch)
    start = states.pipeline_state
    data = jax.jit(jax.vmap(lambda q, v: data0.replace(qpos=q, qvel=v)))(start.qpos, start.qvel)
    return _time_steps(model, data, steps * env.n_frames, repeats)


# One thread's substeps/s does not depend on how many envs it steps in turn, so the C peer runs
# at most this many (at the GPU's batch 4096 the Franka scene's C rollouts alone outran a
# 10-minute call).
C_MAX_BATCH = 256


def bench_c(name, batch, steps, repeats):
    """MuJoCo C on the env's model, 1 thread: mujoco.rollout when the env acts through ctrl;
    min(batch, C_MAX_BATCH) envs in turn."""
    env = make_env(name, pixels="off")
    batch = min(batch, C_MAX_BATCH)
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
    env = make_env(name, pixels="required")
    states = _reset(env, batch)
    actions = _random_actions(jax.random.key(1), steps, batch, env.action_size)
    t = measure(_env_rollout(env), states, actions, repeats=repeats)
    return {"frames_per_s": batch * steps / t["median_s"], **t}


def _render_fn(env):
    """jit(vmap(env.pixels_fn)): the frames env.step would draw for a batch of its states."""
    return jax.jit(jax.vmap(env.pixels_fn), compiler_options=envs_mjx.compiler_options(env))


def bench_render(name, batch, repeats):
    """Frames/s of the env's pixels function alone, vmapped over `batch` reset states: the
    renderer's share of a physics + pixels step (same context, colours and textures)."""
    env = make_env(name, pixels="required")
    states = _reset(env, batch)
    t = measure(_render_fn(env), states.pipeline_state, states.info, repeats=repeats)
    return {"frames_per_s": batch / t["median_s"], **t}


PEER_FRAME = ("reference: getCameraImage with the reference's renderer and default flags "
              "(segmentation mask computed), RGB to float 3x64x64 as the reference's wrapper; "
              "resets untimed")
SIDE_NOTE = (
    "Measured side by side in one process, alternated block by block: jaml's env.step with 64x64 "
    "pixels (XLA on every core the process may use, cpu_affinity) against "
    "benchmarks/peers/pybullet_envs.py (PyBullet 3.2.7 + TinyRenderer 64x64, one worker process "
    "per such core). ratio_jaml_over_pybullet divides the two "
    "medians; ratio_min / ratio_max are the extreme per-round ratios. The quoted_ columns are "
    "anchors quoted from docs/reference/perf_anchors.md, not measured here and not divided into."
)


def side_by_side_pairs(batches, processes: int) -> list[tuple[int, int]]:
    """(jaml batch, PyBullet processes) of the side-by-side rows: the largest batch against
    `processes` workers, and one env against one process, always (2026-11-26: `--pixel-batches
    1` alone had put one env against two)."""
    largest = max(batches)
    pairs = [(largest, processes if largest > 1 else 1)]
    if 1 in batches and largest > 1:
        pairs.append((1, 1))
    return pairs


def bench_vs_pybullet(name, batch, steps, rounds, processes=2):
    """jaml's env.step with pixels and the PyBullet peer, alternated block by block.

    A jaml block is one blocked call of `batch` envs x `steps` steps from reset states; a
    PyBullet block is `processes` workers x ceil(batch / processes) episodes x `steps` steps,
    about the same number of frames, timed over the steps (the resets left out, see
    pybullet_envs.run_block)."""
    env = make_env(name, pixels="required")
    states = _reset(env, batch)
    actions = _random_actions(jax.random.key(1), steps, batch, env.action_size)
    fn = _env_rollout(env, whole_frame=True)
    start = time.perf_counter()
    block(fn(states, actions))
    compile_s = time.perf_counter() - start
    episodes = -(-batch // processes)
    with pybullet_envs.PeerPool(name, processes, episodes, steps) as pool:
        t = alternate(lambda: fn(states, actions), pool, rounds)
    return side_by_side_row(name, batch, steps, batch * steps, t["jaml_s"],
                            pool.frames_per_block, t["pybullet_s"], compile_s=compile_s,
                            setup_s=pool.setup_s, processes=processes,
                            jaml_cpu=t["jaml_cpu_s"], pybullet_cpu=t["pybullet_cpu_s"])


def bench_vs_pybullet_in_processes(spec, batch, steps, rounds, processes, fresh):
    """`bench_vs_pybullet` in `fresh` new Python processes, one after another, and one row of
    them: the median process's ratio and rates, and every process's ratio and jaml rate. A
    process's XLA:CPU program can run at about half its usual rate for that process's whole
    life (docs/notes/learners.md, "The CPU ratio that slipped"), which one process cannot tell
    from the peer's noise; the spread across processes can."""
    rows = []
    for _ in range(fresh):
        try:
            rows.append(child_result(__file__, "--side-by-side-child", json.dumps(
                [spec, batch, steps, rounds, processes])))
        except RuntimeError as e:
            raise RuntimeError(f"a --fresh-processes child ({spec}, batch {batch}): {e}") from e
    by_ratio = sorted(rows, key=lambda r: r["ratio_jaml_over_pybullet"])
    row = dict(by_ratio[(len(rows) - 1) // 2])  # the median process (the lower one of two)
    row.update({
        "fresh_processes": fresh,
        "ratio_by_process": [round(r["ratio_jaml_over_pybullet"], 3) for r in rows],
        "jaml_frames_per_s_by_process": [round(r["jaml_frames_per_s"]) for r in rows],
        "ratio_min": min(r["ratio_min"] for r in rows),
        "ratio_max": max(r["ratio_max"] for r in rows),
        "rounds": sum(r["rounds"] for r in rows),
    })
    return row


def bench_gym_vs_pybullet(name, steps, rounds):
    """One env stepped through jaml's Gymnasium interface (`envs_mjx.to_gymnasium`: a jitted
    call and a host copy of the frame per step, as a user's Python loop runs it) against one
    PyBullet process, alternated block by block; each block resets untimed, then steps `steps`
    random actions with a frame each, as the peer does (neither side resets within a block)."""
    env_name, overrides = parse_env(name)
    gym_env = envs_mjx.to_gymnasium(env_name, None, seed=0, pixels="required", **overrides)
    actions = np.random.default_rng(0).uniform(-1, 1, (steps, *gym_env.action_space.shape))
    actions = actions.astype(np.float32)

    def episode():
        obs = None
        for a in actions:
            obs = gym_env.step(a)[0]
        return obs

    start = time.perf_counter()
    gym_env.reset(seed=0)
    episode()
    compile_s = time.perf_counter() - start
    with pybullet_envs.PeerPool(name, 1, 1, steps) as pool:
        t = alternate(episode, pool, rounds, before=lambda: gym_env.reset(seed=0))
    row = side_by_side_row(name, 1, steps, steps, t["jaml_s"], pool.frames_per_block,
                           t["pybullet_s"], compile_s=compile_s, setup_s=pool.setup_s,
                           processes=1, jaml_cpu=t["jaml_cpu_s"],
                           pybullet_cpu=t["pybullet_cpu_s"])
    row["case"] = f"{name}/gym_vs_pybullet/b1"
    row["impl"] = "jaml Gymnasium env.step (one env) vs PyBullet+TinyRenderer x1 process"
    return row


def bench_compiler_options(name, batch, steps, rounds):
    """Physics alone (pixels off): the env rollout compiled with XLA:CPU's older fusion emitters
    (`envs_mjx.compile.CPU_COMPILER_OPTIONS`) and with XLA's defaults, in one process, alternated
    block by block (even rounds the older first); both compile times and median substeps/s,
    their ratio with its per-round spread, and which of the two jaml's env programs use for this
    env (`envs_mjx.compiler_options(env)`). On a GPU run it compares XLA:GPU with itself."""
    env = make_env(name, pixels="off")
    states = _reset(env, batch)
    actions = _random_actions(jax.random.key(1), steps, batch, env.action_size)
    options = {"older": CPU_COMPILER_OPTIONS, "xla_default": None}
    fns, compile_s = {}, {}
    for label, opts in options.items():
        fns[label] = _rollout_with(env, opts)
        start = time.perf_counter()
        block(fns[label](states, actions))
        compile_s[label] = time.perf_counter() - start
    times = {label: [] for label in fns}
    for r in range(rounds):
        for label in (("older", "xla_default") if r % 2 == 0 else ("xla_default", "older")):
            start = time.perf_counter()
            block(fns[label](states, actions))
            times[label].append(time.perf_counter() - start)
    substeps = batch * steps * env.n_frames
    ratios = sorted(d / o for o, d in zip(times["older"], times["xla_default"], strict=True))
    return {
        "case": f"{name}/compiler_options/b{batch}",
        "impl": "env.step, pixels off: XLA:CPU's older fusion emitters vs XLA's defaults",
        "options": json.dumps(CPU_COMPILER_OPTIONS),
        "jaml_uses": "older" if envs_mjx.compiler_options(env) else "xla_default",
        "older_substeps_per_s": substeps / statistics.median(times["older"]),
        "default_substeps_per_s": substeps / statistics.median(times["xla_default"]),
        "ratio_older_over_default": statistics.median(times["xla_default"])
        / statistics.median(times["older"]),
        "ratio_min": ratios[0], "ratio_max": ratios[-1],
        "older_compile_s": compile_s["older"], "default_compile_s": compile_s["xla_default"],
        "batch": batch, "steps": steps, "rounds": rounds,
    }


def alternate(jaml_call, pool, rounds, before=None):
    """Seconds per round of `jaml_call()` (blocked) and of `pool.block()`, with the CPU seconds
    of each (jaml's process, all its threads; the PyBullet workers, summed), after one warm-up
    block of the pool (jaml's first call is its compile, made before). Even rounds run jaml
    first, odd rounds PyBullet first. `before` (optional) runs untimed ahead of each jaml block."""
    pool.block()
    out = {"jaml_s": [], "pybullet_s": [], "jaml_cpu_s": [], "pybullet_cpu_s": []}

    def jaml_block():
        if before is not None:  # untimed set-up of the block (a reset)
            before()
        start, start_cpu = time.perf_counter(), time.process_time()
        block(jaml_call())
        out["jaml_s"].append(time.perf_counter() - start)
        out["jaml_cpu_s"].append(time.process_time() - start_cpu)

    def pb_block():
        out["pybullet_s"].append(pool.block())
        out["pybullet_cpu_s"].append(pool.last_cpu_s)

    for r in range(rounds):
        for side in (pb_block, jaml_block) if r % 2 else (jaml_block, pb_block):
            side()
    return out


def side_by_side_row(name, batch, steps, jaml_frames, jaml_times, pb_frames, pb_times, *,
                     compile_s, setup_s, processes, jaml_cpu=(), pybullet_cpu=()):
    """The recorded row: both sides' median frames/s, their ratio and its per-round spread;
    frames per CPU second of each side (a per-core view that other processes' load does not
    lower); the quoted anchor in its own columns, not divided into."""
    ratios = sorted((jaml_frames / j) / (pb_frames / p)
                    for j, p in zip(jaml_times, pb_times, strict=True))
    jaml_fps = jaml_frames / statistics.median(jaml_times)
    pb_fps = pb_frames / statistics.median(pb_times)
    quoted, source = QUOTED_FPS.get(name, ("", ""))
    row = {
        "case": f"{name}/pixels_vs_pybullet/b{batch}",
        "impl": f"jaml env.step b{batch} vs PyBullet+TinyRenderer x{processes} processes",
        "jaml_frames_per_s": jaml_fps,
        "pybullet_frames_per_s": pb_fps,
        "ratio_jaml_over_pybullet": jaml_fps / pb_fps,
        "ratio_min": ratios[0],
        "ratio_max": ratios[-1],
        "rounds": len(ratios),
        "steps": steps,
        "pybullet_scene": pybullet_envs.SCENE_NOTES[pybullet_envs.scene_key(name)],
        "pybullet_frame": PEER_FRAME,
        "jaml_compile_s": compile_s,
        "pybullet_setup_s": setup_s,
        "quoted_pybullet_1core_frames_per_s": quoted,
        "quoted_source": source,
    }
    if jaml_cpu and pybullet_cpu:
        row["jaml_frames_per_cpu_s"] = jaml_frames / statistics.median(jaml_cpu)
        row["pybullet_frames_per_cpu_s"] = pb_frames / statistics.median(pybullet_cpu)
    return row


def main(argv=None):
    if argv is None:  # a process of its own runs as jaml's commands do
        _huge_pages.adopt()
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--envs", nargs="+", default=list(envs_mjx.ALL_ENVS),
                        help="domains, each optionally with config overrides, e.g. "
                             "RearrangeGeom:arm=franka")
    parser.add_argument("--quick", action="store_true", help="small batches, few steps, 2 reps")
    parser.add_argument("--no-record", action="store_true", help="print only")
    parser.add_argument("--pixel-batches", type=int, nargs="+",
                        help="batches of the physics + rendering case (default 1 64 1024; "
                             "256 in place of 1024 on CPU)")
    parser.add_argument("--physics-batch", type=int,
                        help="batch of the physics case (default 1024; 64 with --quick)")
    parts = ("physics", "pixels", "pybullet", "render", "options")
    parser.add_argument("--parts", nargs="+", choices=parts, default=list(parts[:3]),
                        help="which cases to run (pybullet: the side-by-side rows, for the "
                             "domains with a PyBullet scene, when pybullet is installed; "
                             "render: the renderer alone at the pixel batches; options: "
                             "physics with XLA:CPU's older emitters against XLA's defaults; "
                             "the default runs physics, pixels and pybullet)")
    parser.add_argument("--rounds", type=int, default=7,
                        help="alternated blocks per side in the side-by-side case")
    parser.add_argument("--single-env-steps", type=int, default=200,
                        help="steps per block of the one-env side-by-side pair (10 steps of one "
                             "env, ~3 ms, would time the call's fixed cost more than the steps)")
    parser.add_argument("--gym", action="store_true",
                        help="with batch 1: also one env stepped through the Gymnasium "
                             "interface, one Python call per step, against one PyBullet process")
    parser.add_argument("--options-batch", type=int, default=8,
                        help="batch of the options case (small: XLA's default CPU emitters "
                             "run the Franka scene's step ~1.9 s at 8 envs)")
    parser.add_argument("--fresh-processes", type=int, default=1, metavar="K",
                        help="run each side-by-side pair in K new Python processes, one after "
                             "another, and record the median process with every process's "
                             "ratio (a process's rate can hold at about half for its whole "
                             "life, which one process cannot tell)")
    parser.add_argument("--side-by-side-child", help=argparse.SUPPRESS)
    parser.add_argument("--processes", type=int, default=usable_cores(),
                        help="PyBullet worker processes (default: one per core this process "
                             "may run on, so `taskset -c 0` gives one)")
    args = parser.parse_args(argv)
    if args.side_by_side_child:  # one process of --fresh-processes: its row on stdout
        print(json.dumps(bench_vs_pybullet(*json.loads(args.side_by_side_child))), flush=True)
        return []
    if args.fresh_processes < 1:
        parser.error(f"--fresh-processes must be at least 1, got {args.fresh_processes}")
    for spec in args.envs:
        try:
            name = parse_env(spec)[0]
        except ValueError as e:
            parser.error(str(e))
        if name not in envs_mjx.ALL_ENVS:
            parser.error(f"unknown env {name!r}; valid: {list(envs_mjx.ALL_ENVS)}")
    cpu = jax.devices()[0].platform == "cpu"
    if args.quick:
        phys_batch, phys_steps, pix_batches, pix_steps, reps = 64, 10, (1, 64), 2, 2
    else:
        phys_batch, phys_steps, reps = 1024, 50, 5
        pix_batches, pix_steps = (1, 64, 256 if cpu else 1024), 10
    pix_batches = tuple(args.pixel_batches or pix_batches)
    phys_batch = args.physics_batch or phys_batch
    print(f"jax {jax.__version__}, mujoco {mujoco.__version__}, device {jax.devices()[0]}")
    # The side-by-side case compares CPU with CPU: on an accelerator the PyBullet workers would
    # still run on the host's cores.
    side = "pybullet" in args.parts and cpu and pybullet_envs.available()
    if "pybullet" in args.parts and not side:
        print("no side-by-side rows: " + ("pybullet is not installed (pip install -e '.[dev]')"
                                          if cpu else "they compare CPU with CPU"))
    all_rows = []
    for name in args.envs:
        # Recorded per env: a run cut short keeps the finished domains.
        rows, side_rows, option_rows = [], [], []
        print(f"== {name} ==", flush=True)
        if "physics" in args.parts:
            rows.append(_physics_row(name, phys_batch, phys_steps, reps))
        for b in pix_batches if "pixels" in args.parts else ():
            p = bench_pixels(name, b, pix_steps, reps)
            print(f"  physics+render 64x64, batch {b}: {p['frames_per_s']:,.1f} frames/s "
                  f"(compile {p['compile_s']:.1f} s)", flush=True)
            rows.append({"case": f"{name}/pixels/b{b}", "frames_per_s": p["frames_per_s"],
                         "compile_s": p["compile_s"]})
        for b in pix_batches if "render" in args.parts else ():
            r = bench_render(name, b, reps)
            print(f"  render alone 64x64, batch {b}: {r['frames_per_s']:,.1f} frames/s "
                  f"(compile {r['compile_s']:.1f} s)", flush=True)
            rows.append({"case": f"{name}/render/b{b}", "frames_per_s": r["frames_per_s"],
                         "compile_s": r["compile_s"]})
        if "options" in args.parts:
            r = bench_compiler_options(name, args.options_batch, pix_steps, args.rounds)
            print(f"  physics substeps/s, batch {args.options_batch}: older emitters "
                  f"{r['older_substeps_per_s']:,.0f} (compile {r['older_compile_s']:.1f} s) | "
                  f"XLA's defaults {r['default_substeps_per_s']:,.0f} (compile "
                  f"{r['default_compile_s']:.1f} s) | ratio {r['ratio_older_over_default']:.2f} "
                  f"(rounds {r['ratio_min']:.2f}-{r['ratio_max']:.2f}); jaml uses "
                  f"{r['jaml_uses']}", flush=True)
            option_rows.append(r)
        pairs = side_by_side_pairs(pix_batches, args.processes)
        has_peer = side and _has_peer(name)
        for b, procs in pairs if has_peer else ():
            steps = pix_steps if b > 1 or args.quick else args.single_env_steps
            if args.fresh_processes > 1:
                r = bench_vs_pybullet_in_processes(name, b, steps, args.rounds, procs,
                                                   args.fresh_processes)
            else:
                r = bench_vs_pybullet(name, b, steps, args.rounds, procs)
            line = (f"  side by side, 64x64 frames/s: jaml b{b} "
                    f"{r['jaml_frames_per_s']:,.0f} | PyBullet x{procs} "
                    f"{r['pybullet_frames_per_s']:,.0f} | ratio {r['ratio_jaml_over_pybullet']:.2f}"
                    f" (rounds {r['ratio_min']:.2f}-{r['ratio_max']:.2f}); per CPU second: "
                    f"jaml {r['jaml_frames_per_cpu_s']:,.0f}, PyBullet "
                    f"{r['pybullet_frames_per_cpu_s']:,.0f}")
            if quoted := r["quoted_pybullet_1core_frames_per_s"]:
                line += f"; quoted, not measured: {quoted:.0f} per core"
            if "ratio_by_process" in r:
                line += (f"\n    the median of {args.fresh_processes} processes; their ratios "
                         f"{r['ratio_by_process']}, jaml b{b} frames/s "
                         f"{r['jaml_frames_per_s_by_process']}")
            print(line, flush=True)
            side_rows.append(r)
        if has_peer and args.gym and 1 in pix_batches:
            r = bench_gym_vs_pybullet(name, 20 if args.quick else args.single_env_steps,
                                      args.rounds)
            print(f"  Gymnasium, one env: jaml {r['jaml_frames_per_s']:,.0f} | PyBullet x1 "
                  f"{r['pybullet_frames_per_s']:,.0f} frames/s | ratio "
                  f"{r['ratio_jaml_over_pybullet']:.2f} (rounds {r['ratio_min']:.2f}-"
                  f"{r['ratio_max']:.2f})", flush=True)
            side_rows.append(r)
        if not args.no_record:
            notes = "quick" if args.quick else ""
            if rows:
                record("envs_throughput", rows, notes=notes)
            if side_rows:
                record("envs_vs_pybullet", side_rows, notes=SIDE_NOTE + (" Quick run." if
                                                                         args.quick else ""))
            if option_rows:
                record("env_compiler_options", option_rows, notes=notes)
        all_rows += rows + side_rows + option_rows
    return all_rows


def _has_peer(spec):
    """Whether the PyBullet peer has the scene of env spec `spec` (the arm override picks it;
    physics / max_contacts keep it); if not, says why, so that no other scene stands in."""
    try:
        pybullet_envs.scene_key(spec)
    except ValueError as e:
        print(f"  no side-by-side rows: {e}", flush=True)
        return False
    return True


def _physics_row(name, batch, steps, reps):
    env_r = bench_env_physics(name, batch, steps, reps)
    mjx_r = bench_raw_mjx(name, batch, steps, reps)
    c_r = bench_c(name, batch, steps, reps)
    warp_r = bench_raw_warp(name, batch, steps, reps) if warp_available() else None
    warp_text = ("warp not installed" if warp_r is None else
                 f"raw MuJoCo Warp {warp_r['substeps_per_s']:,.0f} (compile "
                 f"{warp_r['compile_s']:.1f} s), mjx/warp "
                 f"{mjx_r['substeps_per_s'] / warp_r['substeps_per_s']:.2f}")
    print(
        f"  physics substeps/s, batch {batch}: env.step {env_r['substeps_per_s']:,.0f} "
        f"(= {env_r['frames_per_s']:,.0f} frames/s at {env_r['substeps_per_frame']} substeps "
        f"per frame; compile {env_r['compile_s']:.1f} s) | "
        f"raw mjx.step {mjx_r['substeps_per_s']:,.0f} "
        f"(compile {mjx_r['compile_s']:.1f} s) | C {c_r['substeps_per_s']:,.0f} ({c_r['how']})"
        f" | {warp_text} | env/mjx {env_r['substeps_per_s'] / mjx_r['substeps_per_s']:.2f}, "
        f"env/C {env_r['substeps_per_s'] / c_r['substeps_per_s']:.3f}",
        flush=True,
    )
    warp_cols = {} if warp_r is None else {
        "warp_substeps_per_s": warp_r["substeps_per_s"], "warp_compile_s": warp_r["compile_s"],
        "mjx_over_warp": mjx_r["substeps_per_s"] / warp_r["substeps_per_s"]}
    return {**warp_cols,
        "case": f"{name}/physics/b{batch}",
        "env_substeps_per_s": env_r["substeps_per_s"],
        "env_frames_per_s": env_r["frames_per_s"],
        "substeps_per_frame": env_r["substeps_per_frame"],
        "mjx_substeps_per_s": mjx_r["substeps_per_s"],
        "c_substeps_per_s": c_r["substeps_per_s"],
        "c_how": c_r["how"],
        "env_compile_s": env_r["compile_s"],
        "mjx_compile_s": mjx_r["compile_s"],
    }


if __name__ == "__main__":
    main()
