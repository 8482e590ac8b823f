"""Releasing the programs compiled for a Stream (`stream.release_programs`): every jitted
function keyed on a Stream is registered, releasing empties their caches and `build`'s kept
Streams, and the executables' memory mappings go back to the system (on XLA:CPU each kernel is
mapped on its own, and a process that kept every cell's programs ran out of mappings)."""

import os

import jax
import jax.numpy as jnp
import pytest

from jaml import stream
from jaml.experiments import _runs
from jaml.stream import analysis, loop, programs
from tests.stream.test_loop import tiny


def _module_jits(module) -> list:
    """The module's own module-level jitted functions (what `jax.jit` returns)."""
    return [value for name, value in vars(module).items()
            if hasattr(value, "clear_cache") and hasattr(value, "lower")
            and getattr(value, "__module__", module.__name__) == module.__name__]


def test_every_jitted_function_keyed_on_a_stream_is_released():
    jits = _module_jits(loop) + _module_jits(analysis)
    assert len(jits) >= 10  # the loop's epochs/act/learn programs and the analysis' rollouts
    keyed = {id(j) for j in programs._KEYED}
    assert [j for j in jits if id(j) not in keyed] == []
    # The learner-options variants are made at first use; they are registered too.
    made = loop._with_learner_options(loop._block)
    assert id(made) in {id(j) for j in programs._KEYED}


def _mappings() -> int:
    with open("/proc/self/maps") as f:
        return sum(1 for _ in f)


@pytest.mark.skipif(not os.path.exists("/proc/self/maps"), reason="counts Linux mappings")
def test_release_drops_compiled_programs_and_their_memory_mappings():
    s = loop.build(tiny())
    assert any(v is s for v in loop._BUILT.values())
    s.programs["device", "avals"] = "an executable"

    @programs.stream_jit(static_argnums=0)
    def program(st, x):
        # Sorts and scans between the elementwise steps keep XLA from fusing it into one kernel.
        for k in range(12):
            x = jnp.sort(jnp.sin(x * (k + st.config.learner_steps))) + jnp.cumsum(x) * 1e-3
        return x

    try:
        before = _mappings()
        program(s, jnp.ones(64)).block_until_ready()
        added = _mappings() - before
        assert added >= 30  # a few mappings per compiled kernel
        assert program._cache_size() == 1
        stream.release_programs()
        assert program._cache_size() == 0
        assert _mappings() - before < added / 3
        assert loop._BUILT == {} and s.programs == {}
        # A released Stream still runs: it compiles again.
        assert jnp.allclose(program(s, jnp.ones(64)), program(loop.build(tiny()), jnp.ones(64)))
    finally:
        programs._KEYED.remove(program)


def test_a_figure_cell_releases_its_programs_even_when_it_fails(monkeypatch):
    released = []
    monkeypatch.setattr("jaml.stream.release_programs", lambda: released.append(True))

    def failing_run_many(*args, **kwargs):
        raise RuntimeError("a run failed")

    monkeypatch.setattr("jaml.stream.run.run_many", failing_run_many)
    with pytest.raises(RuntimeError, match="a run failed"):
        _runs.train_seeds("cell", [tiny()], ["unused"])
    assert released == [True]


def test_stream_jit_is_jax_jit():
    f = programs.stream_jit(lambda n, x: x * n, static_argnums=0)
    try:
        assert int(f(3, jnp.int32(2))) == 6
        assert f(2, 1.0) == jax.jit(lambda n, x: x * n, static_argnums=0)(2, 1.0)
    finally:
        programs._KEYED.remove(f)
