"""The learning loop and its run directory: config errors, checkpoints, resume, non-finite loss.

The end-to-end runs compile a learner, PPO and the renderer on CPU (minutes), so they are
marked slow; the config checks and the checkpoint round trip run by default.
"""

import dataclasses
import json
import math
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml import stream
from jaml.stream import checkpoint, rundir
from jaml.stream import run as run_lib


@pytest.fixture(autouse=True, scope="module")
def _fast_compiling_prng():
    with jax.threefry_partitionable(False):  # see tests/learners/conftest.py
        yield


def tiny(learner="VAE_rpl", overrides=None, **fields):
    """Two fill epochs, then training; analyses at epochs 2, 4, 6. `overrides` (paths) and
    `fields` (the stream's own) change it (`StreamConfig.with_overrides`)."""
    settings = {"num_envs": 8, "rollout_len": 4, "replay.slots": 16, "frames_per_batch": 8,
                "learner_steps": 2, "epochs": 6, "eval.every": 2, "eval.train": 16,
                "eval.rand": 16, "eval.curr": 16, "eval.transient": 3,
                "eval.regressor_iterations": 20, "ppo.num_minibatches": 4}
    return stream.for_env("CartPole", learner, {**settings, **fields, **(overrides or {})})


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(env="Pendulum"), "unknown env 'Pendulum'; valid names"),
        (dict(learner="AE"), "unknown learner 'AE'; valid names"),
        (dict(learner="SVAE"), "needs sequences of 24 frames but replay columns hold"),
        ({"learner": "PRED", "learner_config.hist": 2, "learner_config.pred": 2,
          "frames_per_batch": 3}, "frames_per_batch \\(3\\) holds no 4-frame sequence"),
        ({"replay.slots": 20}, "must be a multiple of num_envs"),
        (dict(epochs=1), "end before the replay fills"),
        ({"replay.slots": 8, "replay.keep_fraction": 0.5}, "only 4 replay slots are replaceable"),
        ({"learner_config.hist": 2}, r"unknown config field 'learner_config.hist'; valid: "
                                     r"learner_config.ld_dim, learner_config.latent_dim"),
        ({"eval.every": 0}, r"eval.every must be ≥ 1, got 0"),
        ({"replay.keep_fraction": 1.0}, r"replay.keep_fraction must be in \[0, 1\), got 1.0"),
    ],
)
def test_bad_configs_raise_before_anything_runs(change, message, tmp_path):
    with pytest.raises(ValueError, match=message):
        run_lib.run(tiny().with_overrides(change), tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()  # nothing written for a config that cannot run


def test_replay_size_defaults_to_the_references_5000_columns_per_env_count():
    def run(**fields):
        return stream.resolve(stream.StreamConfig(**fields), 4, "cpu")

    assert run().replay.slots == 4992  # 78 columns of 64 envs
    assert run(num_envs=200).replay.slots == 5000
    assert run(num_envs=96, replay=stream.ReplayConfig(slots=192)).fill_epochs == 2


def test_bad_policy_and_sizes_are_named():
    with pytest.raises(ValueError, match="policy must be one of"):
        tiny(policy="greedy")
    with pytest.raises(ValueError, match=r"must split into ppo\.num_minibatches"):
        tiny(num_envs=8, ppo=stream.PPOConfig(num_minibatches=3))


def test_a_run_directory_refuses_another_config(tmp_path):
    (tmp_path / "config.json").write_text(json.dumps(tiny(seed=1).to_dict()))
    with pytest.raises(ValueError, match="different configuration"):
        run_lib.run(tiny(), tmp_path, progress=False)
    from jaml import _rundir

    _rundir.lock(tmp_path).close()  # the refused run let its directory go


def test_a_run_directory_another_process_holds_is_refused(tmp_path):
    from jaml import _rundir

    with _rundir.lock(tmp_path), pytest.raises(_rundir.RunInUse, match="another process"):
        run_lib.run(tiny(), tmp_path, progress=False)
    assert not (tmp_path / "config.json").exists()  # refused before it touched the directory


def test_checkpoint_round_trip_keeps_every_leaf_by_name(tmp_path):
    s = stream.build(tiny())
    state = s.init(jax.random.PRNGKey(0))
    empty = [x for x in jax.tree.leaves(state) if x.size == 0]
    assert empty, "mjx.Data carries zero-size fields; the checkpoint must handle them"
    mgr = checkpoint.manager(tmp_path)
    checkpoint.save(mgr, 0, state)
    mgr.close()
    # A fresh manager, as a resumed process opens it (one that has not saved must still read).
    mgr = checkpoint.manager(tmp_path)
    assert "learner.params.conv.conv0.kernel" in set(mgr.item_metadata(0).keys())
    assert mgr.metadata().custom_metadata["format"] == checkpoint.FORMAT
    restored = checkpoint.restore(mgr, jax.eval_shape(s.init, jax.random.PRNGKey(0)))
    assert jax.tree.structure(restored) == jax.tree.structure(state)
    for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(restored), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # Other shapes (more envs) or another learner's state: refused, naming what differs.
    wider = stream.build(tiny(num_envs=16, overrides={"replay.slots": 32}))
    with pytest.raises(checkpoint.CheckpointMismatch, match=r"other shapes .*saved \(8"):
        checkpoint.restore(mgr, jax.eval_shape(wider.init, jax.random.PRNGKey(0)))
    other = stream.build(tiny(learner="SVAE", rollout_len=24, frames_per_batch=24))
    with pytest.raises(checkpoint.CheckpointMismatch, match=r"missing .*unexpected"):
        checkpoint.restore(mgr, jax.eval_shape(other.init, jax.random.PRNGKey(0)))
    mgr.close()


def test_a_checkpoint_written_by_a_child_process_reads_back_leaf_for_leaf(tmp_path):
    """The several-processes save (`_save_apart`: a child process writes the step) on one
    process: every leaf comes back with its dtype (bfloat16 included) and values, and the
    parent's manager sees the new step."""
    state = {"learner": {"w": jnp.linspace(-1, 1, 6, dtype=jnp.bfloat16).reshape(2, 3),
                         "step": jnp.int32(7)},
             "replay": {"frames": jnp.arange(24, dtype=jnp.uint8).reshape(2, 3, 4)},
             "key": jnp.asarray([3, 5], jnp.uint32)}
    mgr = checkpoint.manager(tmp_path)
    checkpoint._save_apart(mgr, 4, {k: np.asarray(x) for k, x in checkpoint.named(state).items()})
    assert mgr.latest_step() == 4
    restored = checkpoint.restore(mgr, jax.eval_shape(lambda: state))
    for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(restored), strict=True):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    mgr.close()


