"""The run's stopwatch: wall time and its steady part, without JAX's compilation."""

import time

import jax
import jax.numpy as jnp

from jaml.stream import timing


def test_the_deadlines_stopwatch_leaves_compilation_out_of_the_steady_time():
    """A block that compiles a fresh program and then sleeps: its wall time holds both, its
    steady time (what the deadline extrapolates) the sleep and not the compilation, which
    `jax.monitoring` reports; a block that compiles nothing is steady throughout."""
    def body(x):  # a scan of matmuls: a compile of tens of milliseconds
        return jax.lax.scan(lambda c, _: (jnp.tanh(c @ c.T) @ c, None), x, None, length=4)[0]

    with timing.Stopwatch() as compiling:
        jax.jit(body)(jnp.ones((16, 16))).block_until_ready()
        time.sleep(0.2)
    compile_seconds = compiling.wall - compiling.steady
    assert compile_seconds > 0.005
    assert 0.2 <= compiling.steady < compiling.wall
    with timing.Stopwatch() as steady:
        time.sleep(0.1)
    assert steady.steady == steady.wall >= 0.1
