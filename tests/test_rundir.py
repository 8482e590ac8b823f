"""The run directory shared by `jaml relations` and `jaml suite`: config claim and refusal,
logs cut back to the checkpoint on resume."""

import json

import pytest

from jaml import _rundir


def test_claim_creates_then_resumes_and_refuses_another_config(tmp_path):
    out = tmp_path / "a" / "run"
    assert _rundir.claim(out, {"lr": 1e-3, "widths": [8, 8]}) is False
    assert json.loads((out / "config.json").read_text()) == {"lr": 1e-3, "widths": [8, 8]}
    assert _rundir.claim(out, {"lr": 1e-3, "widths": [8, 8]}) is True
    with pytest.raises(ValueError, match="holds a run with a different configuration"):
        _rundir.claim(out, {"lr": 1e-4, "widths": [8, 8]})
    assert json.loads((out / "config.json").read_text())["lr"] == 1e-3  # left as it was
    assert not list(out.glob("*.tmp"))


def test_run_log_keeps_the_records_up_to_the_checkpoint(tmp_path):
    log = _rundir.RunLog(tmp_path)
    for epoch in (1, 2, 3):
        log.record({"epoch": epoch, "loss": 1.0 / epoch})
    log.scalars({"loss": 0.5, "bad": float("nan")}, 3)
    log.close()
    log = _rundir.RunLog(tmp_path, keep=lambda r: r["epoch"] <= 2)  # resumed at epoch 2
    log.record({"epoch": 3, "loss": 0.25})
    log.close()
    lines = [json.loads(x) for x in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert lines == [{"epoch": 1, "loss": 1.0}, {"epoch": 2, "loss": 0.5},
                     {"epoch": 3, "loss": 0.25}]
    assert _rundir.truncate_jsonl(tmp_path / "missing.jsonl", lambda r: True) == []
