"""Test-session setup: two XLA:CPU devices, cheap XLA:CPU codegen and a shared XLA cache.

Two host devices let the default suite run the multi-device code (runs split across a mesh,
`tests/stream/test_stacked.py`) on a CPU-only machine; XLA reads its flags when the backend
starts, so they are set before JAX is imported. Single-device code is unaffected: arrays live
on device 0 unless a test shards them.

The suite's tests run small shapes for a few steps, so its wall time is XLA compilation, not
execution: LLVM's backend optimisation level 0 (XLA:CPU only; HLO passes are untouched, so
results are the same programs) cut the two-device stacked test from 234 s to 177 s with no step
measurably slower. The persistent cache is shared by the xdist workers of one run (keyed by
xdist's run id), so a program one worker compiled is read, not rebuilt, by the other.
"""

import os
import tempfile

_FLAGS = ("--xla_force_host_platform_device_count=2", "--xla_backend_optimization_level=0")
os.environ["XLA_FLAGS"] = " ".join([os.environ.get("XLA_FLAGS", ""), *_FLAGS]).strip()

import jax  # noqa: E402

_run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
_cache = (
    os.path.join(tempfile.gettempdir(), f"jaml-xla-cache-{_run}")
    if _run
    else tempfile.mkdtemp(prefix="jaml-xla-cache-")
)
# Each `relations.fit` builds fresh jitted closures; with a persistent cache the XLA
# compilation of an identical program is reused across fits and across the run's workers.
jax.config.update("jax_compilation_cache_dir", _cache)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
