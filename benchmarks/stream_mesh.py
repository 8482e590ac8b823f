"""One SPMD program over several devices, in one process or one process per device: the same
stacked runs must train bit-identically both ways; epochs/s of each.

R runs of one config (seeds) train through `run_stacked_epochs`' device loop on a mesh of D
devices: (a) one process holding all D devices, (b) D processes of one device each, joined by
`jax.distributed` (a coordinator on this machine), each holding its share of the runs
(`executor.held_runs`). Each process fills the replays in a first call (which compiles), then
times `--epochs` epochs; the parent compares every run's metrics and learner parameters bit for
bit between (a) and (b) and reports epochs/s (all runs; (b) at its slowest process's pace).

    python benchmarks/stream_mesh.py --runs 4                  # a machine with two GPUs
    python benchmarks/stream_mesh.py --cpu --quick --no-record # two XLA:CPU devices, tiny sizes

On GPUs the two agree bit for bit only with XLA's deterministic kernels
(`XLA_FLAGS=--xla_gpu_deterministic_ops=true`, slower); without them they round apart.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# Small enough to compile in about a minute on XLA:CPU: VAE_v0 with narrow convolutions, one
# learner step per epoch; the replay fills in two epochs.
QUICK = {"num_envs": 8, "rollout_len": 4, "replay.slots": 16, "frames_per_batch": 8,
         "learner_steps": 1, "ppo.num_minibatches": 4,
         "learner_config.conv_filters": (8, 8, 8, 8), "learner_config.conv_features": 16,
         "learner_config.deconv_filters": (8, 8, 8, 8)}
# The paper's sizes of one epoch, the replay as stream_throughput measures it.
PAPER = {"num_envs": 64, "replay.slots": 1024, "frames_per_batch": 1024}


def worker(args) -> None:
    """One process of a call: trains its runs (all of them, or its share over several
    processes) and writes their metrics, learner parameters and timings to `args.out`."""
    import jax

    if args.num_processes > 1:
        jax.distributed.initialize(args.coordinator, args.num_processes, args.process_id)
    from jaml.stream import build, for_env
    from jaml.stream.executor import held_runs, run_stacked_epochs, runs_mesh, stack_runs

    env, learner = args.case.split("/")
    stream = build(for_env(env, learner, {**(QUICK if args.quick else PAPER), "epochs": 1000}))
    config = stream.config  # resolved: the replay's fill epochs
    mesh = runs_mesh(args.runs)
    held = held_runs(args.runs, mesh)
    states = stack_runs([stream.init(jax.random.PRNGKey(seed)) for seed in held])
    start = time.perf_counter()
    states, filled = run_stacked_epochs(stream, states, config.fill_epochs, mesh=mesh,
                                        host_loop=False, num_runs=args.runs)
    jax.block_until_ready(states)
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    states, trained = run_stacked_epochs(stream, states, args.epochs, mesh=mesh,
                                         host_loop=False, num_runs=args.runs)
    jax.block_until_ready(states)
    wall = time.perf_counter() - start
    arrays = {f"metrics/{k}": np.concatenate([np.asarray(filled[k]), np.asarray(v)])
              for k, v in trained.items()}
    leaves = jax.tree_util.tree_leaves_with_path(states.learner.params)
    arrays |= {f"params/{jax.tree_util.keystr(p)}": np.asarray(x) for p, x in leaves}
    np.savez(args.out, runs=np.asarray(list(held)), **arrays)
    Path(args.out).with_suffix(".json").write_text(json.dumps({
        "compile_s": compile_s, "wall_s": wall, "mesh_devices": mesh.size,
        "local_devices": len(jax.local_devices()), "held": list(held),
        "device": str(jax.devices()[0].device_kind)}))


def launch(args, processes: int, folder: Path) -> list[Path]:
    """(a) one process with `args.devices` devices (processes=1), or (b) that many processes of
    one device each; returns their output files."""
    port = _free_port()
    procs, outs = [], []
    for i in range(processes):
        env = dict(os.environ)
        if args.cpu:
            count = args.devices if processes == 1 else 1
            env["JAX_PLATFORMS"] = "cpu"
            env["XLA_FLAGS"] = (f"{env.get('XLA_FLAGS', '')} "
                                f"--xla_force_host_platform_device_count={count}").strip()
        elif processes > 1:
            env["CUDA_VISIBLE_DEVICES"] = str(i)
        out = folder / f"p{processes}_{i}.npz"
        command = [sys.executable, __file__, "--worker", "--case", args.case, "--runs",
                   str(args.runs), "--epochs", str(args.epochs), "--out", str(out),
                   "--num-processes", str(processes), "--process-id", str(i),
                   "--coordinator", f"127.0.0.1:{port}", *(["--quick"] if args.quick else [])]
        procs.append(subprocess.Popen(command, env=env, cwd=ROOT))
        outs.append(out)
    codes = [p.wait() for p in procs]
    if any(codes):
        raise RuntimeError(f"{processes} process(es) exited with {codes}")
    return outs


def gathered(outs: list[Path]) -> tuple[dict[str, np.ndarray], list[dict]]:
    """The processes' arrays joined along the runs axis in run order (metrics [n, R],
    parameters [R, ...]), and their timings."""
    parts = [dict(np.load(o)) for o in outs]
    joined = {}
    for name in parts[0]:
        if name != "runs":
            axis = 1 if name.startswith("metrics/") else 0
            joined[name] = np.concatenate([p[name] for p in parts], axis=axis)
    runs = np.concatenate([p["runs"] for p in parts])
    assert runs.tolist() == sorted(runs.tolist()), runs
    return joined, [json.loads(o.with_suffix(".json").read_text()) for o in outs]


def different(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> list[str]:
    """The arrays that are not bit-identical (NaN equal to NaN)."""
    return [k for k in a if a[k].shape != b[k].shape
            or not np.array_equal(a[k], b[k], equal_nan=True)]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", default="CartPole/VAE_rpl", help="ENV/LEARNER")
    parser.add_argument("--runs", type=int, default=4)
    parser.add_argument("--devices", type=int, default=2)
    parser.add_argument("--epochs", type=int, default=20, help="epochs timed after the fill")
    parser.add_argument("--cpu", action="store_true",
                        help="XLA:CPU with --devices forced host devices (a smoke run)")
    parser.add_argument("--quick", action="store_true", help="tiny sizes (for --cpu)")
    parser.add_argument("--no-record", action="store_true", help="print only")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    parser.add_argument("--num-processes", type=int, default=1, help=argparse.SUPPRESS)
    parser.add_argument("--process-id", type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument("--coordinator", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        worker(args)
        return 0
    if args.runs < args.devices:
        parser.error(f"--runs ({args.runs}) must be at least --devices ({args.devices})")
    with tempfile.TemporaryDirectory() as folder:
        one, one_times = gathered(launch(args, 1, Path(folder)))
        many, many_times = gathered(launch(args, args.devices, Path(folder)))
    differ = different(one, many)
    shardy = os.environ.get("JAX_USE_SHARDY_PARTITIONER", "true").lower() not in ("0", "false")
    rows = []
    for label, times in (("one process", one_times), ("one process per device", many_times)):
        wall = max(t["wall_s"] for t in times)
        rows.append({"case": f"{args.case}/{label}", "impl": "jaml", "runs": args.runs,
                     "devices": times[0]["mesh_devices"], "processes": len(times),
                     "compile_s": max(t["compile_s"] for t in times), "median_s": wall,
                     "epochs_per_call": args.epochs,
                     "epochs_per_s": args.runs * args.epochs / wall,
                     "bit_identical": not differ,
                     "partitioner": "shardy" if shardy else "gspmd",
                     "xla_flags": os.environ.get("XLA_FLAGS", "")})
        print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in rows[-1].items()},
              flush=True)
    if differ:
        print(f"not bit-identical: {differ}", flush=True)
    if not args.no_record:
        from benchmarks import harness

        harness.record("stream_mesh", rows, notes="R runs on D devices through one SPMD "
                       "program: one process with every device against one process per "
                       "device (jax.distributed); epochs/s over all runs, a timed call after "
                       "the fill; bit_identical: every run's metrics and learner parameters")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
