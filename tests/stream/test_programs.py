"""A Stream owns the programs compiled for it (`Stream.jit`): they go, with their memory mappings,
when the Stream does (on XLA:CPU each kernel is mapped on its own, and a process that kept every
figure cell's programs ran out of mappings), and a driver keeps no Stream past its cell."""

import gc
import os
import weakref

import jax
import jax.numpy as jnp
import pytest

from jaml import stream
from jaml.experiments import _runs
from jaml.stream import loop
from jaml.stream import run as run_lib
from tests.stream.test_loop import tiny


def _program(st, x):
    # Sorts and scans between the elementwise steps keep XLA from fusing it into one kernel.
    for k in range(12):
        x = jnp.sort(jnp.sin(x * (k + st.config.learner_steps))) + jnp.cumsum(x) * 1e-3
    return x


def _mappings() -> int:
    with open("/proc/self/maps") as f:
        return sum(1 for _ in f)


@pytest.mark.skipif(not os.path.exists("/proc/self/maps"), reason="counts Linux mappings")
def test_a_streams_programs_and_their_memory_mappings_go_with_it():
    jax.jit(lambda x: jnp.sort(x) + 1)(jnp.ones(3)).block_until_ready()  # the runtime's own
    s = stream.build(tiny())
    before = _mappings()
    first = s.jit(_program)(jnp.ones(64)).block_until_ready()
    added = _mappings() - before
    assert added >= 30  # a few mappings per compiled kernel
    program = weakref.ref(s.jit(_program))
    del s  # no reference cycle: the programs go at once, not at the next garbage collection
    assert program() is None
    assert _mappings() - before < added / 3
    # Another Stream of the config compiles its own, to the same numbers.
    assert jnp.array_equal(stream.build(tiny()).jit(_program)(jnp.ones(64)), first)


def test_a_figure_cell_keeps_no_stream_even_when_it_fails(monkeypatch):
    built = []

    def build_runs(configs):
        built_stream, runs = loop.build_runs(configs)
        built_stream.jit(_program)  # a program of its own, which must not keep it either
        built.append(weakref.ref(built_stream))
        return built_stream, runs

    monkeypatch.setattr(run_lib, "build_runs", build_runs)
    monkeypatch.setattr(run_lib, "open_runs", lambda *_, **__: 1 / 0)
    with pytest.raises(ZeroDivisionError):
        _runs.train_seeds("cell", [tiny()], ["unused"])
    gc.collect()  # the exception's frames held it while it was raised
    assert len(built) == 1 and built[0]() is None
