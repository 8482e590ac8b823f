"""Every program compiled for a Stream, owned by a scope that releases them when it ends.

The stream's jitted functions take a Stream as a static argument, so what they compile is kept
per Stream. One `Programs` owns all of it: the jitted functions, the Streams that
`executor.build` made, and the multi-device loop's per-device executables. `scope()` opens a
fresh one for a block and releases it on leaving; outside every scope the process's own is
used. A driver that trains many configs one after another opens a scope per config: on XLA:CPU
each compiled kernel takes its own memory mappings, and a process that kept every config's
programs ran out of them (`vm.max_map_count`).
"""

from __future__ import annotations

import collections
import contextlib
import contextvars
import functools
from collections.abc import Callable, Iterator

import jax


class Programs:
    """The compiled programs of one scope: jitted functions by (function, options), built
    Streams by program, and per-device executables by (Stream, device, input avals)."""

    def __init__(self):
        self._jitted: dict = {}
        self.built: collections.OrderedDict = collections.OrderedDict()
        self.executables: dict = {}

    def jit(self, fun: Callable, **options) -> Callable:
        """`jax.jit(fun, **options)`, made once in this scope and kept with what it compiles."""
        key = (fun, _frozen(options))
        jitted = self._jitted.get(key)
        if jitted is None:
            jitted = self._jitted[key] = jax.jit(fun, **options)
        return jitted

    def cache_sizes(self) -> dict[str, int]:
        """How many programs each kind holds (compiled entries of the jitted functions)."""
        return {"jitted": sum(j._cache_size() for j in self._jitted.values()),
                "built": len(self.built), "executables": len(self.executables)}

    def release(self) -> None:
        """Drops every program held here; a Stream used again compiles again."""
        for jitted in self._jitted.values():
            jitted.clear_cache()
        self._jitted.clear()
        self.built.clear()
        self.executables.clear()


_PROCESS = Programs()
_CURRENT: contextvars.ContextVar[Programs] = contextvars.ContextVar("jaml_stream_programs",
                                                                   default=_PROCESS)


def current() -> Programs:
    """The innermost open scope's programs (the process's outside every scope)."""
    return _CURRENT.get()


@contextlib.contextmanager
def scope() -> Iterator[Programs]:
    """A block whose Streams compile into a fresh `Programs`, released when the block ends
    (normally or by an exception)."""
    programs = Programs()
    token = _CURRENT.set(programs)
    try:
        yield programs
    finally:
        _CURRENT.reset(token)
        programs.release()


def jitted(fun: Callable | None = None, /, **options) -> Callable:
    """`fun` under `jax.jit(fun, **options)`, compiled into the scope current at each call.
    Usable as `@jitted(static_argnums=0)`; `.lower(...)` lowers it the same way."""
    if fun is None:
        return functools.partial(jitted, **options)

    @functools.wraps(fun)
    def call(*args, **kwargs):
        return current().jit(fun, **options)(*args, **kwargs)

    call.lower = lambda *args, **kwargs: current().jit(fun, **options).lower(*args, **kwargs)
    return call


def _frozen(options: dict) -> tuple:
    """jit options as a hashable key (compiler_options is a dict)."""
    return tuple(sorted((k, tuple(sorted(v.items())) if isinstance(v, dict) else v)
                        for k, v in options.items()))
