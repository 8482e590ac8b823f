"""Does XLA's GPU compiler take the stream's sharded program under Shardy? A check, not a timing.

One GPU poses as two hosts of one GPU each (JAX's mock GPU topology), so the compiler partitions
the same two-device program it would on two GPUs; with --real, a machine's two GPUs run it. Each
variant runs in its own process (a compiler crash kills it):

  repro_empty  the 6-line reproduction (docs/notes/stream.md): segfaults on jaxlib 0.11.2
  repro_full   the same with a non-empty array: compiles
  block_raw    the block with every state leaf crossing the shard_map: segfaults on 0.11.2
  block        executor.sharded_program as it ships: must compile
  run          that program run 3 epochs under Shardy and under GSPMD: the runs each process
               holds compared (device 0's under the mock, both devices' with --real)

    python benchmarks/shardy_gpu_check.py [--case CartPole/VAE_rpl] [--variants ...] [--real]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys

VARIANTS = ("repro_empty", "repro_full", "block_raw", "block", "run")


def variant(name: str, case: str, real: bool = False) -> str:
    """Compile (and for `run`, run) one variant in this process; what it found, in words."""
    import jax
    import jax.numpy as jnp
    import numpy as np
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as P

    if not real:
        jax.config.update("jax_mock_gpu_topology", "1x2x1")  # before the backend starts
    assert jax.device_count() >= 2, jax.devices()
    mesh = Mesh(np.asarray(jax.devices()[:2]), ("runs",))
    runs = NamedSharding(mesh, P("runs"))

    def abstract(tree):
        return jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=runs), tree)

    if name.startswith("repro_"):
        width = 0 if name == "repro_empty" else 2
        f = jax.jit(jax.shard_map(lambda a, b: (a * 2, b), mesh=mesh,
                                  in_specs=(P("runs"), P("runs")),
                                  out_specs=(P("runs"), P("runs")), check_vma=False))
        f.lower(*abstract((jnp.ones((4, 3)), jnp.zeros((4, width))))).compile()
        return "compiles"

    from jaml.configs.stream import scaled
    from jaml.stream import build, for_env
    from jaml.stream.executor import _block, sharded_program, stack_runs

    env, learner = case.split("/")
    stream = build(scaled(for_env(env, learner), "smoke"))
    states = stack_runs([stream.init(jax.random.PRNGKey(seed)) for seed in range(2)])
    n = jax.ShapeDtypeStruct((), jnp.int32, sharding=NamedSharding(mesh, P()))
    if name == "block_raw":
        f = jax.jit(jax.shard_map(lambda st, k: _block(stream, st, k), mesh=mesh,
                                  in_specs=(P("runs"), P()),
                                  out_specs=(P("runs"), P(None, "runs")), check_vma=False))
        f.lower(abstract(states), n).compile()
        return "compiles"
    if name == "block":
        sharded_program(stream).lower(mesh, abstract(states), n).compile()
        return "compiles"

    def run_three(use_shardy: bool):
        jax.config.update("jax_use_shardy_partitioner", use_shardy)  # in jit's cache key
        this = jax.tree.map(lambda x: jax.make_array_from_callback(
            x.shape, runs, lambda i: np.asarray(x)[i]), states)
        out = sharded_program(stream)(mesh, this, jnp.asarray(3, jnp.int32))
        return [np.asarray(s.data) for a in jax.tree.leaves(out) for s in a.addressable_shards]

    gspmd, shardy, again = run_three(False), run_three(True), run_three(True)

    def equal(a, b):
        return sum(np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b, strict=True))

    return (f"ran: Shardy vs GSPMD {equal(shardy, gspmd)} of {len(gspmd)} leaves bit-identical, "
            f"Shardy twice {equal(shardy, again)} of {len(gspmd)}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", default="CartPole/VAE_rpl", help="ENV/LEARNER (smoke scale)")
    parser.add_argument("--variants", nargs="+", default=VARIANTS, choices=VARIANTS)
    parser.add_argument("--one", help=argparse.SUPPRESS)  # a child: run this variant
    parser.add_argument("--timeout", type=float, default=300.0, help="seconds per variant")
    parser.add_argument("--real", action="store_true", help="two real GPUs, no mock topology")
    args = parser.parse_args(argv)
    if args.one:
        print("RESULT", variant(args.one, args.case, args.real), flush=True)
        return 0
    env = dict(os.environ, PYTHONFAULTHANDLER="1")
    if not args.real:  # else the mocked compile waits for the absent host's autotuning results
        env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " --xla_gpu_shard_autotuning=false").strip()
    for name in args.variants:
        try:
            done = subprocess.run([sys.executable, __file__, "--one", name, "--case", args.case]
                                  + ["--real"] * args.real,
                                  env=env, capture_output=True, text=True, timeout=args.timeout)
        except subprocess.TimeoutExpired:
            print(f"{name}: no answer in {args.timeout:.0f} s")
            continue
        said = [line[7:] for line in done.stdout.splitlines() if line.startswith("RESULT ")]
        crashed = "Segmentation fault" in done.stderr
        print(f"{name}: " + (said[0] if said else "segfault" if crashed
                             else f"failed (exit {done.returncode}): {done.stderr[-300:]}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
