"""A stream run's directory: its figures, drawn in the background (`plots.FigureWriter`)."""

from pathlib import Path

import pytest

from jaml.evaluation import plots
from jaml.stream import rundir, schedule


def test_figures_are_drawn_in_the_background_from_each_runs_newest_history(monkeypatch):
    """A request still queued behind a slow drawing is skipped for a newer one of the same run;
    every run's newest history is drawn; a drawing error surfaces at `check`."""
    import threading

    drawn, started, release = [], threading.Event(), threading.Event()

    def figures(history, out, floor):
        if not drawn:
            started.set()
            release.wait(5)  # the first drawing is slow: the next requests queue behind it
        drawn.append((out, len(history), floor))

    monkeypatch.setattr(plots, "run_figures", figures)
    writer = plots.FigureWriter()
    writer.submit(Path("a"), [{}])
    assert started.wait(5)
    for n in (2, 3):
        writer.submit(Path("a"), [{}] * n)
    writer.submit(Path("b"), [{}], {"pi_rand": {"x": 0.1}})
    release.set()
    writer.wait()
    writer.check()
    assert drawn == [(Path("a"), 1, None), (Path("a"), 3, None),
                     (Path("b"), 1, {"pi_rand": {"x": 0.1}})]

    monkeypatch.setattr(plots, "run_figures", lambda history, out, floor: 1 / 0)
    failing = plots.FigureWriter()
    failing.submit(Path("a"), [])
    failing.wait()
    with pytest.raises(ZeroDivisionError):
        failing.check()


def test_a_learner_of_your_own_is_recorded_by_its_factorys_config(tmp_path):
    """config.json holds the config the factory built (not null), its class as "type"; a
    resume whose factory builds another config is refused, naming the field."""
    import json
    from types import SimpleNamespace

    from jaml import stream
    from jaml.learners.learner import SingleFrameConfig

    config = stream.resolve(
        stream.for_env("CartPole", "tests.stream.test_own_learner:make_tiny"), 4, "cpu")
    assert config.learner_config is None

    def built(latent_dim):
        own = SingleFrameConfig(ld_dim=4, latent_dim=latent_dim, learning_rate=1e-3)
        return SimpleNamespace(config=config, learner=SimpleNamespace(config=own),
                               env=SimpleNamespace(ld_state_names=("a", "b", "c", "d")))

    assert rundir.claim_run(tmp_path, config, built(6)) is False
    recorded = json.loads((tmp_path / "config.json").read_text())["learner_config"]
    assert recorded["type"] == "jaml.configs.learners.SingleFrameConfig"
    assert recorded["latent_dim"] == 6 and recorded["ld_dim"] == 4
    assert rundir.claim_run(tmp_path, config, built(6)) is True
    # A record written while the ready-made configs lived in jaml.learners.config resumes.
    record = json.loads((tmp_path / "config.json").read_text())
    record["learner_config"]["type"] = "jaml.learners.config.SingleFrameConfig"
    (tmp_path / "config.json").write_text(json.dumps(record))
    assert rundir.claim_run(tmp_path, config, built(6)) is True
    with pytest.raises(ValueError, match=r"learner_config\.latent_dim 6 recorded, 8 now"):
        rundir.claim_run(tmp_path, config, built(8))
    registry = stream.resolve(stream.for_env("CartPole", "VAE_rpl"), 4, "cpu")
    with pytest.raises(ValueError, match=r"learner_config SingleFrameConfig recorded, VAEConfig "
                                         r"now; "):
        rundir.claim_run(tmp_path, registry, SimpleNamespace(config=registry, env=built(6).env))


def test_analyses_fall_every_eval_every_epochs_from_the_full_replay_and_the_docs_say_so():
    """The epochs count the replay's filling; the analyses are the reference's, counted from
    the full replay (with 2 fill epochs, every 50: 2, 52, 102); the option's help says so."""
    from jaml import _command, stream

    config = stream.for_env("CartPole", "VAE_rpl", {"num_envs": 8, "replay.slots": 16,
                                                    "epochs": 160, "eval.every": 50})
    run = stream.resolve(config, 4, "cpu")
    assert run.fill_epochs == 2
    assert schedule.analysis_epochs(run.fill_epochs, run.epochs, run.eval.every) == [
        2, 52, 102, 152, 160]
    assert "2, 52, 102" in _command.field_docs(stream.EvalConfig)["every"]