def test_test_policy_is_uniform_or_current_by_a_traced_flag():
    """π_rand and π_curr share one compiled policy; each flag value gives that policy's actions."""
    st = stream.build(tiny())
    ppo_state = jax.jit(st.ppo.init)(jax.random.PRNGKey(1))
    obs = jax.random.normal(jax.random.PRNGKey(2), (8, 4))
    key = jax.random.PRNGKey(3)
    traces = []

    def act(random):
        traces.append(1)
        return st.test_policy(ppo_state, random)(obs, key)[0]

    act = jax.jit(act)
    uniform = stream.random_policy(st.env.action_size)(obs, key)[0]
    current = st.policy(ppo_state)(obs, key)[0]
    assert not np.allclose(uniform, current)
    np.testing.assert_array_equal(act(jnp.asarray(True)), uniform)
    # (jit may fuse the policy network differently from eager: float rounding only)
    np.testing.assert_allclose(act(jnp.asarray(False)), current, rtol=1e-5, atol=1e-6)
    assert len(traces) == 1


def test_a_stream_makes_each_program_once_and_owns_it():
    a, b = stream.build(tiny()), stream.build(tiny(seed=7))
    assert (a.config.seed, b.config.seed) == (0, 7)
    traces = []

    def f(st, x):
        traces.append(st.config.seed)
        return x + st.config.learner_steps

    assert a.jit(f) is a.jit(f) and a.jit(f) is not b.jit(f)
    assert a.jit(f, donate_argnums=0) is not a.jit(f)  # the options are part of the program
    assert int(a.jit(f)(1)) == 3 and int(a.jit(f)(2)) == 4 and traces == [0]  # one trace
    # A Stream with a replaced part starts with no programs, whatever its config.
    assert dataclasses.replace(a, train_step=lambda *x: x).programs == {}


