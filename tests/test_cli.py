"""`jaml info`, and the CLI's (and a library import's) stdout free of mujoco.mjx's MuJoCo Warp
probe prints."""

import dataclasses
import importlib.metadata
import json
import os
import platform
import subprocess
import sys

import jax
import numpy as np
import pytest

from jaml import _huge_pages, cli
from jaml.cli import _INFO_PACKAGES, main
from jaml.configs.stream import for_env
from jaml.experiments import _runs


def test_info_names_the_cpu_device_versions_and_mjx_imports(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert lines[0] == f"jax {jax.__version__}, default backend cpu"
    assert "  device 0: platform cpu, kind cpu" in lines
    for name in (
        "jax",
        "jaxlib",
        "flax",
        "optax",
        "orbax-checkpoint",
        "brax",
        "mujoco",
        "mujoco-mjx",
    ):
        assert name in _INFO_PACKAGES
        assert f"{name} {importlib.metadata.version(name)}" in lines
    assert "MJX physics (mujoco.mjx): import ok" in lines
    assert "MJX renderer (envs_mjx.render): import ok" in lines
    assert "CUDA graphs of the stream's loops: no CUDA GPU (JAML_CUDA_GRAPHS)" in lines


def test_cli_stdout_has_no_warp_probe_lines(tmp_path):
    """A fresh process: mujoco.mjx's 'Failed to import warp' prints are captured by main; the
    command line's compilation cache is where JAML_XLA_CACHE says."""
    plain = {k: v for k, v in os.environ.items() if k != "GLIBC_TUNABLES"}
    result = subprocess.run(
        [sys.executable, "-m", "jaml.cli", "info"],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
        env={**plain, "JAML_XLA_CACHE": str(tmp_path / "xla")},
    )
    assert "Failed to import" not in result.stdout + result.stderr
    assert result.stdout.startswith("jax ")
    assert f"XLA compilation cache: {tmp_path / 'xla'} (JAML_XLA_CACHE)" in result.stdout
    # The command re-executed itself with malloc on huge pages where the machine gives them.
    if _huge_pages.environment(plain, platform.libc_ver(), _huge_pages.thp_mode()):
        assert "malloc: huge pages (GLIBC_TUNABLES glibc.malloc.hugetlb=1)" in result.stdout


def test_a_stdout_closed_early_ends_quietly():
    """`jaml envs show --env RearrangeGeom --help | head`: the reader is gone before the help
    is written; the command ends with 141 (128 + SIGPIPE) and no traceback."""
    process = subprocess.Popen(
        [sys.executable, "-m", "jaml.cli", "envs", "show", "--env", "RearrangeGeom", "--help"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    process.stdout.close()  # long before the interpreter has started and parsed
    err = process.stderr.read()
    assert process.wait(timeout=120) == 141
    assert err == ""


def test_a_library_import_of_mjx_keeps_the_warp_probe_off_stdout(capsys):
    """A script importing envs_mjx, then MJX through brax and jaml.stream, prints only its own
    lines; what else the probe module prints still reaches stdout."""
    script = ("import envs_mjx\nprint('first')\nimport brax.envs\nenvs_mjx.make\n"
              "from jaml import stream\nimport mujoco.mjx.warp\nprint('last')\n")
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                            check=True, timeout=300)
    assert result.stdout == "first\nlast\n"
    from envs_mjx import _quiet

    class Probe:
        def exec_module(self, module):
            print("Failed to import warp: No module named 'warp'\nwarp 9.9 ready")

    _quiet._QuietLoader(Probe()).exec_module(None)
    assert capsys.readouterr().out == "warp 9.9 ready\n"
    assert _quiet.probe_lines[-1] == "Failed to import warp: No module named 'warp'"


@pytest.mark.slow  # two fresh processes that compile: ~1 min on the 2-core machine
def test_a_second_run_reads_the_compilation_cache(tmp_path):
    """`jaml relations` writes its compiled programs to the persistent cache, and the same
    command in a new process finds them there (JAX counts its cache hits; the first run may
    hit a program it compiled itself)."""
    script = (
        "import sys, jax\n"
        "from jax._src import monitoring\n"
        "hits = []\n"
        "monitoring.register_event_listener(lambda e, **kw: hits.append(e) if e =="
        " '/jax/compilation_cache/cache_hits' else None)\n"
        "from jaml import cli\n"
        "code = cli.main(sys.argv[1:])\n"
        "print('cache hits', len(hits))\n"
        "sys.exit(code)\n")
    env = {**os.environ, "JAML_XLA_CACHE": str(tmp_path / "xla"),
           "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    hits = []
    for run in ("a", "b"):
        argv = ["relations", "--source", "ellipse", "--out", str(tmp_path / run), *TINY]
        result = subprocess.run([sys.executable, "-c", script, *argv], capture_output=True,
                                text=True, timeout=300, env=env)
        assert result.returncode == 0, result.stderr[-2000:]
        hits.append(int(result.stdout.rsplit("cache hits", 1)[1]))
    assert any((tmp_path / "xla").iterdir())
    assert hits[1] > hits[0], hits


# One config/CLI mechanism: typed, complete help; one-line errors; --debug; file sources.

TINY = ["--max-relations", "1", "--max-steps", "20", "--chunk-steps", "20", "--batch-size", "32",
        "--stop-patience", "1", "--eval-batches", "1", "--no-progress", "--mined-weight", "0",
        "--no-stop-when-complete"]


@pytest.mark.parametrize("command", ["relations", "suite", "fig2", "fig3", "fig9", "demo", "envs",
                                     "envs list", "envs show", "info"])
def test_every_subcommand_has_help(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main([*command.split(), "--help"])
    assert exit_info.value.code == 0
    assert f"usage: jaml {command}" in capsys.readouterr().out


def test_relations_help_documents_every_field_with_its_choices(capsys):
    with pytest.raises(SystemExit):
        cli.main(["relations", "--help"])
    out = " ".join(capsys.readouterr().out.replace("│", " ").split())
    assert "--depth INT hidden layers of every g_k. (default: 3)" in out
    assert "--base-width INT hidden width of g_1" in out and "--max-width INT cap on" in out
    assert "--independence {transversality,syzygy}" in out
    assert "--objective {paper,reference}" in out
    # Multi-line docstring entries are whole, not cut at their first line.
    assert "the on-manifold statistic is the mean of the largest fraction of |g| values" in out


def test_suite_help_shows_the_pairs_defaults_and_typed_learner_and_env_options(capsys):
    with pytest.raises(SystemExit):
        cli.main(["suite", "--env", "Ant", "--learner", "PRED", "--help"])
    out = " ".join(capsys.readouterr().out.replace("│", " ").split())
    assert "--policy {ppo,random}" in out
    assert "--rollout-len INT steps per env per epoch" in out and "(default: 64)" in out
    assert "--ppo.hidden [INT [INT ...]] widths of the policy's" in out
    assert "hidden layers. (default: 256 256)" in out
    assert "--learner-config.hist INT" in out and "--learner-config.frame-nll {sum,mean}" in out
    assert "--env-config.pixels {auto,required,off}" in out
    assert "--learner-config.ld-dim" not in out and "--learner-overrides" not in out
    assert "--eval.every INT epochs between alignment analyses" in out
    assert "--replay.slots {None}|INT replay columns" in out


def test_suite_flags_become_the_runs_config():
    args = cli.parse(["suite", "--env", "Ant", "--learner", "PRED", "--out", "x",
                      "--learner-config.beta", "2", "--env-config.episode-length", "500",
                      "--ppo.num-updates", "7", "--epochs", "3", "--eval.every", "2",
                      "--replay.slots", "128"])
    config = args.command.stream_config()
    base = for_env("Ant", "PRED")
    assert config.learner_config == base.learner_config.replace(beta=2.0)  # hist 4, pred 12
    assert config.env_config == dataclasses.replace(base.env_config, episode_length=500)
    assert config.ppo.num_updates == 7 and config.ppo.hidden == (256, 256)  # Ant's, kept
    assert config.epochs == 3 and config.rollout_len == 64
    assert (config.eval.every, config.eval.train, config.replay.slots) == (2, 10_000, 128)
    # --scale smoke sets the sizes; a flag given beside it wins, field by field.
    smoke = cli.parse(["suite", "--env", "Ant", "--learner", "PRED", "--out", "x", "--scale",
                       "smoke", "--eval.every", "3"]).command.stream_config()
    assert (smoke.eval.every, smoke.eval.train, smoke.replay.slots) == (3, 64, 16)


def test_the_usage_docs_suite_commands_parse_a_scale_then_its_flags(capsys):
    """docs/usage.md's `jaml suite` lines parse: the flags are checked over the scale's sizes
    (smoke's 8 envs, not the paper's 64), and win over them, even at the paper's value; an
    inconsistent combination is one line naming the problem and the fix."""
    import shlex
    from pathlib import Path

    usage = (Path(__file__).parents[1] / "docs" / "usage.md").read_text()
    lines = [x.split("#")[0] for x in usage.splitlines() if x.startswith("jaml suite ")]
    assert len(lines) >= 3
    configs = [cli.parse(shlex.split(x)[1:]).command.stream_config() for x in lines]
    ant = configs[[" Ant " in x for x in lines].index(True)]
    assert (ant.num_envs, ant.replay.slots, ant.eval.every, ant.eval.train) == (8, 32, 2, 64)
    assert ant.learner_config.hist == 4 and ant.ppo.hidden == (256, 256)  # Ant's PRED
    paper_envs = cli.parse(["suite", "--env", "Ant", "--learner", "PRED", "--out", "x",
                            "--scale", "smoke", "--num-envs", "64", "--replay.slots", "64"])
    assert paper_envs.command.stream_config().num_envs == 64
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["suite", "--env", "Ant", "--learner", "PRED", "--out", "x", "--scale",
                  "smoke", "--replay.slots", "12"])
    err = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 2 and len(err) == 1
    assert "replay.slots (12) must be a multiple of num_envs (8)" in err[0]
    assert "make replay.slots a multiple (e.g. 8) or change num_envs" in err[0]


def test_suite_call_flags_reach_the_run(monkeypatch, tmp_path):
    """`jaml suite` takes the training commands' call flags (`CallOptions`) and hands them to
    `stream.run.run` unchanged."""
    from jaml.stream import run as run_lib

    seen = {}

    def run(config, out, **kwargs):
        seen.update(kwargs)
        return {"status": "interrupted", "epoch": 3, "checkpoint_epoch": 3, "final": []}

    monkeypatch.setattr(run_lib, "run", run)
    assert cli.main(["suite", "--env", "CartPole", "--learner", "VAE_rpl",
                     "--out", str(tmp_path), "--stop-after", "3", "--checkpoint-every", "50",
                     "--no-final-checkpoint", "--no-keep-pi-rand", "--no-progress",
                     "--time-limit", "600"]) == 0
    deadline = seen.pop("deadline")
    assert seen == {"progress": False, "stop_after": 3, "checkpoint_every": 50,
                    "final_checkpoint": False, "keep_pi_rand": False}
    # Counted from the command's start (the module's import), not from the call.
    assert deadline == pytest.approx(_runs._STARTED + 600)


def test_a_bad_choice_is_one_line_naming_the_valid_values(capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["relations", "--source", "ellipse", "--out", "x", "--objective", "best"])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and len(err.strip().splitlines()) == 1
    assert err.startswith("jaml relations: error: invalid choice 'best'")
    assert "('paper', 'reference')" in err


@pytest.mark.parametrize(("given", "meant"), [(["--max-relation", "2"], "--max-relations"),
                                               (["--zzzz"], None)])
def test_a_misspelt_flag_is_one_line_naming_the_closest_one(capsys, given, meant):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["relations", "--source", "ellipse", "--out", "x", *given])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and len(err.strip().splitlines()) == 1
    assert err.startswith(f"jaml relations: error: Unrecognized options: {', '.join(given)}")
    assert ("perhaps you meant" in err) == (meant is not None)
    if meant:
        assert f"; perhaps you meant {meant} (see `jaml relations --help`)" in err


def test_a_value_no_type_of_a_union_takes_is_one_short_line(capsys):
    """tyro lists each type's own error after a union's (`int | None`); the line keeps the
    flag, the value and the types."""
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["relations", "--source", "ellipse", "--out", "x", "--codimension", "abc"])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2
    assert err == ("jaml relations: error: Error parsing --codimension: 'abc' is not None or INT "
                   "(see `jaml relations --help`)\n")


def test_a_bad_value_beside_help_is_refused_without_a_traceback(capsys):
    """`--help` with an invalid value: tyro's own message, exit 2, no Python traceback (the
    one-line rewrite has nothing to read there: stderr is not captured while helping)."""
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["envs", "show", "--env", "Nope", "--help"])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2
    assert "Nope" in err and "Traceback" not in err
    assert cli._one_line("") == "invalid arguments"


