"""Test-session setup: two XLA:CPU devices and a persistent XLA cache.

Two host devices let the default suite run the multi-device code (runs split across a mesh,
`tests/stream/test_stacked.py`) on a CPU-only machine; XLA reads the flag when its backend
starts, so it is set before JAX is imported. Single-device code is unaffected: arrays live on
device 0 unless a test shards them.
"""

import os
import tempfile

_TWO_DEVICES = "--xla_force_host_platform_device_count=2"
os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_TWO_DEVICES}".strip()

import jax  # noqa: E402

# Each `relations.fit` builds fresh jitted closures; with a persistent cache the XLA
# compilation of an identical program is reused across fits within (and between) runs.
jax.config.update("jax_compilation_cache_dir", tempfile.mkdtemp(prefix="jaml-xla-cache-"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
