"""The `jaml relations` run directory: contents, figures, resume after an interruption, refusal."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml import cli, relations, sources
from jaml.relations import run as run_module

TINY_FLAGS = ["--max-steps", "40", "--chunk-steps", "20", "--batch-size", "64",
              "--stop-patience", "1", "--eval-batches", "2", "--no-progress",
              "--no-stop-when-complete", "--mined-weight", "0"]


def _tiny_config(**changes):
    """Relations that end capped after 40 steps, each trained once (another start of a capped
    one would log its steps again)."""
    return relations.Config(max_relations=2, max_steps=40, chunk_steps=20, batch_size=64,
                            stop_patience=1, eval_batches=2, mined_weight=0.0,
                            stop_when_complete=False, premine_attempts=1).replace(**changes)


def test_cli_writes_the_run_directory(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli.main(["relations", "--source", "block45", "--max-relations", "2", "--out",
                     str(out), *TINY_FLAGS]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["num_relations"] == 2 and summary["status"].split(":")[0] in ("done", "capped")
    for r in summary["relations"]:
        assert r["steps"] <= 40 and r["status"] in ("done", "capped") and r["seconds"] > 0
        assert r["off_mean"] > 0 and r["on_mean"] > 0
    codim = summary["codimension"]
    assert codim["relations"] == 2 and codim["points"] == 2048
    assert 0.0 <= codim["full_rank_fraction"] <= 1.0
    assert sum(codim["rank_fractions"]) == pytest.approx(1.0)
    assert [r["codimension"]["relations"] for r in summary["relations"]] == [1, 2]
    config = json.loads((out / "config.json").read_text())
    assert config["source"] == "block45" and config["relations"]["max_steps"] == 40
    lines = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert {line["relation"] for line in lines} == {1, 2}
    assert {"loss", "distance", "on_mean", "off_mean"} <= set(lines[0])
    assert "angle" in lines[-1] and "transversality" in lines[-1]
    assert any((out / "tensorboard").iterdir())
    assert (out / "phase_space.png").stat().st_size > 10_000
    assert relations.load(out / "checkpoint").num_relations == 2
    assert "block45: 2 relations, " in capsys.readouterr().out


@pytest.mark.slow  # default-suite time; the run directory and resume checks stay default
def test_three_dimensional_sources_get_zero_level_set_figures(tmp_path):
    run_module.run("ellipse", _tiny_config(max_relations=1), tmp_path / "e", progress=False)
    assert (tmp_path / "e" / "zero_sets.png").stat().st_size > 10_000


def test_an_interrupted_run_resumes_after_its_last_finished_relation(tmp_path, monkeypatch,
                                                                     caplog):
    out, cfg = tmp_path / "run", _tiny_config()
    real_save = run_module.checkpoint.save

    def save_then_die(rs, path):
        real_save(rs, path)
        raise KeyboardInterrupt  # killed right after the first relation's checkpoint

    monkeypatch.setattr(run_module.checkpoint, "save", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        run_module.run("ellipse", cfg, out, progress=False, figures=False)
    first = relations.load(out / "checkpoint")
    assert first.num_relations == 1
    recorded = json.loads((out / "summary.json").read_text())
    (out / "summary.json").write_text(json.dumps(recorded | {"seconds": 1000.0}))
    # A line g_2 logged before the kill, after the checkpoint: the resumed run drops it.
    with (out / "metrics.jsonl").open("a") as f:
        f.write(json.dumps({"phase": "relation", "relation": 2, "step": 999}) + "\n")
    monkeypatch.setattr(run_module.checkpoint, "save", real_save)
    with caplog.at_level("INFO", logger="jaml.resume"):
        summary = run_module.run("ellipse", cfg, out, progress=False, figures=False)
    assert f"{out}: resumed from its checkpoint with 1 of 2 relations" in caplog.text
    lines = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
    keys = [(r["relation"], r["phase"], r["step"]) for r in lines]
    assert len(keys) == len(set(keys)) and (2, "relation", 999) not in keys
    assert {r["relation"] for r in lines} == {1, 2}
    assert summary["num_relations"] == 2 and summary["status"].split(":")[0] in ("done", "capped")
    resumed = relations.load(out / "checkpoint")
    tau = sources.make("ellipse").sample(jax.random.key(0), 16)
    np.testing.assert_array_equal(relations.evaluate(resumed, tau)[:, 0],
                                  relations.evaluate(first, tau)[:, 0])
    assert [r["index"] for r in summary["relations"]] == [1, 2]
    # g1's end is the one its first call recorded, not "restored" (its checkpoint was written
    # mid-fit, before any quality report).
    assert summary["quality"]["relations"][0]["status"] == summary["relations"][0]["status"]
    assert summary["relations"][0]["status"] != "restored"
    assert summary["seconds"] > 1000.0  # every call's seconds, not the last one's


def test_a_relation_interrupted_mid_training_resumes_step_for_step(tmp_path, monkeypatch):
    """Killed after g1's third kept state (one per 20-step chunk), the run resumes g1 from that
    state and ends with the relation an uninterrupted run learns, to the bit."""
    cfg = _tiny_config(max_relations=1, max_steps=100, stop_patience=1000)
    monkeypatch.setattr(run_module._PartialDir.__init__, "__defaults__", (0.0,))
    whole = run_module.run("ellipse", cfg, tmp_path / "whole", progress=False, figures=False)
    real_save, saves = run_module._PartialDir.save, []

    def save_then_die(self, k, state):
        real_save(self, k, state)
        saves.append(int(state.step))
        if len(saves) == 3:
            raise KeyboardInterrupt

    out = tmp_path / "cut"
    monkeypatch.setattr(run_module._PartialDir, "save", save_then_die)
    with pytest.raises(KeyboardInterrupt):
        run_module.run("ellipse", cfg, out, progress=False, figures=False)
    assert saves == [20, 40, 60] and not (out / "checkpoint").exists()
    monkeypatch.setattr(run_module._PartialDir, "save", real_save)
    resumed = run_module.run("ellipse", cfg, out, progress=False, figures=False)
    assert resumed["relations"][0]["steps"] == whole["relations"][0]["steps"] == 100
    assert not (out / "partial").exists()
    tau = sources.make("ellipse").sample(jax.random.key(0), 16)
    np.testing.assert_array_equal(
        relations.evaluate(relations.load(out / "checkpoint"), tau),
        relations.evaluate(relations.load(tmp_path / "whole" / "checkpoint"), tau))
    steps = [json.loads(x)["step"] for x in (out / "metrics.jsonl").read_text().splitlines()]
    assert steps == list(range(20, 101, 20))


def test_a_finished_run_started_again_trains_nothing_and_keeps_no_partial_state(
        tmp_path, monkeypatch):
    """A fit that ended (here with a relation in progress left behind, as one dropped at the
    end leaves it) clears OUT/partial; started again, the run returns its summary untrained,
    and a fit from its checkpoint takes the relations' recorded ends, not "restored"."""
    out, cfg = tmp_path / "run", _tiny_config(max_relations=1)
    real_fit = run_module.fit

    def fit_leaving_partial(*args, **kwargs):
        rs = real_fit(*args, **kwargs)
        (out / "partial").mkdir()
        return rs

    monkeypatch.setattr(run_module, "fit", fit_leaving_partial)
    first = run_module.run("ellipse", cfg, out, progress=False, figures=False)
    assert not (out / "partial").exists()

    def no_training(*args, **kwargs):
        raise AssertionError("a finished run trained again")

    monkeypatch.setattr(run_module, "fit", no_training)
    again = run_module.run("ellipse", cfg, out, progress=False, figures=False)
    assert again == first
    from jaml.relations import training

    ended = [r["status"] for r in first["relations"]]
    assert training._start_ends(relations.load(out / "checkpoint"))[0] == ended
    assert training._start_ends(relations.load(out / "checkpoint").replace(quality=None)) == (
        ["restored"], [None])


