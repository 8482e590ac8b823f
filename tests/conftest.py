"""Test-session setup: a persistent XLA cache so identical programs compile once per run."""

import tempfile

import jax

# Each `relations.fit` builds fresh jitted closures; with a persistent cache the XLA
# compilation of an identical program is reused across fits within (and between) runs.
jax.config.update("jax_compilation_cache_dir", tempfile.mkdtemp(prefix="jaml-xla-cache-"))
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
