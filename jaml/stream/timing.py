"""Wall time by phase, and its steady part: the wall time less what JAX spent compiling in it
(a run's deadline extrapolates steady time; `jaml.stream.run`)."""

from __future__ import annotations

import contextlib
import time

import jax

# What JAX reports of each compilation (`jax.monitoring`): tracing, lowering, XLA's compile.
_COMPILE_EVENTS = frozenset({"/jax/core/compile/jaxpr_trace_duration",
                             "/jax/core/compile/jaxpr_to_mlir_module_duration",
                             "/jax/core/compile/backend_compile_duration"})
_compile_seconds = [0.0]  # this process's compilation time so far
_listening = [False]


def _count_compile(event: str, seconds: float, **_) -> None:
    if event in _COMPILE_EVENTS:
        _compile_seconds[0] += seconds


class Stopwatch:
    """The wall time of a `with` block and its steady part: the wall time less what JAX spent
    compiling inside it (never below zero: threads compiling together count their sum)."""

    wall = steady = 0.0

    def __enter__(self) -> Stopwatch:
        if not _listening[0]:
            jax.monitoring.register_event_duration_secs_listener(_count_compile)
            _listening[0] = True
        self._tic, self._compiled = time.perf_counter(), _compile_seconds[0]
        return self

    def __exit__(self, *exc) -> None:
        self.wall = time.perf_counter() - self._tic
        self.steady = max(self.wall - (_compile_seconds[0] - self._compiled), 0.0)


@contextlib.contextmanager
def timed(seconds: dict[str, float], phase: str):
    """Adds the wall time of the block to seconds[phase]."""
    tic = time.perf_counter()
    try:
        yield
    finally:
        seconds[phase] = seconds.get(phase, 0.0) + time.perf_counter() - tic
