"""Interrupts during runs: not lost when a callback swallows one, held while a checkpoint is
written, and a one-line message that gives the command that resumes."""

import logging
import os
import signal
import threading
import time

import jax.numpy as jnp
import pytest

from jaml import _interrupts
from jaml.stream import checkpoint

pytestmark = pytest.mark.skipif(threading.current_thread() is not threading.main_thread(),
                                reason="signal handlers need the main thread")


def test_a_swallowed_ctrl_c_is_raised_again_where_the_loop_checks():
    """Python ignores an exception raised in a gc callback (JAX has one): the signal is
    remembered and `raise_if_pending` raises it again; the handlers are restored after."""
    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    with _interrupts.as_interrupt():
        swallowed = []
        try:  # stands in for the callback that swallows the KeyboardInterrupt
            os.kill(os.getpid(), signal.SIGINT)  # the handler runs at the next bytecode
            time.sleep(5)
        except KeyboardInterrupt:
            swallowed.append(True)
        assert swallowed and _interrupts.pending()
        with pytest.raises(KeyboardInterrupt):
            _interrupts.raise_if_pending()
        assert not _interrupts.pending()
        _interrupts.raise_if_pending()  # nothing pending: no-op
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


@pytest.fixture
def default_sigint():
    """SIGINT raising KeyboardInterrupt, as in a terminal (pytest-xdist's workers ignore it)."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def test_ctrl_c_during_a_checkpoint_write_waits_for_it(tmp_path, monkeypatch, caplog,
                                                       default_sigint):
    """The interrupt lands inside Orbax's save: the step is still finalised (the latest on
    disk, the one a summary names), Orbax logs no error, then KeyboardInterrupt is raised."""
    mgr = checkpoint.manager(tmp_path)
    real_save = mgr.save

    def interrupted_save(step, **kwargs):
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C as the write starts
        return real_save(step, **kwargs)

    monkeypatch.setattr(mgr, "save", interrupted_save)
    with caplog.at_level(logging.ERROR), pytest.raises(KeyboardInterrupt):
        checkpoint.save(mgr, 4, {"a": jnp.arange(3.0)})
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
    mgr.reload()
    assert mgr.latest_step() == 4 and (tmp_path / "checkpoints" / "4").is_dir()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    mgr.close()
