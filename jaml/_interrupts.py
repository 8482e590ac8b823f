"""Interrupts (Ctrl-C, SIGTERM) for the runs: raised as KeyboardInterrupt, not lost when a
callback swallows one, and held while a checkpoint is written so that it is written whole.

Python ignores an exception raised inside a garbage-collection callback (JAX installs one), so
a Ctrl-C that lands there only prints "Exception ignored in …" and the run goes on; `pending`
remembers it for the run loop to raise again. A KeyboardInterrupt inside Orbax's save leaves
the step half-finalised and Orbax logs its own traceback; `held` delays the signal instead.
"""

from __future__ import annotations

import contextlib
import signal
import threading

_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_pending = threading.Event()


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def as_interrupt():
    """While the block runs, SIGINT and SIGTERM (`timeout`, a scheduler's preemption) raise
    KeyboardInterrupt and are remembered (`pending`), so that runs unwind through their
    `finally` blocks and write their summaries. Only the main thread installs handlers;
    elsewhere this does nothing."""
    if not _in_main_thread():
        yield
        return

    def interrupt(signum, frame):
        _pending.set()
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    previous = {s: signal.signal(s, interrupt) for s in _SIGNALS}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        _pending.clear()


def pending() -> bool:
    """Whether a signal arrived since the last `delivered` (under `as_interrupt`)."""
    return _pending.is_set()


def delivered() -> None:
    """The interrupt reached its handler: nothing is pending any more."""
    _pending.clear()


def raise_if_pending() -> None:
    """Raise the KeyboardInterrupt of a signal whose first one was swallowed (a gc callback)."""
    if _pending.is_set():
        _pending.clear()
        raise KeyboardInterrupt("interrupted")


@contextlib.contextmanager
def held():
    """SIGINT and SIGTERM that arrive in the block take effect when it ends (their handlers as
    before, the signal raised again): a checkpoint is finalised rather than cut off. Only the
    main thread installs handlers; elsewhere this does nothing."""
    if not _in_main_thread():
        yield
        return
    got: list[int] = []
    previous = {s: signal.signal(s, lambda signum, frame: got.append(signum)) for s in _SIGNALS}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        if got:
            signal.raise_signal(got[0])
