"""A run's config: one typed tree, resolved whole into config.json, read back by resume, older
(flat) records still read."""

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from envs_mjx.config import ALL_ENVS, FAMILIES, default_config, family
from jaml import stream
from jaml.learners import config as learners_config
from jaml.learners.config import ALL_LEARNERS
from jaml.stream import run as run_lib
from jaml.stream.config import (
    DOMAINS,
    FLAT_FIELDS,
    LEGACY_EVAL_FIELDS,
    LEGACY_LEARNER_FIELDS,
    changed_fields,
)
from tests.stream.test_loop import tiny

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "results"
# "ENV/LEARNER" → the fields of `for_env(ENV, LEARNER)` that differ from
# `StreamConfig(env=ENV, learner=LEARNER)`, in the flat form `_flat` writes.
FOR_ENV = json.loads((Path(__file__).parent / "for_env_expected.json").read_text())
# "ENV/LEARNER" → what `for_env(ENV, LEARNER)` resolved to before the config became a typed
# tree (#45; commit c2137d0, from the flat config with learner_overrides / env_overrides): its
# resolved stream fields (flat names) with the replay's columns, kept share and fill epochs, and
# its learner config (at ld_dim 7) and env config, whole, with their classes.
RESOLVED = json.loads((Path(__file__).parent / "resolved_expected.json").read_text())


def _fields(config) -> dict:
    return json.loads(json.dumps(dataclasses.asdict(config)))


def _flat(config: stream.StreamConfig) -> dict:
    """`config` in the flat form of records written before the tree: its sizes by their flat
    names (`FLAT_FIELDS`), the learner's and env's fields that differ from their defaults as
    learner_overrides / env_overrides."""
    d = config.to_dict()
    flat = {k: v for k, v in d.items()
            if k not in ("replay", "eval", "learner_config", "env_config")}
    for name, path in FLAT_FIELDS.items():
        part, field = path.split(".")
        flat[name] = d[part][field]
    plain = stream.StreamConfig(env=config.env, learner=config.learner)
    for part in ("learner", "env"):
        flat[f"{part}_overrides"] = json.loads(json.dumps(changed_fields(
            getattr(config, f"{part}_config"), getattr(plain, f"{part}_config"))))
    return flat


def _settings(config: stream.StreamConfig) -> dict:
    base = _flat(stream.StreamConfig(env=config.env, learner=config.learner))
    return {k: v for k, v in _flat(config).items() if v != base[k]}


@pytest.mark.parametrize("env", ALL_ENVS)
def test_each_domain_and_learner_gets_the_settings_for_env_always_gave(env):
    """for_env_expected.json was written by `_settings(for_env(env, learner))` from the
    pre-change `for_env` (commit 1e0c628: an if/elif over the domain families), for every
    registered env and learner; the declared per-family table must give the same configs."""
    assert set(FOR_ENV) == {f"{e}/{x}" for e in ALL_ENVS for x in ALL_LEARNERS}
    for learner in ALL_LEARNERS:
        assert _settings(stream.for_env(env, learner)) == FOR_ENV[f"{env}/{learner}"], learner


@pytest.mark.parametrize("env", ALL_ENVS)
def test_each_env_and_learner_resolves_to_the_values_the_flat_config_gave(env):
    """The tree, resolved, holds every value the flat config's resolution gave (the table was
    frozen from it before the change), learner and env configs whole."""
    assert set(RESOLVED) == {f"{e}/{x}" for e in ALL_ENVS for x in ALL_LEARNERS}
    for learner in ALL_LEARNERS:
        config = stream.for_env(env, learner)
        resolved = config.resolved(ld_dim=7)
        flat = _flat(resolved)
        del flat["learner_overrides"], flat["env_overrides"]
        got = {
            "stream": flat | {"replay_columns": resolved.replay.slots,
                              "keep_fraction": resolved.replay.keep_fraction,
                              "fill_epochs": config.fill_epochs},
            "learner": _fields(resolved.learner_config)
            | {"class": type(resolved.learner_config).__name__},
            "env": _fields(resolved.env_config) | {"class": type(resolved.env_config).__name__},
        }
        assert got == RESOLVED[f"{env}/{learner}"], learner