def test_verbose_shows_jamls_info_lines_not_other_libraries(capsys):
    """-v turned the root logger to INFO and Orbax / absl filled the output; now only jaml's
    loggers go to INFO, and a later call without -v is quiet again."""
    import logging

    assert cli.main(["-v", "envs", "list"]) == 0
    assert logging.getLogger("jaml.relations").getEffectiveLevel() == logging.INFO
    for other in ("absl", "orbax", "jax"):
        assert logging.getLogger(other).getEffectiveLevel() >= logging.WARNING, other
    assert cli.main(["envs", "list"]) == 0
    assert logging.getLogger("jaml.relations").getEffectiveLevel() == logging.WARNING
    assert logging.getLogger("jaml.resume").getEffectiveLevel() == logging.INFO
    capsys.readouterr()


def test_debug_shows_the_traceback(tmp_path, capsys):
    argv = ["relations", "--source", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "r")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "missing.csv: no such file" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert cli.main([*argv, "--debug"]) == 2
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "FileNotFoundError" in err


def test_sigterm_unwinds_like_ctrl_c_and_says_how_to_resume(monkeypatch, capsys):
    """`timeout` or a scheduler's SIGTERM raises KeyboardInterrupt in the command, so runs
    write their summaries (their `finally` blocks run); exit 130, and the handler is restored."""
    import signal
    import threading
    import time

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers need the main thread")
    unwound = []

    def killed(self):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(30)  # interrupted long before this ends
        finally:
            unwound.append(True)
        return 0

    monkeypatch.setattr(cli.Relations, "run", killed)
    before = signal.getsignal(signal.SIGTERM)
    assert cli.main(["relations", "--source", "ellipse", "--out", "unused dir"]) == 130
    assert unwound == [True] and signal.getsignal(signal.SIGTERM) is before
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["jaml: interrupted; resume with: jaml relations --source ellipse --out "
                   "'unused dir'"]