def test_top_level_programs_take_cuda_graphs_on_a_cuda_gpu_alone(monkeypatch):
    """`graphs=True` adds `CUDA_GRAPHS` to a program's compiler options on a CUDA GPU (the
    given options kept and winning), not elsewhere, not with `cuda_graphs=False`, not on a
    nested program; and this XLA parses the options (a misspelt command type fails here)."""
    from jaml.stream import loop

    s = stream.build(tiny())
    made = []
    real_jit = jax.jit
    monkeypatch.setattr(loop.jax, "jit", lambda f, **o: made.append(o) or real_jit(f, **o))
    f = lambda st, x: x * 2  # noqa: E731
    g = lambda st, x: x * 3  # noqa: E731
    s.jit(f, graphs=True)
    monkeypatch.setattr(loop, "on_cuda", lambda: True)
    given = {"xla_gpu_graph_min_graph_size": 3, "xla_backend_optimization_level": 1}
    assert int(s.jit(f, graphs=True, compiler_options=given)(2)) == 4  # compiled on the CPU
    s.jit(g)
    dataclasses.replace(s, cuda_graphs=False).jit(f, graphs=True)
    assert [o.get("compiler_options") for o in made] == [
        None, {**loop.CUDA_GRAPHS, **given}, None, None]
    # JAML_CUDA_GRAPHS=0 turns them off for the Streams built after it; 0 and 1 alone are read.
    monkeypatch.setenv("JAML_CUDA_GRAPHS", "0")
    assert not stream.build(tiny()).cuda_graphs
    monkeypatch.setenv("JAML_CUDA_GRAPHS", "off")
    with pytest.raises(ValueError, match="JAML_CUDA_GRAPHS must be 0 or 1, got 'off'"):
        stream.build(tiny())


def _records(path):
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_checkpoint_every_must_be_a_positive_number_of_epochs():
    with pytest.raises(ValueError, match="checkpoint_every must be a positive"):
        run_lib.run_many([tiny()], ["unused"], checkpoint_every=0)


@pytest.mark.slow  # a whole run for one option; checkpoint_due is tested alone
def test_without_a_final_checkpoint_a_run_writes_its_records_and_no_checkpoint(tmp_path):
    """--no-final-checkpoint on a machine whose disk goes with the run: the last analysis does
    not force one, so with checkpoints thinned past the run's length none is written."""
    summary = run_lib.run(tiny(epochs=2), tmp_path, progress=False, checkpoint_every=100,
                          final_checkpoint=False)
    assert summary["status"] == "finished" and summary["checkpoint_epoch"] is None
    assert {r["step"] for r in _records(tmp_path / "history.jsonl")} == {2}
    assert all(set(r["irregularity"]) == {"pi_rand", "replay"}
               for r in _records(tmp_path / "history.jsonl"))
    assert not [p for p in (tmp_path / "checkpoints").iterdir() if p.name.isdigit()]  # no step


@pytest.mark.slow  # two whole runs for one option (--keep-pi-rand)
def test_a_run_rolls_its_pi_rand_set_out_once_and_records_what_rolling_it_every_time_gives(
        tmp_path, monkeypatch):
    """`run_many` keeps each run's π_rand sequences after its first analysis (`PiRandSet`):
    the later analyses roll out only π_curr, and the records are those of a run that rolls
    π_rand out at every analysis (analyses at epochs 2 and 4)."""
    from jaml.stream import analysis
    starts = []
    start = analysis._rollout_start
    monkeypatch.setattr(analysis, "_rollout_start",
                        lambda stream_, s, key, random: starts.append(bool(random)) or
                        start(stream_, s, key, random))
    config = tiny(epochs=4)
    options = dict(progress=False, checkpoint_every=100, final_checkpoint=False)
    run_lib.run(config, tmp_path / "kept", **options)
    assert starts == [True, False, False]  # π_rand, π_curr at epoch 2; π_curr at epoch 4
    starts.clear()
    run_lib.run(config, tmp_path / "rolled", keep_pi_rand=False, **options)
    assert starts == [True, False, True, False]
    kept, rolled = (_records(tmp_path / d / "history.jsonl") for d in ("kept", "rolled"))
    assert {r["step"] for r in kept} == {2, 4} and kept == rolled


def _learner_params(out, config):
    s = stream.build(config)
    mgr = checkpoint.manager(out)
    params = checkpoint.restore(mgr, jax.eval_shape(s.init, jax.random.PRNGKey(config.seed)))
    mgr.close()
    return params.learner.params