def test_every_domain_names_a_family_and_every_family_has_settings():
    assert sorted(DOMAINS) == sorted(FAMILIES)
    assert {family(env) for env in ALL_ENVS} == set(FAMILIES)
    with pytest.raises(ValueError, match="unknown env 'Pendulum'"):
        stream.for_env("Pendulum")


def test_for_env_overrides_win_over_the_domains_and_keep_the_rest():
    config = stream.for_env("GeomOnIncline", "PRED", {
        "rollout_len": 12, "learner_config.hist": 2, "learner_config.beta": 3.0})
    expected = FOR_ENV["GeomOnIncline/PRED"]
    assert config.rollout_len == 12 and config.ppo.num_updates == expected["ppo"]["num_updates"]
    assert _flat(config)["learner_overrides"] == {**expected["learner_overrides"], "hist": 2,
                                                  "beta": 3.0}


def test_overrides_enter_the_tree_by_path_and_unknown_paths_are_named():
    config = stream.for_env("RearrangeGeom", "SPAIR", {
        "eval.every": 5, "replay.slots": 128, "ppo.hidden": [32, 32],
        "env_config.versions": [0, 1], "learner_config.grid_size": 6})
    assert (config.eval.every, config.replay.slots, config.ppo.hidden) == (5, 128, (32, 32))
    assert (config.env_config.versions, config.learner_config.grid_size) == ((0, 1), 6)
    assert not config.eval.regressor_normalize  # the domain's, kept
    # A new learner starts from its own config; its fields follow.
    pred = config.with_overrides({"learner": "PRED", "learner_config.hist": 2})
    assert type(pred.learner_config).__name__ == "PREDConfig" and pred.learner_config.hist == 2
    with pytest.raises(ValueError, match=r"unknown config field 'eval.evry'; valid: eval.every"):
        config.with_overrides({"eval.evry": 5})
    with pytest.raises(ValueError, match=r"unknown config field 'replay_slots'; valid: env, "):
        config.with_overrides({"replay_slots": 5})
    with pytest.raises(ValueError, match=r"replay.slots \(20\) must be a multiple of num_envs"):
        config.with_overrides({"replay.slots": 20})
    # Checked once, after every override: a valid end through an invalid middle is fine.
    assert config.with_overrides({"num_envs": 4, "replay.slots": 8}).replay.slots == 8
    with pytest.raises(ValueError, match="needs a SPAIRConfig"):
        config.replace(learner_config=learners_config.default_config("PRED", ld_dim=None))


def test_the_replays_kept_share_is_the_streams_the_learners_default_unless_set():
    def keep(learner, **replay):
        return (stream.StreamConfig(learner=learner, replay=stream.ReplayConfig(**replay))
                .resolved().replay.keep_fraction)

    assert keep("VAE_v0") == 0.0
    assert keep("VAE_rpl") == 0.5
    assert keep("PRED") == 0.5
    assert keep("VAE_v0", keep_fraction=0.25) == 0.25


def test_resolving_fills_the_derived_fields_once():
    config = tiny(learner="VAE_v0", overrides={"replay.slots": None})
    resolved = config.resolved()
    assert (resolved.replay.slots, resolved.replay.keep_fraction) == (5000, 0.0)  # 625 × 8 envs
    assert resolved.resolved() == resolved and resolved.fill_epochs == config.fill_epochs
    assert config.learner_config.ld_dim is None and config.resolved(4).learner_config.ld_dim == 4
    # The same program whether a default is left to resolve or written out, and whatever the
    # learner's ld_dim (the env's).
    assert resolved.program_key() == config.program_key() == config.resolved(4).program_key()


def _old_record(config: stream.StreamConfig) -> dict:
    """`config` as records were written before the tree (unresolved, flat)."""
    return _flat(config)


