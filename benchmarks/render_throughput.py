"""Frames per second of the JAX ray caster at 64×64, batch 1/64/256, on the default JAX device.

Run from the repo root: python -m benchmarks.render_throughput [--reps 5]
[--batches 1 64 256] [--large] [--outputs all seg] [--scenes cartpole mesh half_cheetah ant]
[--no-record]. Rows are recorded through the harness (`benchmarks/results.jsonl`, RESULTS.md)
unless --no-record.
`--large` adds batches 1024 and 4096 (for a GPU). `--outputs seg` also times a jitted function
that returns only the segmentation (XLA drops the unused shading). Compile time is reported
apart; throughput is the median over blocked repetitions, and for the CPU the frames per
second of process CPU time as well (less sensitive to other load on a shared machine). The
"before" column is the renderer before the rewrite (commit 2c4fecd), measured on the project's
2-core CPU machine; compare it only with CPU runs there.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import NamedTuple

import jax
import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import harness
from envs_mjx import render

CARTPOLE = """<mujoco><worldbody><light pos="0 0 4" dir="0 0 -1"/>
  <geom type="plane" size="3 3 .1" rgba=".9 .9 .9 1"/>
  <geom type="box" size="2 .02 .02" pos="0 0 1" rgba=".3 .3 .3 1"/>
  <body pos="0 0 1"><joint type="slide" axis="1 0 0"/>
    <geom type="box" size=".2 .1 .08" rgba=".8 .3 .2 1"/>
    <body><joint type="hinge" axis="0 1 0"/>
      <geom type="box" size=".03 .03 .4" pos="0 0 .4" rgba=".2 .5 .8 1"/></body></body>
  <camera name="cam" pos="0 -4 1.2" xyaxes="1 0 0 0 0 1"/>
</worldbody></mujoco>"""


def mesh_scene(nu=16, nv=8) -> str:
    """A torus mesh (2*nu*nv triangles) hinged above a plane."""
    a, b = np.meshgrid(2 * np.pi * np.arange(nu) / nu, 2 * np.pi * np.arange(nv) / nv,
                       indexing="ij")
    v = np.stack([(0.5 + 0.2 * np.cos(b)) * np.cos(a), (0.5 + 0.2 * np.cos(b)) * np.sin(a),
                  0.2 * np.sin(b)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    k = lambda ii, jj: ((ii % nu) * nv + (jj % nv)).ravel()  # noqa: E731
    f = np.concatenate([np.stack([k(i, j), k(i + 1, j), k(i + 1, j + 1)], -1),
                        np.stack([k(i, j), k(i + 1, j + 1), k(i, j + 1)], -1)])
    fmt = lambda x: " ".join(f"{y:.6g}" for y in np.ravel(x))  # noqa: E731
    return f"""<mujoco><asset><mesh name="torus" vertex="{fmt(v)}" face="{fmt(f)}"/></asset>
  <worldbody><light pos="0 0 4" dir="0 0 -1"/>
  <geom type="plane" size="3 3 .1" rgba=".9 .9 .9 1"/>
  <body pos="0 0 1"><joint type="hinge" axis="0 1 0"/>
    <geom type="mesh" mesh="torus" rgba=".2 .5 .8 1"/></body>
  <camera name="cam" pos="0 -3 1.5" xyaxes="1 0 0 0 .4 .9"/>
