"""`--scale smoke`: the figure drivers and `jaml suite` at minutes-on-a-CPU sizes, resumable."""

import json

import pytest

from jaml import stream, suite
from jaml.cli import main


def test_smoke_keeps_a_sequence_learners_window_and_builds():
    config = suite.scaled(stream.for_env("CartPole", "SVAE"), "smoke")
    assert config.num_envs == 8 and config.epochs == 4
    assert config.rollout_len == 23 and config.frames_per_batch == 24  # SVAE's 24 frames
    assert stream.build(config).seq_len == 24
    assert suite.scaled(config, "paper") == config


# ~200 s of the default suite's wall on two cores (clean clone, 2026-11-27): out of it.
@pytest.mark.slow
def test_fig2_smoke_trains_resumes_with_a_word_and_reports(tmp_path, capsys):
    args = ["fig2", "--scale", "smoke", "--envs", "CartPole", "--variants", "VAE_rpl",
            "--seeds", "0", "--out", str(tmp_path)]
    assert main([*args, "--stop-after", "2"]) == 0
    capsys.readouterr()
    assert main(args) == 0
    captured = capsys.readouterr()
    for seed in (0,):
        run = tmp_path / "CartPole" / "VAE_rpl" / f"seed_{seed}"
        assert f"{run}: resumed from its checkpoint at epoch 2 of 4" in captured.err
        config = json.loads((run / "config.json").read_text())
        assert (config["num_envs"], config["epochs"], config["eval"]["rand"]) == (8, 4, 64)
        summary = json.loads((run / "summary.json").read_text())
        assert summary["status"] == "finished" and summary["resumed_from"] == 2
    assert (tmp_path / "fig2.md").is_file()
    assert "CartPole" in (tmp_path / "fig2.md").read_text()


def test_fig3_smoke_configs_take_the_smoke_sizes():
    from jaml.cli import parse
    from jaml.experiments import _runs, fig3

    paper_sizes = _runs.Sizes().overrides()

    args = parse(["fig3", "--scale", "smoke", "--out", "unused"]).command
    assert args.scale == "smoke"
    config = fig3.config_for("SPAIR_4x4", 0, paper_sizes, fig3.SCHEDULE, preset=args.scale)
    assert (config.num_envs, config.epochs, config.eval.rand,
            config.eval.regressor_iterations) == (8, 4, 64, 200)
    assert config.learner_config.grid_size == 4 and not config.eval.regressor_normalize
    paper = fig3.config_for("SPAIR_4x4", 0, paper_sizes, fig3.SCHEDULE)
    assert paper.num_envs == 64 and paper.epochs == fig3.SCHEDULE[0]


def test_smoke_replaces_size_flags_without_checking_them_against_the_papers_sizes(capsys):
    """`fig2 --scale smoke --replay-slots 32` failed: 32 slots checked against the paper's 64
    envs before the smoke scale replaced both. Now the scale's sizes are used, the flag named."""
    from jaml.cli import parse
    from jaml.experiments import fig2

    args = parse(["fig2", "--scale", "smoke", "--replay-slots", "32", "--out", "unused"]).command
    scale = args.sizes.under(args.scale)
    assert scale == {}
    assert "--scale smoke replaces --replay-slots 32" in capsys.readouterr().err
    config = fig2.config_for("CartPole", "VAE_rpl", 0, scale, fig2.SCHEDULE, preset=args.scale)
    assert (config.num_envs, config.replay.slots) == (8, suite.SCALES["smoke"]["replay.slots"])
    assert args.sizes.under("paper")["replay.slots"] == 32
