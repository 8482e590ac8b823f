"""mujoco.mjx's MuJoCo Warp probe kept off stdout, whoever imports mujoco.mjx first (brax does).

mujoco 4.0's mujoco.mjx.warp `print`s "Failed to import warp: …" and "Failed to import
mujoco_warp: …" on every import without MuJoCo Warp (optional, GPU; unused here): a print, so
no logger or warnings filter silences it. `install` (run by `import envs_mjx`) captures that
module's stdout while it runs, keeps those lines in `probe_lines` and writes any other line
through.
"""

from __future__ import annotations

import contextlib
import importlib.abc
import importlib.machinery
import io
import sys

PROBE_MODULE = "mujoco.mjx.warp"
PROBE_PREFIXES = ("Failed to import warp:", "Failed to import mujoco_warp:")
# What the probe printed in this process (`jaml -v` logs it).
probe_lines: list[str] = []


class _QuietLoader(importlib.abc.Loader):
    """The probe module's own loader, its stdout captured while the module runs."""

    def __init__(self, loader):
        self._loader = loader

    def __getattr__(self, name):
        return getattr(self._loader, name)

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:
        buffer = io.StringIO()
        try:
            with contextlib.redirect_stdout(buffer):
                self._loader.exec_module(module)
        finally:
            for line in buffer.getvalue().splitlines(keepends=True):
                if line.startswith(PROBE_PREFIXES):
                    probe_lines.append(line.rstrip("\n"))
                else:
                    sys.stdout.write(line)


class _QuietFinder(importlib.abc.MetaPathFinder):
    """Finds the probe module as the path finder does, with `_QuietLoader` as its loader."""

    def find_spec(self, name, path, target=None):
        if name != PROBE_MODULE:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path, target)
        if spec is not None and spec.loader is not None:
            spec.loader = _QuietLoader(spec.loader)
        return spec


def install() -> None:
    """Quiet the probe from now on (once per process; imports nothing)."""
    if not any(isinstance(finder, _QuietFinder) for finder in sys.meta_path):
        sys.meta_path.insert(0, _QuietFinder())
