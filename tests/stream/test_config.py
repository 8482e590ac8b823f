"""A run's config: resolved whole into config.json, read back by resume, older files still read."""

import json
from pathlib import Path

import pytest

from jaml import stream
from jaml.stream import run as run_lib
from tests.stream.test_loop import tiny

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "results"


def test_the_replays_kept_share_is_the_streams_the_learners_default_unless_set():
    assert stream.StreamConfig(learner="VAE_v0").keep_fraction == 0.0
    assert stream.StreamConfig(learner="VAE_rpl").keep_fraction == 0.5
    assert stream.StreamConfig(learner="PRED").keep_fraction == 0.5
    assert stream.StreamConfig(learner="VAE_v0", replay_keep_fraction=0.25).keep_fraction == 0.25


def test_resolving_fills_the_derived_fields_once():
    config = tiny(learner="VAE_v0", replay_slots=None)
    resolved = config.resolved()
    assert (resolved.replay_slots, resolved.replay_keep_fraction) == (5000, 0.0)  # 625 × 8 envs
    assert resolved.resolved() == resolved
    assert (resolved.replay_columns, resolved.fill_epochs) == (config.replay_columns,
                                                                config.fill_epochs)
    # The same program whether a default is left to resolve or written out.
    assert resolved.program_key() == config.program_key()


def test_a_run_records_its_resolved_config_and_resumes_from_an_older_record(tmp_path):
    config = tiny()
    old = tmp_path / "old"
    old.mkdir()
    (old / "config.json").write_text(json.dumps(config.to_dict()))  # as older runs wrote it
    assert json.loads((old / "config.json").read_text())["replay_keep_fraction"] is None
    assert run_lib.claim_run(old, config)  # a resume of the same run
    recorded = json.loads((old / "config.json").read_text())
    assert recorded == config.resolved().to_dict() and recorded["replay_keep_fraction"] == 0.5
    assert stream.StreamConfig.from_dict(recorded).resolved() == config.resolved()
    with pytest.raises(ValueError, match="different configuration"):
        run_lib.claim_run(old, config.replace(replay_keep_fraction=0.25))
    assert not run_lib.claim_run(tmp_path / "new", config)


def test_every_committed_stream_run_config_reads_back():
    paths = [p for p in RESULTS.rglob("seed_*/config.json")]
    assert len(paths) > 100
    for path in paths:
        recorded = json.loads(path.read_text())
        config = stream.StreamConfig.from_dict(recorded)
        assert config.resolved().replay_columns == config.replay_columns, path
        assert config.to_dict() == json.loads(json.dumps(recorded)), path
