"""The benchmark harness refuses results that name no commit, and writes those that do."""

import json

import pytest

from benchmarks import harness


def test_record_refuses_rows_without_a_commit_and_writes_rows_with_one(tmp_path, monkeypatch):
    env = {"device": "cpu:cpu", "device_count": 1, "cpu": "x", "cpu_cores": 2, "python": "3",
           "versions": {"jax": "0"}, "commit": "", "date": "2026-01-01T00:00:00+00:00"}
    monkeypatch.setattr(harness, "RESULTS_JSONL", tmp_path / "results.jsonl")
    monkeypatch.setattr(harness, "RESULTS_MD", tmp_path / "RESULTS.md")
    monkeypatch.setattr(harness, "environment", lambda: dict(env))
    with pytest.raises(ValueError, match="no commit"):
        harness.record("b", [{"case": "c", "wall_s": 1.0}])
    assert not (tmp_path / "results.jsonl").exists()
    env["commit"] = "abc1234"
    harness.record("b", [{"case": "c", "modelled_wall_s": 2.0}])
    row = json.loads((tmp_path / "results.jsonl").read_text())
    assert row["commit"] == "abc1234" and row["modelled_wall_s"] == 2.0
    assert "modelled_wall_s" in (tmp_path / "RESULTS.md").read_text()