</worldbody></mujoco>"""


class Poses(NamedTuple):
    geom_xpos: np.ndarray
    geom_xmat: np.ndarray
    cam_xpos: np.ndarray
    cam_xmat: np.ndarray


def batch_of_poses(m: mujoco.MjModel, n: int, rng: np.random.Generator) -> Poses:
    """n configurations with random joint positions, stacked on a leading axis."""
    d = mujoco.MjData(m)
    rows = []
    for _ in range(n):
        d.qpos[:] = rng.uniform(-1.0, 1.0, m.nq)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_camlight(m, d)
        rows.append([np.array(getattr(d, f), np.float32) for f in Poses._fields])
    return Poses(*(np.stack(col) for col in zip(*rows, strict=True)))


# Frames/s of the renderer before the rewrite (commit 2c4fecd, all outputs), median of 5 reps
# on the 2-core AMD EPYC machine (JAX 0.10.2 CPU), keyed by (scene, batch).
BEFORE_2CORE = {("cartpole", 1): 279, ("cartpole", 64): 229, ("cartpole", 256): 203,
                ("mesh", 1): 34, ("mesh", 64): 40, ("mesh", 256): 32}

OUTPUTS = {"all": lambda out: out, "seg": lambda out: out.segmentation}


def bench(name: str, xml: str, batches, reps: int, outputs, camera: str = "cam") -> list[dict]:
    """Prints one line per (batch, outputs) and returns them as harness rows."""
    rows = []
    m = mujoco.MjModel.from_xml_string(xml)
    ctx = render.make_context(m, camera, 64, 64)
    rng = np.random.default_rng(0)
    cpu = jax.devices()[0].platform == "cpu"
    for b in batches:
        data = jax.device_put(batch_of_poses(m, b, rng))
        for which in outputs:
            pick = OUTPUTS[which]
            fn = jax.jit(jax.vmap(lambda c, d, pick=pick: pick(render.render(c, d)),
                                  in_axes=(None, 0)))
            t0 = time.perf_counter()
            compiled = fn.lower(ctx, data).compile()
            compile_s = time.perf_counter() - t0
            jax.block_until_ready(compiled(ctx, data))  # warm-up
            times, cpu_times = [], []
            for _ in range(reps):
                t0, c0 = time.perf_counter(), time.process_time()
                jax.block_until_ready(compiled(ctx, data))
                times.append(time.perf_counter() - t0)
                cpu_times.append(time.process_time() - c0)
            med = statistics.median(times)
            row = {"case": f"{name}/render/{which}", "impl": "jaml renderer", "batch": b,
                   "compile_s": compile_s, "median_s": med, "frames_per_s": b / med}
            line = (f"  batch {b:4d} {which:>3}: {b / med:10.1f} frames/s  (median"
                    f" {med * 1e3:8.2f} ms over {reps} reps; compile {compile_s:5.2f} s)")
            if cpu:
                row["frames_per_cpu_s"] = b / statistics.median(cpu_times)
                line += f"; {row['frames_per_cpu_s']:8.1f} frames/cpu-s"
                if which == "all" and (name, b) in BEFORE_2CORE:
                    line += f"; before {BEFORE_2CORE[name, b]}"
            print(line)
            rows.append(row)
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--reps", type=int, default=5)
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 64, 256])
    parser.add_argument("--large", action="store_true", help="add batches 1024 and 4096")
    parser.add_argument("--outputs", nargs="+", default=["all"], choices=sorted(OUTPUTS))
    parser.add_argument("--scenes", nargs="+", default=["cartpole", "mesh"],
                        choices=["cartpole", "mesh", "half_cheetah", "ant"])
    parser.add_argument("--no-record", action="store_true", help="print only")
    args = parser.parse_args()
    batches = list(args.batches) + ([1024, 4096] if args.large else [])
    dev = jax.devices()[0]
    print(f"jax {jax.__version__}, mujoco {mujoco.__version__}, device {dev.platform}:"
          f" {dev.device_kind}, host {platform.processor() or platform.machine()}")
    rows = []
    if "cartpole" in args.scenes:
        print("cartpole (3 boxes + plane), 64x64:")
        rows += bench("cartpole", CARTPOLE, batches, args.reps, args.outputs)
    if "mesh" in args.scenes:
        print("mesh (256-triangle torus + plane), 64x64:")
        rows += bench("mesh", mesh_scene(), batches, args.reps, args.outputs)
    if "half_cheetah" in args.scenes:
        print("half_cheetah (assets/half_cheetah.xml: 9 capsules + checker floor), 64x64:")
        xml = (Path(__file__).resolve().parents[1] / "assets" / "half_cheetah.xml").read_text()
        rows += bench("half_cheetah", xml, batches, args.reps, args.outputs, camera="pixels")
    if "ant" in args.scenes:
        print("ant (assets/ant.xml: sphere + 12 capsules + checker floor), 64x64:")
        xml = (Path(__file__).resolve().parents[1] / "assets" / "ant.xml").read_text()
        rows += bench("ant", xml, batches, args.reps, args.outputs, camera="pixels")

    if not args.no_record:
        harness.record("render_throughput", rows,
                       notes="The renderer alone (jit(vmap(render))) on random poses of each "
                             "scene, 64x64, compile apart, median of blocked repetitions.")


if __name__ == "__main__":
    main()
