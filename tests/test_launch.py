"""`jaml ... --help`, every command's, is built from tyro and the config dataclasses alone: a
fresh process prints it without importing JAX, MJX, Flax or MuJoCo (nor Brax, Optax, Orbax,
Matplotlib, SciPy), so it needs no cache to be quick."""

import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("jax", "jaxlib", "mujoco", "flax", "brax", "optax", "orbax", "matplotlib", "scipy")
COMMANDS = [[], ["relations"], ["suite"], ["suite", "--env", "Ant", "--learner", "PRED"],
            ["suite", "--env", "RearrangeGeom", "--learner", "SPAIR"],
            ["suite", "--env", "CartPole", "--learner", "my_module:make"], ["fig2"], ["fig3"],
            ["fig9"], ["demo"], ["envs"], ["envs", "list"], ["envs", "show"],
            ["envs", "show", "--env", "MeshOnIncline"], ["info"]]

# Each command's help in one fresh process, through the console script's entry point; then the
# top-level packages of every module the process imported.
SCRIPT = """
import contextlib, io, json, sys
from jaml import _launch
shown = []
for argv in json.loads(sys.argv[1]):
    out = io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            code = _launch.main([*argv, "--help"])
    except SystemExit as exit_:
        code = exit_.code
    shown.append([code, out.getvalue()])
print(json.dumps({"shown": shown, "imported": sorted({m.split(".")[0] for m in sys.modules})}))
"""


def _python(*args, **env):
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=ROOT,
                          env=os.environ | {"COLUMNS": "100", "PYTHONPATH": str(ROOT), **env})


def test_every_commands_help_imports_no_jax_mjx_flax_or_mujoco():
    result = _python("-c", SCRIPT, json.dumps(COMMANDS))
    assert result.returncode == 0, result.stderr[-2000:]
    report = json.loads(result.stdout)
    for argv, (code, text) in zip(COMMANDS, report["shown"], strict=True):
        command = " ".join(["jaml", *itertools.takewhile(lambda a: not a.startswith("-"), argv)])
        assert code == 0 and text.startswith(f"usage: {command} "), (argv, code, text[:300])
    assert "tyro" in report["imported"]  # the help was built here, not read from anywhere
    assert not set(HEAVY) & set(report["imported"]), sorted(set(HEAVY) & set(report["imported"]))
    # The env's and the learner's own options are in their help: typed, from their configs.
    ant_pred = report["shown"][COMMANDS.index(["suite", "--env", "Ant", "--learner", "PRED"])][1]
    assert "--learner-config.hist" in ant_pred and "--env-config.episode-length" in ant_pred


def test_the_script_prints_help_and_passes_other_arguments_on():
    out = _python("-m", "jaml._launch", "relations", "--help")
    assert out.returncode == 0 and out.stdout.startswith("usage: jaml relations")
    assert "--max-relations INT" in out.stdout
    bad = _python("-m", "jaml._launch", "suite", "--env", "Nowhere", "--help")
    assert bad.returncode == 2 and "Nowhere" in bad.stderr and not bad.stdout