@pytest.mark.slow
def test_a_killed_run_resumes_to_the_result_of_an_uninterrupted_one(tmp_path, monkeypatch):
    config = tiny()
    # A process that dies before `close` (SIGKILL, its machine taken back) still leaves the
    # summary written at its last analysis: epoch, phase times, that analysis's records.
    def died(run_dir):
        run_dir.logs.close()
        run_dir.manager.close()
        return run_dir.summary()

    with monkeypatch.context() as patch:
        patch.setattr(rundir.RunDir, "close", died)
        run_lib.run(config, tmp_path / "died", progress=False, stop_after=3)
    progress = json.loads((tmp_path / "died" / "summary.json").read_text())
    assert progress["status"] == "running" and progress["epoch"] == 2
    assert progress["checkpoint_epoch"] == 2 and [r["step"] for r in progress["final"]] == [2, 2]
    assert all(progress["seconds_by_phase"][k] > 0 for k in ("epochs", "analysis"))
    first = run_lib.run(config, tmp_path / "a", progress=False, stop_after=3)
    # A deliberate stop between analyses (epochs 2 and 4) checkpoints where it stopped.
    assert first["status"] == "interrupted" and first["checkpoint_epoch"] == 3
    assert not (tmp_path / "a" / "recon" / "epoch_000003.png").exists()  # no analysis at 3
    # A process killed before that save: its last checkpoint is epoch 2's analysis. The epoch
    # after it was logged, then lost with the process: resume drops it.
    shutil.rmtree(tmp_path / "a" / "checkpoints" / "3")
    assert [r["epoch"] for r in _records(tmp_path / "a" / "metrics.jsonl")] == [1, 2, 3]
    resumed = run_lib.run(config, tmp_path / "a", progress=False)
    straight = run_lib.run(config, tmp_path / "b", progress=False)
    assert resumed["status"] == straight["status"] == "finished"
    again = run_lib.run(config, tmp_path / "a", progress=False)  # a finished run stays finished
    assert again["status"] == "finished" and again["epoch"] == 6
    metrics_a = _records(tmp_path / "a" / "metrics.jsonl")
    metrics_b = _records(tmp_path / "b" / "metrics.jsonl")
    assert [r["epoch"] for r in metrics_a] == list(range(1, 7))
    assert json.dumps(metrics_a) == json.dumps(metrics_b)  # NaN-safe exact comparison
    assert _records(tmp_path / "a" / "history.jsonl") == _records(tmp_path / "b" / "history.jsonl")
    assert [r["step"] for r in _records(tmp_path / "a" / "history.jsonl")] == [2, 2, 4, 4, 6, 6]
    jax.tree.map(np.testing.assert_array_equal, _learner_params(tmp_path / "a", config),
                 _learner_params(tmp_path / "b", config))
    for name in ("alignment.png", "distortion.png", "recon/epoch_000006.png", "summary.json"):
        assert (tmp_path / "a" / name).exists(), name


@pytest.mark.slow
def test_a_non_finite_loss_stops_the_run_and_keeps_the_last_good_checkpoint(tmp_path,
                                                                            monkeypatch):
    config = tiny(seed=3)
    run_lib.run(config, tmp_path, progress=False, stop_after=2)  # checkpoint at epoch 2
    good = stream.build(config)

    def poisoned(state, batch, key):
        state, metrics = good.train_step(state, batch, key)
        return state, {**metrics, "loss": jnp.full_like(metrics["loss"], jnp.nan)}

    with monkeypatch.context() as patch:
        patch.setattr(run_lib, "build",
                      lambda *_: dataclasses.replace(good, train_step=poisoned))
        with pytest.raises(run_lib.NonFiniteLoss, match="non-finite at epoch 3"):
            run_lib.run(config, tmp_path, progress=False)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "nonfinite" and summary["checkpoint_epoch"] == 2
    assert summary["error"].startswith("learner loss became non-finite at epoch 3;")
    # The epochs up to the first bad one are logged, the bad one included.
    metrics = _records(tmp_path / "metrics.jsonl")
    assert [r["epoch"] for r in metrics] == [1, 2, 3]
    assert math.isnan(metrics[-1]["learner/loss"])


def test_suite_cli_has_help_and_reports_bad_input(tmp_path, capsys):
    from jaml import cli

    with pytest.raises(SystemExit) as exit_info:
        cli.main(["suite", "--help"])
    out = capsys.readouterr().out
    assert exit_info.value.code == 0 and "resumes from the last checkpoint" in out
    with pytest.raises(SystemExit):
        cli.main(["suite", "--env", "Pendulum", "--learner", "PRED", "--out", str(tmp_path)])
    assert "invalid choice 'Pendulum' for argument '--env'" in capsys.readouterr().err
    code = cli.main(["suite", "--env", "CartPole", "--learner", "SVAE", "--rollout-len", "8",
                     "--out", str(tmp_path / "svae")])
    assert code == 2 and "needs sequences of 24 frames" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["suite", "--env", "CartPole", "--learner", "beta-VAE", "--learner-config.gamma",
                  "2", "--out", str(tmp_path / "beta")])
    assert "Unrecognized options: --learner-config.gamma" in capsys.readouterr().err
    assert cli.key_value("beta=20") == ("beta", 20)
    assert cli.key_value("object=duck") == ("object", "duck")
