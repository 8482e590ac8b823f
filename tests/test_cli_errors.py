"""Every CLI failure one line naming the problem and the fix; flags' help says what they do."""

import asyncio
import os
import time
import types
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_mjx
from jaml import _rundir, evaluation
from jaml._command import quiet_closed_loop_callbacks
from jaml.cli import main
from jaml.evaluation.distortion import CollapsedPairsWarning
from jaml.stream import checkpoint

_SUITE = ["suite", "--env", "CartPole", "--learner", "VAE_rpl", "--no-progress"]


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(("jaml: error: ", "jaml suite: error: ")), err[0]
    assert "Traceback" not in err[0]
    return err[0]


def test_a_run_directory_in_use_is_one_line(tmp_path, capsys):
    held = _rundir.lock(tmp_path / "run")
    try:
        assert main([*_SUITE, "--out", str(tmp_path / "run")]) == 2
    finally:
        held.close()
    line = _one_error_line(capsys)
    assert "is being run by another process" in line and "choose another --out" in line


def test_boolean_flags_help_says_what_the_flag_does(capsys):
    with pytest.raises(SystemExit):
        main(["suite", "--env", "CartPole", "--learner", "PRED", "--help"])
    text = " ".join(capsys.readouterr().out.replace("│", " ").split())
    for flag in ("--ppo.no-lr-decay", "--eval.no-regressor-normalize", "--no-final-checkpoint"):
        after = text.split(flag, 1)[1]
        assert after.lstrip().startswith("turn off: "), (flag, after[:100])
        assert after.split("(default: ", 1)[1].startswith("on)"), (flag, after[:300])


def test_a_negative_beta_is_refused_before_any_work(tmp_path, capsys):
    out = tmp_path / "b"
    with pytest.raises(SystemExit) as exit_:  # refused while parsing the flags
        main([*_SUITE[:4], "beta-VAE", "--out", str(out), "--learner-config.beta", "-1"])
    assert exit_.value.code == 2
    assert "beta must be ≥ 0" in _one_error_line(capsys)
    assert not out.exists()


def test_env_config_values_are_validated():
    with pytest.raises(ValueError, match="n_frames must be ≥ 1"):
        envs_mjx.make("CartPole", n_frames=0)
    with pytest.raises(ValueError, match="episode_length must be ≥ 1 or None"):
        envs_mjx.default_config("CartPole").__class__(episode_length=0)


def test_envs_show_checks_the_output_path_before_rendering(tmp_path, capsys):
    tic = time.perf_counter()
    assert main(["envs", "show", "--env", "Ant", "--out", str(tmp_path / "x.jpgx")]) == 2
    # Rendering Ant's grid compiles for ~50 s on two cores; the refusal comes first.
    assert time.perf_counter() - tic < 20
    assert "give a path ending in .png" in _one_error_line(capsys)
    assert not list(tmp_path.iterdir())


def test_an_unreadable_checkpoint_is_one_line(tmp_path, capsys):
    state = {"a": jnp.arange(4.0), "b": jnp.ones((2, 2))}
    mgr = checkpoint.manager(tmp_path)
    checkpoint.save(mgr, 3, state)
    mgr.close()  # managers left open are collected later, after their event loops close
    step = tmp_path / "checkpoints" / "3"
    for f in step.rglob("*"):
        if f.is_file() and "manifest" in f.name:
            f.unlink()
    mgr = checkpoint.manager(tmp_path)
    with pytest.raises(checkpoint.CheckpointUnreadable) as caught:
        checkpoint.restore(mgr, jax.eval_shape(lambda: state))
    mgr.close()
    message = str(caught.value)
    assert "\n" not in message and str(step) in message and "move that folder away" in message
    assert isinstance(caught.value, ValueError)  # the CLI's one-line errors


