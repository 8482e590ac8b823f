"""`jaml info`, and the CLI's stdout free of mujoco.mjx's MuJoCo Warp probe prints."""

import importlib.metadata
import subprocess
import sys

import jax

from jaml.cli import _INFO_PACKAGES, main


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


def test_cli_stdout_has_no_warp_probe_lines():
    """A fresh process: mujoco.mjx's 'Failed to import warp' prints are captured by main."""
    result = subprocess.run(
        [sys.executable, "-m", "jaml.cli", "info"],
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    assert "Failed to import" not in result.stdout + result.stderr
    assert result.stdout.startswith("jax ")
