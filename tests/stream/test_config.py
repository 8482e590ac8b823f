"""A run's config: resolved whole into config.json, read back by resume, older files still read."""

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from envs_mjx.config import ALL_ENVS, FAMILIES, family
from jaml import stream
from jaml.learners.config import ALL_LEARNERS
from jaml.stream import run as run_lib
from jaml.stream.config import DOMAINS, changed_fields, recorded_env_options
from tests.stream.test_loop import tiny

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "results"
# "ENV/LEARNER" → the fields of `for_env(ENV, LEARNER)` that differ from
# `StreamConfig(env=ENV, learner=LEARNER)`, as `_settings` writes them.
FOR_ENV = json.loads((Path(__file__).parent / "for_env_expected.json").read_text())


def _settings(config: stream.StreamConfig) -> dict:
    base = stream.StreamConfig(env=config.env, learner=config.learner).to_dict()
    return {k: v for k, v in config.to_dict().items() if v != base[k]}


@pytest.mark.parametrize("env", ALL_ENVS)
def test_each_domain_and_learner_gets_the_settings_for_env_always_gave(env):
    """for_env_expected.json was written by `_settings(for_env(env, learner))` from the
    pre-change `for_env` (commit 1e0c628: an if/elif over the domain families), for every
    registered env and learner; the declared per-family table must give the same configs."""
    assert set(FOR_ENV) == {f"{e}/{x}" for e in ALL_ENVS for x in ALL_LEARNERS}
    for learner in ALL_LEARNERS:
        assert _settings(stream.for_env(env, learner)) == FOR_ENV[f"{env}/{learner}"], learner


def test_every_domain_names_a_family_and_every_family_has_settings():
    assert sorted(DOMAINS) == sorted(FAMILIES)
    assert {family(env) for env in ALL_ENVS} == set(FAMILIES)
    with pytest.raises(ValueError, match="unknown env 'Pendulum'"):
        stream.for_env("Pendulum")


def test_for_env_overrides_win_over_the_domains_and_keep_the_rest():
    config = stream.for_env("GeomOnIncline", "PRED", rollout_len=12, learner_overrides={
        "hist": 2, "beta": 3.0})
    expected = FOR_ENV["GeomOnIncline/PRED"]
    assert config.rollout_len == 12 and config.ppo.num_updates == expected["ppo"]["num_updates"]
    assert config.learner_overrides == {**expected["learner_overrides"], "hist": 2, "beta": 3.0}


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


def _fields(config) -> dict:
    return json.loads(json.dumps(dataclasses.asdict(config)))


def test_typed_learner_and_env_configs_become_the_overrides_that_give_them_back():
    base = stream.for_env("GeomOnIncline", "PRED")
    learner = base.learner_config(ld_dim=5).replace(beta=2.0)
    env = dataclasses.replace(base.env_config(), force_scale=3.0)
    config = base.with_configs(learner, env)
    assert config.learner_overrides == {**base.learner_overrides, "beta": 2.0}
    assert config.env_overrides == {"force_scale": 3.0}
    assert (config.learner_config(ld_dim=5), config.env_config()) == (learner, env)
    # A domain's setting put back to the learner's own default stays an override.
    back = base.with_configs(base.learner_config(ld_dim=5).replace(latent_dim=None))
    assert back.learner_overrides["latent_dim"] is None
    assert back.learner_config(ld_dim=5).latent_dim is None
    assert base.with_configs() == base
    assert changed_fields(env, base.env_config()) == {"force_scale": 3.0}
    assert changed_fields(env, env, keep=("ground",), skip=("force_scale",)) == {"ground": "paired"}


def test_a_run_records_its_learner_and_env_configs_whole_and_resume_checks_them(tmp_path):
    config = tiny("PRED", learner_overrides={"hist": 2, "pred": 2})
    built = stream.build(config)
    ld_dim = len(built.env.ld_state_names)
    assert not run_lib.claim_run(tmp_path, config, built)
    recorded = json.loads((tmp_path / "config.json").read_text())
    assert recorded["resolved"] == {"learner": _fields(config.learner_config(ld_dim)),
                                    "env": _fields(config.env_config())}
    assert recorded["resolved"]["learner"]["hist"] == 2
    assert recorded["resolved"]["learner"]["ld_dim"] == ld_dim
    assert stream.StreamConfig.from_dict(recorded) == config.resolved()
    assert run_lib.claim_run(tmp_path, config, built)  # a resume
    # A learner default changed since the run started: another run, though the overrides agree.
    changed = json.loads(json.dumps(recorded))
    changed["resolved"]["learner"]["beta"] = 2.0
    (tmp_path / "config.json").write_text(json.dumps(changed))
    with pytest.raises(ValueError, match="different configuration"):
        run_lib.claim_run(tmp_path, config, built)
    # A field new in the code is missing from the record: still the same run.
    del changed["resolved"]["learner"]["beta"], changed["resolved"]["env"]["multicolor"]
    (tmp_path / "config.json").write_text(json.dumps(changed))
    assert run_lib.claim_run(tmp_path, config, built)
    assert json.loads((tmp_path / "config.json").read_text()) == recorded  # written whole again


def test_a_committed_run_record_without_the_resolved_configs_resumes(tmp_path):
    recorded = json.loads((RESULTS / "fig3_ycb" / "VAE_rpl" / "seed_0" / "config.json")
                          .read_text())
    assert "resolved" not in recorded
    (tmp_path / "config.json").write_text(json.dumps(recorded))
    config = stream.StreamConfig.from_dict(recorded)
    built = SimpleNamespace(learner=SimpleNamespace(config=config.learner_config(ld_dim=53)),
                            env=SimpleNamespace(config=config.env_config()))
    assert run_lib.claim_run(tmp_path, config, built)
    assert json.loads((tmp_path / "config.json").read_text())["resolved"]["learner"][
        "latent_dim"] == 53


def test_a_records_env_options_are_its_resolved_env_config_else_its_overrides():
    old = {"env": "RearrangeGeom", "env_overrides": {"versions": [5]}}
    assert recorded_env_options(old) == {"versions": [5]}
    assert recorded_env_options({"env": "CartPole"}) == {}
    env = _fields(stream.StreamConfig(env="RearrangeGeom", env_overrides={"versions": (5,)})
                  .env_config())
    new = {**old, "env_overrides": {}, "resolved": {"env": {**env, "gone": 1}}}
    assert recorded_env_options(new) == env and env["versions"] == [5]


def test_every_committed_stream_run_config_reads_back():
    paths = [p for p in RESULTS.rglob("seed_*/config.json")]
    assert len(paths) > 100
    for path in paths:
        recorded = json.loads(path.read_text())
        config = stream.StreamConfig.from_dict(recorded)
        assert config.resolved().replay_columns == config.replay_columns, path
        assert config.to_dict() == {k: v for k, v in recorded.items() if k != "resolved"}, path
        # The typed configs its overrides give, every override applied.
        learner, env = config.learner_config(ld_dim=5), config.env_config()
        for typed, given in ((learner, config.learner_overrides), (env, config.env_overrides)):
            assert _fields(typed) == _fields(typed) | given, path