def test_relations_fit_a_csv_with_a_header(tmp_path, capsys):
    t = np.random.default_rng(0).uniform(0, 2 * np.pi, 200)
    rows = np.stack([np.cos(t), np.sin(t), 0.5 * np.cos(t)], axis=1)
    path = tmp_path / "rows.csv"
    path.write_text("a,b,c\n" + "\n".join(",".join(f"{v:.6f}" for v in r) for r in rows))
    out = tmp_path / "run"
    assert cli.main(["relations", "--source", str(path), "--out", str(out), *TINY]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["num_relations"] == 1 and summary["source"] == str(path)
    from jaml import relations

    assert relations.load(out / "checkpoint").dim_names == ("a", "b", "c")
    config = json.loads((out / "config.json").read_text())
    assert len(config["source_sha256"]) == 64


@pytest.mark.parametrize(("name", "text", "message"), [
    ("ragged.csv", "a,b\n1,2\n3\n", "line 3 has 1 columns, expected 2"),
    ("words.csv", "1,2\n3,x\n", "line 2: 'x' is not a number"),
    ("nan.csv", "a,b\n1,2\n3,nan\n", "non-finite values (NaN/inf), the first in row 1"),
    ("one.csv", "a,b\n1,2\n", "at least 2 rows"),
    ("rows.txt", "1,2\n3,4\n", "expected a .npy or .csv file"),
])
def test_a_malformed_file_is_a_clear_error(tmp_path, capsys, name, text, message):
    (tmp_path / name).write_text(text)
    code = cli.main(["relations", "--source", str(tmp_path / name), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2 and message in err, err


def test_a_npy_of_the_wrong_shape_is_a_clear_error(tmp_path, capsys):
    np.save(tmp_path / "flat.npy", np.arange(10.0))
    code = cli.main(["relations", "--source", str(tmp_path / "flat.npy"), "--out",
                     str(tmp_path / "r")])
    assert code == 2 and "expected an array of [N, D] rows, got shape (10,)" in (
        capsys.readouterr().err)


def test_envs_show_takes_the_envs_own_typed_options(monkeypatch, capsys, tmp_path):
    from envs_mjx import show

    calls = []
    monkeypatch.setattr(show, "show", lambda name, out, **kw: calls.append((name, kw)) or out)
    argv = ["envs", "show", "--env", "RearrangeGeom", "--env-config.arm", "franka",
            "--env-config.version", "7", "--steps", "2", "--out", str(tmp_path / "f.png")]
    assert cli.main(argv) == 0
    assert calls == [("RearrangeGeom", {"resets": 4, "steps": 2, "seed": 0, "arm": "franka",
                                        "version": 7})]
    assert "RearrangeGeom, arm=franka, version=7: 4 resets x 2 frames" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["envs", "show", "--env", "RearrangeGeom", "--env-config.arm", "ur5"])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and "invalid choice 'ur5'" in err and "franka" in err


def test_fig2_and_fig9_are_subcommands_and_modules(capsys):
    from jaml.experiments import fig2, fig9

    args = cli.parse(["fig2", "--out", "x", "--envs", "CartPole", "--variants", "PRED",
                      "--learner-opt", "frame_nll=mean", "--pendulum-epochs", "5"])
    assert isinstance(args.command, fig2.Args) and args.command.envs == ("CartPole",)
    assert args.command.learner_opt == ("frame_nll=mean",) and args.command.pendulum_epochs == 5
    args = cli.parse(["fig9", "--out", "x", "--methods", "PRED", "--form", "sum"])
    assert isinstance(args.command, fig9.Args) and args.command.form == "sum"
    with pytest.raises(SystemExit) as exit_info:
        fig2.main(["--help"])
    assert exit_info.value.code == 0 and "--pendulum-epochs INT" in capsys.readouterr().out


def test_bars_show_only_on_a_terminal_and_the_papers_scale_on_a_cpu_is_flagged(
        tmp_path, capsys, monkeypatch):
    """In a log file a bar's carriage returns join its updates into one line: no bar there;
    on a terminal `jaml suite` at the paper's scale on a CPU says it takes hours before its
    bar starts."""
    import io

    from jaml.stream import run as stream_run

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(sys, "stderr", Terminal())
    assert cli._bars(False) and not cli._bars(True)
    monkeypatch.setattr(sys, "stderr", io.StringIO())
    assert not cli._bars(False)
    monkeypatch.undo()
    calls = []

    def fake_run(config, out, progress, **options):
        calls.append(progress)
        return {"status": "finished", "epoch": 0, "checkpoint_epoch": None, "final": []}

    monkeypatch.setattr(stream_run, "run", fake_run)
    for scale, terminal, flagged in (("paper", True, True), ("smoke", True, False),
                                     ("paper", False, False)):
        monkeypatch.setattr(cli, "_bars", lambda no_progress, terminal=terminal: terminal)
        assert cli.main(["suite", "--env", "CartPole", "--learner", "VAE_rpl", "--scale", scale,
                         "--out", str(tmp_path / f"{scale}{terminal}")]) == 0
        assert ("the paper's scale on a CPU takes hours" in capsys.readouterr().err) == flagged
    assert calls == [True, True, False]


def test_a_runs_last_errors_are_wrapped_under_their_row(capsys):
    """Ant's 28 LD names under four reference rows: lines of at most 100 characters, every
    value once, a row's continuation indented under its head."""
    names = [f"qpos_{i}" for i in range(28)]
    cli._print_errors({"final": [{"test_set": "pi_rand", "errors": dict.fromkeys(names, 0.5)}],
                       "references": {"epoch": 4, "constant": {"pi_rand": [1.0] * 28}}})
    lines = capsys.readouterr().out.splitlines()
    assert max(map(len, lines)) <= 100 and len(lines) > 2
    assert lines[0].startswith("  pi_rand: qpos_0=0.500")
    head = next(i for i, x in enumerate(lines) if x.startswith("    constant (epoch 4): "))
    assert all(x.startswith("      ") for x in lines[1:head])
    assert all(x.startswith("        ") for x in lines[head + 1:])
    text = " ".join(lines)
    assert text.count("=0.500") == 28 and text.count("=1.000") == 28
