"""`jaml relations` says what it resumed from, and an interrupt is recorded as "interrupted"."""

import json
import os
import signal
import threading

import pytest

from jaml.cli import main


def test_a_resumed_relations_run_says_what_it_resumed_from(tmp_path, capsys):
    args = ["relations", "--source", "ellipse", "--max-relations", "1", "--no-progress",
            "--out", str(tmp_path)]
    assert main(args) == 0
    assert "resumed" not in capsys.readouterr().err
    assert main(args) == 0
    assert (f"{tmp_path}: resumed from its checkpoint with 1 of 1 relations"
            in capsys.readouterr().err)


def test_an_interrupted_relations_run_is_recorded_as_interrupted(tmp_path, capsys):
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers need the main thread")
    timer = threading.Timer(4.0, os.kill, (os.getpid(), signal.SIGTERM))
    timer.start()
    try:
        code = main(["relations", "--source", "ellipse", "--max-relations", "4",
                     "--no-progress", "--out", str(tmp_path)])
    finally:
        timer.cancel()
    assert code == 130
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    assert "interrupted" in capsys.readouterr().err
