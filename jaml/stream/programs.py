"""The programs compiled for a Stream, and releasing them (`release_programs`).

The stream's jitted functions take the Stream as a static argument, so each keeps, for the life
of the process, what it compiled for every Stream it was called with: a later call with an
equal Stream (the same config, any seed) runs without compiling. A process that trains many
cells one after another (the Fig. 2 / Fig. 3 drivers) would keep every cell's programs.

On XLA:CPU that ends the process. Each compiled kernel is mapped into memory on its own (code,
constants and data: three mappings per kernel), and Linux allows a process `vm.max_map_count`
mappings (65 530 by default). Measured on the 2-core CPU (jaxlib 0.10.2, two host devices, the
slow Fig. 3 test, two tiny RearrangeGeom cells in one process): during the second cell the
process reached 63 843 mappings, XLA failed to map the next program ("LLVM compilation error:
Cannot allocate memory") and aborted; with each cell's programs released it peaked at 38 890.

`release_programs` drops what the jitted functions keyed on a Stream hold, and the executables
`build`'s Streams keep per device; the next call compiles again (or reads JAX's persistent
compilation cache, where one is configured).
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax

# Every jitted function whose static arguments include a Stream: cleared by `release_programs`.
_KEYED: list = []
# What else holds programs (`loop`'s kept Streams): called by `release_programs` after the clear.
_RELEASES: list[Callable[[], None]] = []


def stream_jit(fun: Callable | None = None, /, **options):
    """`jax.jit(fun, **options)` for a function keyed on a Stream, cleared by
    `release_programs`. Usable as `@stream_jit(static_argnums=0)`."""
    if fun is None:
        return functools.partial(stream_jit, **options)
    jitted = jax.jit(fun, **options)
    _KEYED.append(jitted)
    return jitted


def release_programs() -> None:
    """Drops every program compiled for a Stream in this process.

    Call it between experiments that share no Stream, e.g. after each cell of a grid (the
    figure drivers do). A Stream still in use compiles its programs again at its next call."""
    for jitted in _KEYED:
        jitted.clear_cache()
    for release in _RELEASES:
        release()


def on_release(release: Callable[[], None]) -> Callable[[], None]:
    """Registers `release` (no arguments) to run at every `release_programs`, for a module that
    keeps programs of its own (`loop.forget_built`); usable as a decorator."""
    _RELEASES.append(release)
    return release
