"""A stream run's directory: its figures, drawn in the background."""

from pathlib import Path

import pytest

from jaml.stream import rundir


def test_figures_are_drawn_in_the_background_from_each_runs_newest_history(monkeypatch):
    """A request still queued behind a slow drawing is skipped for a newer one of the same run;
    every run's newest history is drawn; a drawing error surfaces at `check`."""
    import threading

    drawn, started, release = [], threading.Event(), threading.Event()

    def figures(history, out):
        if not drawn:
            started.set()
            release.wait(5)  # the first drawing is slow: the next requests queue behind it
        drawn.append((out, len(history)))

    monkeypatch.setattr(rundir, "_figures", figures)
    writer = rundir.FigureWriter()
    writer.submit(Path("a"), [{}])
    assert started.wait(5)
    for n in (2, 3):
        writer.submit(Path("a"), [{}] * n)
    writer.submit(Path("b"), [{}])
    release.set()
    writer.wait()
    writer.check()
    assert drawn == [(Path("a"), 1), (Path("a"), 3), (Path("b"), 1)]

    monkeypatch.setattr(rundir, "_figures", lambda history, out: 1 / 0)
    failing = rundir.FigureWriter()
    failing.submit(Path("a"), [])
    failing.wait()
    with pytest.raises(ZeroDivisionError):
        failing.check()
