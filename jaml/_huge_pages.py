"""Transparent huge pages for malloc in jaml's own processes (Linux, glibc ≥ 2.35).

XLA:CPU allocates a program's temporaries afresh on every call, as one large block that glibc
maps and unmaps each time, so with 4 KiB pages the kernel faults every page of it in again on
every train step. glibc's `glibc.malloc.hugetlb=1` tunable has malloc ask for transparent huge
pages instead (`madvise`), but glibc reads its tunables only when a process starts: a command
that wants them re-executes itself once, same PID and arguments, with the tunable set.
`GLIBC_TUNABLES=glibc.malloc.hugetlb=0` (or any hugetlb setting of one's own) leaves the
process as it is.
"""

from __future__ import annotations

import os
import platform
import sys
from collections.abc import Mapping
from pathlib import Path

TUNABLE = "glibc.malloc.hugetlb"
THP_ENABLED = Path("/sys/kernel/mm/transparent_hugepage/enabled")


def thp_mode(path: Path = THP_ENABLED) -> str | None:
    """The kernel's transparent-huge-page mode ("always", "madvise", "never"), None unknown."""
    try:
        text = path.read_text()
    except OSError:
        return None
    chosen = [word[1:-1] for word in text.split() if word.startswith("[")]
    return chosen[0] if chosen else None


def environment(environ: Mapping[str, str], libc: tuple[str, str],
                mode: str | None) -> dict[str, str] | None:
    """The environment to re-execute with, or None where there is nothing to gain: not glibc
    ≥ 2.35 (`platform.libc_ver()`), a kernel that gives huge pages always or never rather
    than on `madvise`, or a hugetlb setting already in GLIBC_TUNABLES (the user's own, or
    this process already re-executed)."""
    name, version = libc
    if name != "glibc" or mode != "madvise" or TUNABLE in environ.get("GLIBC_TUNABLES", ""):
        return None
    try:
        if tuple(int(part) for part in version.split(".")[:2]) < (2, 35):
            return None
    except ValueError:
        return None
    tunables = ":".join(filter(None, [environ.get("GLIBC_TUNABLES", ""), f"{TUNABLE}=1"]))
    return {**environ, "GLIBC_TUNABLES": tunables}


def describe(environ: Mapping[str, str], libc: tuple[str, str], mode: str | None) -> str:
    """Whether malloc asks for huge pages in a process of this environment, and why (`jaml
    info`)."""
    tunables = environ.get("GLIBC_TUNABLES", "")
    setting = [item for item in tunables.split(":") if item.startswith(f"{TUNABLE}=")]
    thp = f"transparent huge pages {mode or 'unknown'}"
    if mode == "always":
        return "huge pages (the kernel's transparent huge pages are always on)"
    if setting and setting[-1] != f"{TUNABLE}=0" and mode == "madvise":
        return f"huge pages (GLIBC_TUNABLES {setting[-1]})"
    if setting:
        return f"4 KiB pages (GLIBC_TUNABLES {setting[-1]}, {thp})"
    return f"4 KiB pages ({' '.join(filter(None, libc)) or 'libc unknown'}, {thp})"


def adopt() -> None:
    """Re-executes this process with malloc on transparent huge pages where that applies
    (`environment`); returns where it does not. Call it first thing in a process's entry point,
    before any thread starts: exec replaces the process, keeping its PID and open files."""
    if sys.platform != "linux" or not getattr(sys, "orig_argv", None):
        return
    env = environment(os.environ, platform.libc_ver(), thp_mode())
    if env is None:
        return
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, sys.orig_argv, env)
