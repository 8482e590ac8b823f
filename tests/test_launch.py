"""The `jaml` script's help cache: the same text as `jaml.cli`, under 2 s once built."""

import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _jaml(args, cache: Path, **env):
    tic = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "jaml._launch", *args], capture_output=True,
                         text=True, cwd=ROOT,
                         env=os.environ | {"XDG_CACHE_HOME": str(cache), "COLUMNS": "100",
                                           "PYTHONPATH": str(ROOT), **env})
    return out, time.perf_counter() - tic


def test_help_is_cached_per_arguments_and_served_fast(tmp_path):
    cache = tmp_path / "cache"
    direct = subprocess.run([sys.executable, "-m", "jaml.cli", "--help"], capture_output=True,
                            text=True, cwd=ROOT, env=os.environ | {"COLUMNS": "100",
                                                                   "PYTHONPATH": str(ROOT)})
    first, _ = _jaml(["--help"], cache)
    assert first.returncode == 0 and first.stdout == direct.stdout
    assert "suite" in first.stdout and "relations" in first.stdout
    (written,) = (cache / "jaml" / "help").iterdir()
    times = []
    for _ in range(3):  # fresh processes
        again, seconds = _jaml(["--help"], cache)
        assert again.returncode == 0 and again.stdout == first.stdout
        times.append(seconds)
    assert min(times) < 2.0, times
    other, _ = _jaml(["envs", "--help"], cache)
    assert other.returncode == 0 and other.stdout != first.stdout
    assert len(list((cache / "jaml" / "help").iterdir())) == 2
    assert written.read_text() == first.stdout


def test_the_cache_can_be_turned_off_and_other_commands_pass_through(tmp_path):
    cache = tmp_path / "cache"
    out, _ = _jaml(["--help"], cache, JAML_HELP_CACHE="off")
    assert out.returncode == 0 and "suite" in out.stdout
    assert not (cache / "jaml" / "help").exists()
    bad, _ = _jaml(["suite", "--env", "Nowhere", "--help"], cache)
    assert bad.returncode == 2 and not (cache / "jaml" / "help").exists()