def test_a_run_records_its_resolved_config_and_resumes_from_an_older_record(tmp_path):
    # An older record lacks the learner and eval fields added since (LEGACY_LEARNER_FIELDS,
    # LEGACY_EVAL_FIELDS): it ran float32 with the encoder blind to the current action and the
    # regressor's held-out rows the leading ones, so only such a config resumes it.
    today = tiny()
    config = today.with_overrides({
        **{f"learner_config.{k}": v for k, v in LEGACY_LEARNER_FIELDS.items()},
        **{f"eval.{k}": v for k, v in LEGACY_EVAL_FIELDS.items()}})
    old = tmp_path / "old"
    old.mkdir()
    record = _old_record(today)  # as older runs wrote it: none of those fields
    assert not LEGACY_LEARNER_FIELDS.keys() & record["learner_overrides"].keys()
    (old / "config.json").write_text(json.dumps(record))
    assert json.loads((old / "config.json").read_text())["replay_keep_fraction"] is None
    with pytest.raises(ValueError, match=r"learner_config.current_action 'hidden' recorded, "
                                         r"'observed' now"):
        run_lib.claim_run(old, today)
    assert run_lib.claim_run(old, config)  # a resume of the same run
    recorded = json.loads((old / "config.json").read_text())
    assert recorded == config.resolved().to_dict() and recorded["replay"]["keep_fraction"] == 0.5
    assert stream.StreamConfig.from_dict(recorded) == config.resolved()
    with pytest.raises(ValueError, match="different configuration"):
        run_lib.claim_run(old, config.with_overrides({"replay.keep_fraction": 0.25}))
    assert not run_lib.claim_run(tmp_path / "new", config)


def test_changed_fields_give_the_overrides_that_rebuild_a_config():
    base = stream.for_env("GeomOnIncline", "PRED")
    config = base.replace(
        learner_config=base.learner_config.replace(beta=2.0, latent_dim=None),
        env_config=dataclasses.replace(base.env_config, force_scale=3.0),
        eval=dataclasses.replace(base.eval, every=7))
    changes = changed_fields(config, base)
    assert changes == {"eval.every": 7, "env_config.force_scale": 3.0,
                       "learner_config.latent_dim": None, "learner_config.beta": 2.0}
    assert base.with_overrides(changes) == config
    assert changed_fields(config, config) == {}
    assert changed_fields(config.env_config, base.env_config, skip=("force_scale",)) == {}


def test_a_run_records_its_tree_whole_and_resume_checks_it(tmp_path):
    config = tiny("PRED", {"learner_config.hist": 2, "learner_config.pred": 2})
    built = stream.build(config)
    ld_dim = len(built.env.ld_state_names)
    assert not run_lib.claim_run(tmp_path, config, built)
    recorded = json.loads((tmp_path / "config.json").read_text())
    assert recorded == config.resolved(ld_dim).to_dict() == built.config.to_dict()
    assert recorded["learner_config"]["hist"] == 2
    assert recorded["learner_config"]["ld_dim"] == ld_dim
    assert recorded["env_config"] == _fields(default_config("CartPole"))
    assert stream.StreamConfig.from_dict(recorded) == config.resolved(ld_dim)
    assert run_lib.claim_run(tmp_path, config, built)  # a resume
    # A learner default changed since the run started: another run.
    changed = json.loads(json.dumps(recorded))
    changed["learner_config"]["beta"] = 2.0
    (tmp_path / "config.json").write_text(json.dumps(changed))
    with pytest.raises(ValueError, match="different configuration"):
        run_lib.claim_run(tmp_path, config, built)
    # A field new in the code is missing from the record: still the same run.
    del changed["learner_config"]["beta"], changed["env_config"]["multicolor"]
    del changed["eval"]["distortion_dims"]
    (tmp_path / "config.json").write_text(json.dumps(changed))
    assert run_lib.claim_run(tmp_path, config, built)
    assert json.loads((tmp_path / "config.json").read_text()) == recorded  # written whole again


def test_a_record_with_the_flat_form_and_resolved_configs_reads_as_its_run(tmp_path):
    # The regressor's held-out rows as such runs drew them (LEGACY_EVAL_FIELDS).
    config = tiny("PRED", {"learner_config.hist": 2, "learner_config.pred": 2,
                           "eval.validation_split": "leading"})
    ld_dim = 4
    old = _old_record(config) | {"resolved": {
        "learner": _fields(config.resolved(ld_dim).learner_config) | {"gone": 1},
        "env": _fields(config.env_config)}}
    assert stream.StreamConfig.from_dict(old) == config.resolved(ld_dim).replace(
        replay=config.replay)
    (tmp_path / "config.json").write_text(json.dumps(old))
    assert run_lib.claim_run(tmp_path, config)


