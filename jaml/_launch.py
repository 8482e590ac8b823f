"""The `jaml` console script: `--help` served from a cache, everything else `jaml.cli.main`.

Building any command's help imports JAX, MJX and every config module (≈ 10 s on two CPU cores);
the text depends only on the arguments, the terminal width and the source. So a help request
is answered from $XDG_CACHE_HOME/jaml/help (~/.cache/jaml/help) when a previous call with the
same arguments, width, Python and source files (their sizes and mtimes) wrote it, with nothing
heavy imported; the first such call builds it as before. JAML_HELP_CACHE=off turns it off.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import shutil
import sys
from pathlib import Path

_PACKAGES = ("jaml", "envs_mjx")


def _source_stamp() -> list:
    """(path, size, mtime) of every Python file of jaml and envs_mjx."""
    root = Path(__file__).resolve().parents[1]
    stamp = []
    for package in _PACKAGES:
        for folder, _, files in os.walk(root / package):
            for name in sorted(files):
                if name.endswith(".py"):
                    stat = os.stat(os.path.join(folder, name))
                    stamp.append((os.path.join(folder, name), stat.st_size, stat.st_mtime_ns))
    return sorted(stamp)


def help_path(argv: list[str]) -> Path | None:
    """Where the help text for `argv` is cached, or None when the cache is off."""
    if os.environ.get("JAML_HELP_CACHE", "").lower() == "off":
        return None
    width = shutil.get_terminal_size().columns
    key = repr((argv, width, sys.stdout.isatty(), sys.stdout.encoding, sys.version,
                sys.executable, _source_stamp()))
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "jaml" / "help" / f"{hashlib.sha256(key.encode()).hexdigest()[:32]}.txt"


class _Like(io.StringIO):
    """A text buffer that reports the encoding and terminal of `stream`, so the help drawn into
    it (tyro's boxes, in UTF-8 or ASCII) is what `stream` would have shown."""

    def __init__(self, stream):
        super().__init__()
        self._stream = stream

    @property
    def encoding(self):
        return self._stream.encoding

    def isatty(self) -> bool:
        return self._stream.isatty()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    path = help_path(argv) if ("-h" in argv or "--help" in argv) else None
    if path is not None and path.is_file():
        sys.stdout.write(path.read_text())
        return 0
    from jaml import cli

    if path is None:
        return cli.main(argv)
    buffer = _Like(sys.stdout)
    try:
        with contextlib.redirect_stdout(buffer):
            code = cli.main(argv)
    except SystemExit as exit_:
        code = exit_.code or 0
    sys.stdout.write(buffer.getvalue())
    if code == 0 and buffer.getvalue():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(buffer.getvalue())
        tmp.replace(path)
    return code


if __name__ == "__main__":
    sys.exit(main())
