"""`jaml relations` says what it resumed from, and an interrupt is recorded as "interrupted"."""

import json

from jaml.cli import main


def test_a_finished_relations_run_started_again_says_so(tmp_path, capsys):
    """(What an interrupted run resumes from: tests/relations/test_run.py.)"""
    args = ["relations", "--source", "ellipse", "--max-relations", "1", "--no-progress",
            "--out", str(tmp_path)]
    assert main(args) == 0
    assert "finished" not in capsys.readouterr().err
    assert main(args) == 0
    assert (f"{tmp_path}: finished (done) before; nothing to train"
            in capsys.readouterr().err)


def test_an_interrupted_relations_run_is_recorded_as_interrupted(tmp_path, capsys, monkeypatch):
    """Ctrl-C (or the SIGTERM the CLI turns into one) while a relation trains: exit 130, the
    summary says "interrupted". Raised from inside the fit, so no timing decides where it lands."""
    from jaml.relations import run as run_lib

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(run_lib, "fit", interrupted)
    code = main(["relations", "--source", "ellipse", "--max-relations", "4", "--no-progress",
                 "--out", str(tmp_path)])
    assert code == 130
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    assert "interrupted" in capsys.readouterr().err