def test_a_committed_run_record_without_the_resolved_configs_resumes(tmp_path):
    recorded = json.loads((RESULTS / "fig3_ycb" / "VAE_rpl" / "seed_0" / "config.json")
                          .read_text())
    assert "resolved" not in recorded and "learner_overrides" in recorded
    (tmp_path / "config.json").write_text(json.dumps(recorded))
    config = stream.StreamConfig.from_dict(recorded)
    assert config.learner_config.latent_dim == 53 and config.env_config.versions == (0, 1, 2, 3)
    built = SimpleNamespace(env=SimpleNamespace(ld_state_names=("x",) * 53))
    assert run_lib.claim_run(tmp_path, config, built)
    rewritten = json.loads((tmp_path / "config.json").read_text())
    assert rewritten["learner_config"]["latent_dim"] == 53
    assert rewritten["learner_config"]["ld_dim"] == 53


def test_an_older_records_env_options_are_its_resolved_env_config_else_its_overrides():
    base = _old_record(stream.StreamConfig(env="RearrangeGeom"))
    old = base | {"env_overrides": {"versions": [5]}}
    assert stream.StreamConfig.from_dict(old).env_config.versions == (5,)
    assert stream.StreamConfig.from_dict(base).env_config == default_config("RearrangeGeom")
    env = _fields(dataclasses.replace(default_config("RearrangeGeom"), versions=(6,)))
    new = {**old, "resolved": {"env": {**env, "gone": 1}}}
    assert stream.StreamConfig.from_dict(new).env_config.versions == (6,)


def test_every_committed_stream_run_config_reads_back():
    paths = [p for p in RESULTS.rglob("seed_*/config.json")]
    assert len(paths) > 100
    for path in paths:
        recorded = json.loads(path.read_text())
        config = stream.StreamConfig.from_dict(recorded)
        resolved = config.resolved()
        assert stream.StreamConfig.from_dict(resolved.to_dict()) == resolved, path
        # A field added to the learner's config since: at the value such runs ran with
        # (LEGACY_LEARNER_FIELDS), else at its default.
        defaults = {f.name: f.default for f in dataclasses.fields(config.learner_config)}
        defaults |= LEGACY_LEARNER_FIELDS
        if "learner_overrides" not in recorded:  # the typed tree, written whole: as written
            got = config.to_dict()
            learner, written = got["learner_config"], recorded["learner_config"]
            assert all(learner.pop(k) == defaults[k] for k in learner.keys() - written.keys())
            evaluated, written = got["eval"], recorded["eval"]  # eval fields new since: legacy
            assert all(evaluated.pop(k) == LEGACY_EVAL_FIELDS[k]
                       for k in evaluated.keys() - written.keys())
            # Env fields new since (CartPole's conventions): at their defaults.
            env, written = got["env_config"], recorded["env_config"]
            env_defaults = {f.name: f.default for f in dataclasses.fields(config.env_config)}
            assert all(env.pop(k) == env_defaults[k] for k in env.keys() - written.keys())
            assert got == recorded, path
            continue
        # An older record: its flat fields as written, its learner's and env's configs with
        # every override.
        old = {k: v for k, v in recorded.items() if k != "resolved"}
        flat = _flat(config)
        assert {k: flat[k] for k in old if not k.endswith("_overrides")} == {
            k: v for k, v in old.items() if not k.endswith("_overrides")}, path
        for typed, given in ((config.learner_config, recorded["learner_overrides"]),
                             (config.env_config, recorded["env_overrides"])):
            assert _fields(typed) == _fields(typed) | given, path
        if "resolved" in recorded:
            # As recorded, a field added to the learner's config since as above.
            got, written = _fields(config.learner_config), recorded["resolved"]["learner"]
            assert {k: got[k] for k in written} == written, path
            assert all(got[k] == defaults[k] for k in got.keys() - written.keys()), path
