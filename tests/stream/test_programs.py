"""The programs compiled for a Stream belong to a scope (`stream.programs_scope`): what is built
and compiled inside one is kept there, and leaving it gives the programs and their memory
mappings back (on XLA:CPU each kernel is mapped on its own, and a process that kept every
cell's programs ran out of mappings)."""

import os

import jax
import jax.numpy as jnp
import pytest

from jaml import stream
from jaml.experiments import _runs
from jaml.stream import programs
from tests.stream.test_loop import tiny


@programs.jitted(static_argnums=0)
def _program(st, x):
    # Sorts and scans between the elementwise steps keep XLA from fusing it into one kernel.
    for k in range(12):
        x = jnp.sort(jnp.sin(x * (k + st.config.learner_steps))) + jnp.cumsum(x) * 1e-3
    return x


def _mappings() -> int:
    with open("/proc/self/maps") as f:
        return sum(1 for _ in f)


@pytest.mark.skipif(not os.path.exists("/proc/self/maps"), reason="counts Linux mappings")
def test_leaving_a_scope_drops_its_programs_and_their_memory_mappings():
    outside = programs.current()
    before_outside = outside.cache_sizes()
    with stream.programs_scope() as scope:
        assert programs.current() is scope and scope is not outside
        s = stream.build(tiny())
        assert list(scope.built.values()) == [s]
        before = _mappings()
        first = _program(s, jnp.ones(64)).block_until_ready()
        jitted = scope.jit(_program.__wrapped__, static_argnums=0)
        assert jitted._cache_size() == 1 and scope.cache_sizes()["jitted"] == 1
        added = _mappings() - before
        assert added >= 30  # a few mappings per compiled kernel
    assert programs.current() is outside and outside.cache_sizes() == before_outside
    assert scope.cache_sizes() == {"jitted": 0, "built": 0, "executables": 0}
    assert jitted._cache_size() == 0
    assert _mappings() - before < added / 3
    # The Stream still runs after its scope: it compiles again, in the scope current then.
    with stream.programs_scope() as again:
        assert jnp.array_equal(_program(s, jnp.ones(64)), first)
        assert again.cache_sizes()["jitted"] == 1


def test_scopes_nest_and_release_on_an_exception():
    with stream.programs_scope() as outer:
        s = stream.build(tiny())
        with pytest.raises(RuntimeError, match="inside"), stream.programs_scope() as inner:
            assert stream.build(tiny(seed=3)) is not s  # another scope, another Stream
            assert len(inner.built) == 1
            raise RuntimeError("inside")
        assert inner.cache_sizes()["built"] == 0
        assert programs.current() is outer
        # Within one scope, another seed's config shares the Stream's parts (and programs).
        assert stream.build(tiny(seed=3)) == s and len(outer.built) == 1


def test_a_figure_cell_releases_its_programs_even_when_it_fails(monkeypatch):
    seen = []

    def failing_run_many(configs, *args, **kwargs):
        seen.append(programs.current())
        stream.build(configs[0])
        raise RuntimeError("a run failed")

    monkeypatch.setattr("jaml.stream.run.run_many", failing_run_many)
    with pytest.raises(RuntimeError, match="a run failed"):
        _runs.train_seeds("cell", [tiny()], ["unused"])
    assert seen and seen[0] is not programs.current()
    assert seen[0].cache_sizes() == {"jitted": 0, "built": 0, "executables": 0}


def test_jitted_is_jax_jit_in_the_current_scope():
    f = programs.jitted(lambda n, x: x * n, static_argnums=0)
    with stream.programs_scope() as scope:
        assert int(f(3, jnp.int32(2))) == 6
        assert f(2, 1.0) == jax.jit(lambda n, x: x * n, static_argnums=0)(2, 1.0)
        assert scope.cache_sizes()["jitted"] == 2
        assert f.lower(3, jnp.int32(2)).compile()(jnp.int32(2)) == 6
