"""A run's config: one typed tree, resolved once (`resolve`) into the `RunConfig` that
config.json holds whole, read back by resume; older records (flat, or with fig9's penalty.json)
still read (`jaml.configs.records`)."""

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from envs_mjx.config import ALL_ENVS, FAMILIES, default_config, family
from jaml import stream
from jaml.configs import learners as learners_config
from jaml.configs import records
from jaml.configs.learners import ALL_LEARNERS
from jaml.configs.records import FLAT_FIELDS, LEGACY_EVAL_FIELDS, LEGACY_LEARNER_FIELDS
from jaml.configs.stream import DOMAINS, PenaltyConfig, RunConfig, changed_fields, resolve
from jaml.stream import run as run_lib
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
        resolved = resolve(config, 7, "cpu")
        flat = _flat(resolved)
        del flat["learner_overrides"], flat["env_overrides"], flat["penalty"]
        got = {
            "stream": flat | {"replay_columns": resolved.replay.slots,
                              "keep_fraction": resolved.replay.keep_fraction,
                              "fill_epochs": resolved.fill_epochs},
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
        return resolve(stream.StreamConfig(learner=learner, replay=stream.ReplayConfig(**replay)),
                       4, "cpu").replay.keep_fraction

    assert keep("VAE_v0") == 0.0
    assert keep("VAE_rpl") == 0.5
    assert keep("PRED") == 0.5
    assert keep("VAE_v0", keep_fraction=0.25) == 0.25


def test_resolve_fills_every_value_left_to_the_run_once():
    """Two configs resolved by hand: what `resolve` leaves is the config with the replay's
    columns (5000 rounded down to the envs), the learner's kept share, the backend's dtypes and
    the env's ld_dim written in, and nothing else changed."""
    cart = stream.for_env("CartPole", "VAE_v0", {"num_envs": 48})
    run = resolve(cart, 4, "cpu")
    assert run == RunConfig(
        env="CartPole", learner="VAE_v0", num_envs=48, rollout_len=32, learner_steps=10,
        replay=stream.ReplayConfig(slots=4992, keep_fraction=0.0),  # 104 columns of 48 envs
        learner_config=learners_config.default_config("VAE_v0", ld_dim=4).replace(
            compute_dtype="float32", activation_dtype="float32"))
    assert (run.fill_epochs, type(run) is RunConfig, resolve(run, 4, "cpu") == run) == (
        104, True, True)
    mesh = stream.for_env("MeshOnIncline", "PRED", {"replay.slots": 1024, "seed": 3})
    run = resolve(mesh, 5, "gpu")
    assert run == RunConfig(
        env="MeshOnIncline", learner="PRED", seed=3, rollout_len=10, learner_steps=10,
        replay=stream.ReplayConfig(slots=1024, keep_fraction=0.5),
        ppo=stream.PPOConfig(hidden=(256, 256), num_updates=10, num_minibatches=4),
        eval=stream.EvalConfig(regressor_normalize=False,
                               distortion_dims=("position", "velocity")),
        learner_config=learners_config.default_config(
            "PRED", ld_dim=5, hist=1, pred=1, static_dim=3, latent_dim=2, mu_nl=False,
            logvar_limit=20.0, compute_dtype="bfloat16", activation_dtype="bfloat16"))
    assert run.fill_epochs == 16 and run.to_dict()["learner_config"]["ld_dim"] == 5
    # Nothing is left to resolve in a RunConfig: one made by hand must say it all.
    with pytest.raises(ValueError, match=r"replay.slots, learner_config.ld_dim, "
                                         r"learner_config.compute_dtype.* is left to the run"):
        RunConfig(env="CartPole", learner="PRED", replay=stream.ReplayConfig(keep_fraction=0.5))


def test_a_penalty_is_recorded_in_config_json_and_read_back(tmp_path):
    penalty = PenaltyConfig(weight=2000.0, ok_weight=10.0, relations="runs/r/checkpoint",
                            used=(0, 2), static=("theta",), dynamic=("s", "v"))
    run = resolve(tiny("PRED").replace(penalty=penalty), 4, "cpu")
    record = json.loads(json.dumps(run.to_dict()))  # as config.json holds it
    assert record["penalty"] == {"weight": 2000.0, "form": "hinge", "ok_weight": 10.0,
                                 "ok_rows": "relations", "ok_fraction": None,
                                 "relations": "runs/r/checkpoint", "used": [0, 2],
                                 "static": ["theta"], "dynamic": ["s", "v"]}
    assert RunConfig.from_dict(record) == run == resolve(records.read(record), 4, "cpu")
    assert RunConfig.from_dict(resolve(tiny("PRED"), 4, "cpu").to_dict()).penalty is None


def _claim(out, config: stream.StreamConfig, ld_dim: int = 4) -> bool:
    """`claim_run` for `config` as a stream of an env with `ld_dim` LD entries runs it (what
    `claim_run` reads of a Stream for a registry learner: its config and env's LD-state
    size)."""
    run = resolve(config, ld_dim, "cpu")
    built = SimpleNamespace(config=run, env=SimpleNamespace(ld_state_names=("x",) * ld_dim))
    return run_lib.claim_run(out, run, built)


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
        _claim(old, today)
    assert _claim(old, config)  # a resume of the same run
    recorded = json.loads((old / "config.json").read_text())
    run = resolve(config, 4, "cpu")
    assert recorded == run.to_dict() and recorded["replay"]["keep_fraction"] == 0.5
    assert RunConfig.from_dict(recorded) == run
    with pytest.raises(ValueError, match="different configuration"):
        _claim(old, config.with_overrides({"replay.keep_fraction": 0.25}))
    assert not _claim(tmp_path / "new", config)


def test_another_learner_in_the_same_out_is_refused_naming_the_fields_compactly(tmp_path):
    """Another learner's run in a used OUT: one short line naming the fields that differ (a
    config by its class, not its repr) and the way out."""
    assert not _claim(tmp_path, stream.for_env("CartPole", "VAE_rpl"))
    with pytest.raises(ValueError) as refusal:
        _claim(tmp_path, stream.for_env("CartPole", "PRED"))
    message = str(refusal.value)
    assert "learner 'VAE_rpl' recorded, 'PRED' now" in message
    assert "learner_config VAEConfig recorded, PREDConfig now" in message
    assert "use another --out or the same options" in message
    assert "VAEConfig(" not in message and len(message) < 400


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
    assert not run_lib.claim_run(tmp_path, built.config, built)
    recorded = json.loads((tmp_path / "config.json").read_text())
    assert recorded == resolve(config, ld_dim, "cpu").to_dict() == built.config.to_dict()
    assert recorded["learner_config"]["hist"] == 2
    assert recorded["learner_config"]["ld_dim"] == ld_dim
    assert recorded["env_config"] == _fields(default_config("CartPole"))
    assert RunConfig.from_dict(recorded) == built.config
    assert run_lib.claim_run(tmp_path, built.config, built)  # a resume
    # A learner default changed since the run started: another run.
    changed = json.loads(json.dumps(recorded))
    changed["learner_config"]["beta"] = 2.0
    (tmp_path / "config.json").write_text(json.dumps(changed))
    with pytest.raises(ValueError, match="different configuration"):
        run_lib.claim_run(tmp_path, built.config, built)
    # A field new in the code is missing from the record: still the same run.
    del changed["learner_config"]["beta"], changed["env_config"]["multicolor"]
    del changed["eval"]["distortion_dims"], changed["penalty"]
    (tmp_path / "config.json").write_text(json.dumps(changed))
    assert run_lib.claim_run(tmp_path, built.config, built)
    assert json.loads((tmp_path / "config.json").read_text()) == recorded  # written whole again


def test_a_record_with_the_flat_form_and_resolved_configs_reads_as_its_run(tmp_path):
    # The regressor's held-out rows as such runs drew them (LEGACY_EVAL_FIELDS).
    config = tiny("PRED", {"learner_config.hist": 2, "learner_config.pred": 2,
                           "eval.validation_split": "leading"})
    ld_dim = 4
    old = _old_record(config) | {"resolved": {
        "learner": _fields(resolve(config, ld_dim, "cpu").learner_config) | {"gone": 1},
        "env": _fields(config.env_config)}}
    assert resolve(records.read(old), ld_dim, "cpu") == resolve(config, ld_dim, "cpu")
    (tmp_path / "config.json").write_text(json.dumps(old))
    assert _claim(tmp_path, config, ld_dim)


def test_a_committed_run_record_without_the_resolved_configs_resumes(tmp_path):
    recorded = json.loads((RESULTS / "fig3_ycb" / "VAE_rpl" / "seed_0" / "config.json")
                          .read_text())
    assert "resolved" not in recorded and "learner_overrides" in recorded
    (tmp_path / "config.json").write_text(json.dumps(recorded))
    config = records.read(recorded)
    assert config.learner_config.latent_dim == 53 and config.env_config.versions == (0, 1, 2, 3)
    assert _claim(tmp_path, config, 53)
    rewritten = json.loads((tmp_path / "config.json").read_text())
    assert rewritten["learner_config"]["latent_dim"] == 53
    assert rewritten["learner_config"]["ld_dim"] == 53


def test_an_older_records_env_options_are_its_resolved_env_config_else_its_overrides():
    base = _old_record(stream.StreamConfig(env="RearrangeGeom"))
    old = base | {"env_overrides": {"versions": [5]}}
    assert records.read(old).env_config.versions == (5,)
    assert records.read(base).env_config == default_config("RearrangeGeom")
    env = _fields(dataclasses.replace(default_config("RearrangeGeom"), versions=(6,)))
    new = {**old, "resolved": {"env": {**env, "gone": 1}}}
    assert records.read(new).env_config.versions == (6,)


def test_every_committed_stream_run_config_reads_back():
    paths = [p for p in RESULTS.rglob("seed_*/config.json")]
    assert len(paths) > 100
    for path in paths:
        recorded = json.loads(path.read_text())
        config = records.read(recorded, path.parent)
        resolved = resolve(config, 4, "cpu")
        assert RunConfig.from_dict(resolved.to_dict()) == resolved, path
        # A field added to the learner's config since: at the value such runs ran with
        # (LEGACY_LEARNER_FIELDS), else at its default.
        defaults = {f.name: f.default for f in dataclasses.fields(config.learner_config)}
        defaults |= LEGACY_LEARNER_FIELDS
        if "learner_overrides" not in recorded:  # the typed tree, written whole: as written
            got = config.to_dict()
            sidecar = path.parent / records.PENALTY_SIDECAR  # fig9's, before "penalty" was
            imposed = sidecar.exists() and json.loads(sidecar.read_text())["relations"]
            penalty = got.pop("penalty")
            if "penalty" in recorded:  # written since the penalty moved into the config
                assert recorded.pop("penalty") == penalty, path
            else:
                assert (penalty is not None) == bool(imposed), path
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


def test_a_committed_fig9_run_reads_with_its_penalty_json_as_its_penalty(tmp_path):
    """A run written before config.json held the penalty: its penalty.json (relation set, the
    relations used, 1-based, and the weights) is its `penalty`, the relations' checkpoint
    under OUT/relations and fig9's layout then; with it, the run resumes the same config."""
    out = tmp_path / "out"
    run = out / "PRED+AML_trnsv" / "seed_0"
    committed = RESULTS / "fig9_runs" / "reference_2078" / "PRED+AML_trnsv" / "seed_0"
    run.mkdir(parents=True)
    for name in ("config.json", "penalty.json"):
        (run / name).write_text((committed / name).read_text())
    recorded = json.loads((run / "config.json").read_text())
    config = records.read(recorded, run)
    assert config.penalty == PenaltyConfig(
        weight=2000.0, form="hinge", ok_weight=10.0, ok_rows="relations", ok_fraction=None,
        relations=str(out / "relations" / "trnsv" / "checkpoint"), used=(0, 1, 2),
        static=("theta",), dynamic=("s", "v"))
    assert records.read(recorded).penalty is None  # without its directory: none
    assert _claim(run, config, 5)  # the same run, with the penalty it was trained with
    assert (run / "config.json").read_text() != (committed / "config.json").read_text()
    assert RunConfig.from_dict(json.loads((run / "config.json").read_text())).penalty == (
        config.penalty)
    with pytest.raises(ValueError, match=r"penalty.weight 2000.0 recorded, 100.0 now"):
        _claim(run, config.replace(penalty=dataclasses.replace(config.penalty, weight=100.0)),
               5)
    control = RESULTS / "fig9_runs" / "reference_2078" / "PRED" / "seed_0"
    assert records.read(json.loads((control / "config.json").read_text()),
                        control).penalty is None