def test_a_different_configuration_in_the_same_directory_is_refused(tmp_path, capsys):
    out = tmp_path / "run"
    run_module.run("ellipse", _tiny_config(max_relations=1), out, progress=False, figures=False)
    code = cli.main(["relations", "--source", "ellipse", "--max-relations", "1", "--seed", "3",
                     "--out", str(out), *TINY_FLAGS])
    assert code == 2 and "different configuration" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["--help"], ["relations", "--help"], ["demo", "--help"]])
def test_every_subcommand_has_help(argv, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    assert exit_info.value.code == 0 and "usage: jaml" in capsys.readouterr().out


def test_bad_cli_values_give_clear_errors(tmp_path, capsys):
    code = cli.main(["relations", "--source", "torus", "--out", str(tmp_path)])
    assert code == 2 and "unknown source 'torus'; valid sources" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["relations", "--source", "ellipse", "--out", str(tmp_path),
                  "--independence", "orthogonality"])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and len(err.strip().splitlines()) == 1
    assert "invalid choice 'orthogonality' for argument '--independence'" in err
    assert "('transversality', 'syzygy')" in err


@pytest.mark.slow  # default-suite time; the run directory and resume checks stay default
def test_pretraining_towards_a_prior_heuristic():
    src = sources.make("ellipse")
    plane = lambda t: t[..., 1] - 2 * t[..., 2] - 1  # noqa: E731
    cfg = _tiny_config(max_relations=1, max_steps=1, pretrain_steps=1500, batch_size=256)
    rs = relations.fit(src, cfg, priors=[plane])
    box = jax.random.uniform(jax.random.key(3), (2048, 3), minval=jnp.array([-1.4, -3, -2]),
                             maxval=jnp.array([1.4, 1, 0]))
    g = np.asarray(relations.evaluate(rs, box)[:, 0])
    assert np.corrcoef(g, np.tanh(np.asarray(plane(box))))[0, 1] > 0.95
    with pytest.raises(TypeError, match="priors"):
        relations.fit(src, cfg, priors=["plane"])


def test_a_run_directory_another_process_holds_is_refused(tmp_path):
    from jaml import _rundir

    with _rundir.lock(tmp_path), pytest.raises(_rundir.RunInUse, match="another process"):
        run_module.run("ellipse", _tiny_config(max_relations=1), tmp_path, progress=False)
    assert not (tmp_path / "config.json").exists()