def test_an_infinite_distortion_says_how_many_pairs_collapsed():
    """Points 0 and 1 share a latent but not a state: every pair of them is collapsed."""
    states = np.arange(12.0).reshape(6, 2)
    latents = np.concatenate([np.zeros((2, 3)), np.arange(12.0).reshape(4, 3) + 1])
    rho, valid = evaluation.distortion_coefficients(latents, states, num_pairs=50, seed=1)
    i, j = (np.asarray(x) for x in evaluation.sample_pairs(6, 50, seed=1))
    collapsed = int(np.sum((i < 2) & (j < 2)))
    assert collapsed > 0 and collapsed == int(np.isneginf(np.asarray(rho)).sum())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert evaluation.distortion(latents, states, num_pairs=50, seed=1) == float("inf")
    (w,) = [w for w in caught if w.category is CollapsedPairsWarning]
    assert f"{collapsed} of {int(np.asarray(valid).sum())} pairs" in str(w.message)


def test_an_unrelated_non_empty_out_is_refused_in_one_line(tmp_path, capsys):
    """A folder of someone else's files is not made a run directory (its files would be mixed
    with the run's)."""
    out = tmp_path / "photos"
    out.mkdir()
    (out / "holiday.jpg").write_bytes(b"")
    assert main([*_SUITE, "--out", str(out)]) == 2
    line = _one_error_line(capsys)
    assert "is not empty (holiday.jpg) and holds no jaml run" in line and "--out" in line
    assert [p.name for p in out.iterdir()] == ["holiday.jpg"]  # left as it was


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="Linux's /proc")
def test_an_unwritable_out_says_it_cannot_be_written(capsys):
    """/proc takes no new folders: mkdir there says "No such file or directory" of a folder
    that exists; the line says the path cannot be written, and under which folder."""
    assert main([*_SUITE, "--out", "/proc/jaml-run"]) == 2
    line = _one_error_line(capsys)
    assert "--out /proc/jaml-run cannot be written" in line and "(under /proc" in line
    assert "choose a directory you can write" in line


def test_a_corrupt_config_json_is_one_line_naming_the_file(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "config.json").write_text('{"env": "CartPole", "learner"')  # cut short
    assert main([*_SUITE, "--out", str(out)]) == 2
    line = _one_error_line(capsys)
    assert f"{out / 'config.json'} is not valid JSON" in line and "--out" in line


def test_cartpoles_conventions_are_a_choice_on_the_command_line(capsys):
    with pytest.raises(SystemExit):
        main(["envs", "show", "--env", "CartPole", "--env-config.conventions", "gym"])
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jaml envs: error: invalid choice 'gym' for "
                                                "argument '--env-config.conventions'")
    assert "('reference', 'gymnasium')" in err[0]


def _unraisable(error: BaseException, obj=None):
    return types.SimpleNamespace(exc_type=type(error), exc_value=error,
                                 exc_traceback=error.__traceback__, err_msg=None, object=obj)


def test_asyncio_s_closed_loop_tracebacks_after_a_failed_read_are_dropped_and_only_those():
    """After Orbax fails a read, TensorStore's other reads call back into the event loop Orbax
    closed: asyncio raises in a thread nobody waits on, and Python prints its traceback after
    the command's one-line error. The command line's hook drops exactly that one."""
    loop = asyncio.new_event_loop()
    loop.close()
    with pytest.raises(RuntimeError, match="Event loop is closed") as closed:
        loop.call_soon_threadsafe(print)
    seen = []
    hook = quiet_closed_loop_callbacks(seen.append)
    hook(_unraisable(closed.value))
    assert seen == []
    others = [_unraisable(RuntimeError("Event loop is closed")),  # raised elsewhere
              _unraisable(closed.value, obj=loop),  # from an object's finaliser
              _unraisable(ValueError("Event loop is closed"))]
    for other in others:
        hook(other)
    assert seen == others
    assert quiet_closed_loop_callbacks(hook) is hook  # installed twice, wrapped once
