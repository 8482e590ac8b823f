"""The benchmark harness every subsystem uses.

`measure` reports compile time apart from steady state: the first call (tracing + XLA compile +
one run) is timed on its own, then `repeats` blocked calls give the median. `record` appends one
JSON line per result to `benchmarks/results.jsonl` with the device and library versions, and
regenerates `benchmarks/RESULTS.md` from it. Absolute times hold only for the device they ran on.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

from jaml import _huge_pages

HERE = Path(__file__).resolve().parent
# JAML_BENCH_RESULTS redirects the raw results (e.g. to a remote machine's output folder); the
# RESULTS.md made from them goes beside them, so a redirected run leaves the checkout's alone.
RESULTS_JSONL = Path(os.environ.get("JAML_BENCH_RESULTS", HERE / "results.jsonl"))
RESULTS_MD = RESULTS_JSONL.with_name("RESULTS.md")
PACKAGES = ("jax", "jaxlib", "flax", "optax", "mujoco", "mujoco-mjx", "brax", "torch")


def block(value):
    """Wait for every array in a pytree (JAX or torch) to be computed."""
    import jax

    for leaf in jax.tree.leaves(value):
        if hasattr(leaf, "block_until_ready"):
            leaf.block_until_ready()
        elif type(leaf).__module__.startswith("torch") and getattr(leaf, "is_cuda", False):
            import torch

            torch.cuda.synchronize()
    return value


def measure(fn: Callable, *args, repeats: int = 5, warmup: int = 1) -> dict:
    """Time `fn(*args)`: {"compile_s", "median_s", "min_s", "max_s", "repeats"}.

    The first call is reported as compile time (it includes one execution); `warmup - 1`
    further calls are discarded; then `repeats` calls are each blocked until done.
    """
    start = time.perf_counter()
    block(fn(*args))
    compile_s = time.perf_counter() - start
    for _ in range(max(warmup - 1, 0)):
        block(fn(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        block(fn(*args))
        times.append(time.perf_counter() - start)
    return {
        "compile_s": compile_s,
        "median_s": statistics.median(times),
        "min_s": min(times),
        "max_s": max(times),
        "repeats": repeats,
    }


def measure_calls(fn: Callable, args: tuple, reps: int, steps: int) -> tuple[float, float, object]:
    """`jax.jit(fn)` on `args`: (compile seconds, steady-state seconds per call, an output).
    Compiled ahead, run once, then the median over `reps` blocked blocks of `steps` calls each:
    for kernels short enough that one blocked call would time its dispatch."""
    import jax

    start = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - start
    out = block(compiled(*args))
    times = []
    for _ in range(reps):
        start = time.perf_counter()
        for _ in range(steps):
            out = compiled(*args)
        block(out)
        times.append((time.perf_counter() - start) / steps)
    return compile_s, statistics.median(times), out


def form_row(case: str, impl: str, fn: Callable, args: tuple, cotangent, reps: int, steps: int,
             wrt: tuple[int, ...] | None = None) -> dict:
    """One formulation of a layer timed as training runs it: `fn`'s value and its gradients for
    `args` (those at `wrt`; all by default) under `cotangent`, jitted, steady state
    (`measure_calls`); the row {"case", "impl", "us_per_step", "compile_s"}, also printed."""
    import jax

    def step(*a):
        y, vjp = jax.vjp(fn, *a)
        grads = vjp(cotangent)
        return y, grads if wrt is None else tuple(grads[i] for i in wrt)

    compile_s, seconds, _ = measure_calls(step, args, reps, steps)
    print(f"{case:40s} {impl:28s} {1e6 * seconds:9.1f} µs (compile {compile_s:.1f} s)",
          flush=True)
    return {"case": case, "impl": impl, "us_per_step": 1e6 * seconds, "compile_s": compile_s}


def tree_digest(tree, digits: int = 16) -> str:
    """SHA-256 of a pytree's leaves' bytes in tree order (a dict's keys sorted), its first
    `digits` hex digits: the same digest, the same bits, as far as the digits tell."""
    import jax
    import numpy as np

    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(jax.device_get(tree)):
        digest.update(np.ascontiguousarray(leaf).tobytes())
    return digest.hexdigest()[:digits]


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity, so `taskset -c 0` counts 1), where
    `os.cpu_count()` counts the machine's."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # no affinity on this platform
        return os.cpu_count() or 1


def git_commit(directory: Path, ignore: tuple[str, ...] = ()) -> str:
    """The short HEAD of the checkout holding `directory`, with "+dirty" when tracked files have
    uncommitted changes (the commit alone does not name the code), "" without git. `ignore`:
    paths relative to `directory` whose changes do not count, the harness's own outputs, which
    the first rows of a run change before the later rows are recorded."""
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=directory, text=True, capture_output=True,
                              check=False).stdout.strip()

    try:
        commit = git("rev-parse", "--short", "HEAD")
        exclude = [f":(exclude){path}" for path in ignore]
        if commit and git("status", "--porcelain", "--untracked-files=no", "--", ":(top)",
                          *exclude):
            commit += "+dirty"
    except OSError:
        return ""
    return commit


def environment() -> dict:
    """Device, host and library versions for a results record."""
    import jax

    versions = {}
    for name in PACKAGES:
        with contextlib.suppress(metadata.PackageNotFoundError):
            versions[name] = metadata.version(name)
    device = jax.devices()[0]
    # JAML_COMMIT names the commit where the checkout's git does not (a copied working tree on a
    # remote machine can carry a stale .git).
    outputs = ("results.jsonl", "RESULTS.md")
    commit = os.environ.get("JAML_COMMIT") or git_commit(HERE, ignore=outputs)
    return {
        "device": f"{device.platform}:{getattr(device, 'device_kind', '')}",
        "device_count": jax.device_count(),
        "cpu": _cpu_model(),
        "cpu_cores": os.cpu_count(),
        # A pinned run (taskset) uses fewer; XLA:CPU sizes its thread pool by this too.
        "cpu_affinity": usable_cores(),
        "python": platform.python_version(),
        # glibc's malloc tunables (jaml._huge_pages: huge pages or 4 KiB ones on a CPU step).
        "glibc_tunables": os.environ.get("GLIBC_TUNABLES", ""),
        "versions": versions,
        "commit": commit,
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
    }


def parse_env(spec: str) -> tuple[str, dict]:
    """"RearrangeGeom:arm=franka,version=3" → ("RearrangeGeom", {"arm": "franka", "version": 3}):
    a domain with config overrides (numbers parsed as JSON, the rest kept as strings)."""
    name, _, opts = spec.partition(":")
    overrides = {}
    for item in filter(None, opts.split(",")):
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"env option {item!r} in {spec!r} is not KEY=VALUE")
        try:
            overrides[key] = json.loads(value)
        except json.JSONDecodeError:
            overrides[key] = value
    return name, overrides


def child_result(script: str, *args: str) -> dict:
    """The JSON a benchmark script prints on its stdout's last line, run with `args` in a new
    Python process; RuntimeError with the status and stderr's last line if it fails."""
    out = subprocess.run([sys.executable, script, *args], capture_output=True, text=True)
    if out.returncode:
        last = (out.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"its process exited with status {out.returncode}: {last[:160]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def record(benchmark: str, rows: list[dict], notes: str = "") -> None:
    """Append result rows (each a dict with at least "case") and rebuild RESULTS.md.

    A result must name the code it measured: without a commit (no git checkout and no
    JAML_COMMIT) nothing is recorded."""
    env = environment()
    if not env["commit"]:
        raise ValueError("no commit to record these results against: run from a git checkout "
                         "or set JAML_COMMIT to the commit the working tree holds")
    with RESULTS_JSONL.open("a") as f:
        for row in rows:
            f.write(json.dumps({"benchmark": benchmark, **env, **row, "notes": notes}) + "\n")
    write_markdown()


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, list) and value and all(isinstance(v, float) for v in value):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    return str(value)


def _identity(row: dict) -> tuple:
    """What a result is a result of: rows that share it supersede one another in RESULTS.md.

    Beside the benchmark, case and implementation: the device (for a CPU, its model: two CPU
    machines both read "cpu:cpu"; and whether malloc used huge pages) and its host's core
    count, and the settings a benchmark varies within one case (stacked runs, devices,
    batch), so that a later row at other settings does not hide an earlier one. A row from
    before a benchmark recorded runs and devices ran one run on one device, and one from before
    it recorded its affinity could run on every core (a pinned run, `taskset`, stands beside
    the unpinned one)."""
    device = row["device"]
    machine = (row.get("cpu"), _huge_pages_row(row)) if device.startswith("cpu") else None
    return (row["benchmark"], row["case"], row.get("impl", ""), device, machine,
            row.get("cpu_cores"), _affinity(row), row.get("runs", 1), row.get("devices", 1),
            row.get("batch"))


def _huge_pages_row(row: dict) -> bool:
    """Whether malloc asked for huge pages in a row's process: a CPU step's rate moves with it,
    so those rows stand beside the 4 KiB ones (rows from before it was recorded had 4 KiB)."""
    return f"{_huge_pages.TUNABLE}=1" in row.get("glibc_tunables", "")


def _affinity(row: dict):
    return row.get("cpu_affinity", row.get("cpu_cores"))


def write_markdown() -> None:
    """RESULTS.md: the latest result per `_identity` (benchmark, case, impl, device, settings),
    grouped by benchmark."""
    if not RESULTS_JSONL.exists():
        return
    latest: dict = {}
    for line in RESULTS_JSONL.read_text().splitlines():
        if line.strip():
            row = json.loads(line)
            latest[_identity(row)] = row
    lines = [
        "# Benchmark results",
        "",
        "Generated by `benchmarks/harness.py` from `results.jsonl` (latest run per case, "
        "device and settings). Times are medians of blocked repetitions, compile time apart. "
        "Absolute numbers hold only for the device named. Columns named `modelled_…` are "
        "computed, not measured (e.g. a peer's step count times its measured steps/s), and "
        "ratios against them are named so too.",
        "",
        "Experiment results (not timings): "
        "[Fig. 2, the paper-scale grid](../docs/results/fig2.md), "
        "[Fig. 9](../docs/results/fig9.md); "
        "what the learning-loop figures mean: [docs/stream.md](../docs/stream.md#speed).",
        "",
    ]
    env_keys = {
        "benchmark",
        "device",
        "device_count",
        "cpu",
        "cpu_cores",
        "cpu_affinity",
        "python",
        "glibc_tunables",
        "versions",
        "commit",
        "date",
        "notes",
        "case",
        "impl",
    }
    for bench in sorted({k[0] for k in latest}):
        rows = [r for k, r in latest.items() if k[0] == bench]
        lines += [f"## {bench}", ""]
        for note in sorted({r["notes"] for r in rows if r.get("notes")}):
            lines += [note, ""]
        columns = sorted({c for r in rows for c in r if c not in env_keys})
        lines.append("| case | impl | device | " + " | ".join(columns) + " | versions, date |")
        lines.append("|" + "---|" * (len(columns) + 4))
        for r in sorted(rows, key=lambda r: (r["device"], r["case"], r.get("impl", ""))):
            v = r.get("versions", {})
            commit = r.get("commit") or "no commit recorded"
            stamp = f"jax {v.get('jax', '?')}, {r['date'][:10]}, {commit}"
            if r["device"].startswith("cpu"):
                device = f"{r['device']} ({r['cpu_cores']} cores {r['cpu']})"
                if _affinity(r) != r["cpu_cores"]:
                    device += f", pinned to {_affinity(r)}"
                if _huge_pages_row(r):
                    device += ", malloc on huge pages"
            else:  # the host: rows of one GPU model on different machines stay told apart
                count = r.get("device_count", 1)
                device = (f"{r['device']} ({count} GPU{'s' * (count > 1)}, host of "
                          f"{r['cpu_cores']} cores)")
            lines.append(
                f"| {r['case']} | {r.get('impl', '')} | {device} | "
                + " | ".join(_fmt(r.get(c, "")) for c in columns)
                + f" | {stamp} |"
            )
        lines.append("")
    RESULTS_MD.write_text("\n".join(lines))


if __name__ == "__main__":
    write_markdown()
