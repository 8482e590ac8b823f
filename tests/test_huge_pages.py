"""jaml's processes re-execute themselves once with glibc's malloc on transparent huge pages
(jaml._huge_pages): when, with what environment, and that the process stays the same one."""

import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from jaml import _huge_pages
from jaml._huge_pages import describe, environment, thp_mode

ROOT = Path(__file__).resolve().parents[1]
GLIBC = ("glibc", "2.36")


def test_the_environment_adds_the_tunable_to_what_is_there():
    env = environment({"PATH": "/bin"}, GLIBC, "madvise")
    assert env == {"PATH": "/bin", "GLIBC_TUNABLES": "glibc.malloc.hugetlb=1"}
    mine = {"GLIBC_TUNABLES": "glibc.malloc.arena_max=2"}
    assert environment(mine, GLIBC, "madvise") == {
        "GLIBC_TUNABLES": "glibc.malloc.arena_max=2:glibc.malloc.hugetlb=1"}


@pytest.mark.parametrize("environ, libc, mode", [
    ({"GLIBC_TUNABLES": "glibc.malloc.hugetlb=0"}, GLIBC, "madvise"),  # the user's way out
    ({"GLIBC_TUNABLES": "glibc.malloc.hugetlb=1"}, GLIBC, "madvise"),  # already re-executed
    ({}, ("glibc", "2.34"), "madvise"),  # before the tunable existed
    ({}, ("", ""), "madvise"),  # musl, or not Linux
    ({}, GLIBC, "always"),  # the kernel gives huge pages anyway
    ({}, GLIBC, "never"),  # it gives none
    ({}, GLIBC, None),  # unknown
])
def test_nothing_to_gain_leaves_the_process_as_it_is(environ, libc, mode):
    assert environment(environ, libc, mode) is None


def test_the_kernels_mode_is_the_bracketed_word(tmp_path):
    path = tmp_path / "enabled"
    path.write_text("always [madvise] never\n")
    assert thp_mode(path) == "madvise"
    assert thp_mode(tmp_path / "missing") is None


def test_describe_says_which_pages_and_why():
    assert describe({"GLIBC_TUNABLES": "glibc.malloc.hugetlb=1"}, GLIBC, "madvise") == (
        "huge pages (GLIBC_TUNABLES glibc.malloc.hugetlb=1)")
    assert describe({"GLIBC_TUNABLES": "glibc.malloc.hugetlb=0"}, GLIBC, "madvise") == (
        "4 KiB pages (GLIBC_TUNABLES glibc.malloc.hugetlb=0, transparent huge pages madvise)")
    assert describe({}, GLIBC, "never") == "4 KiB pages (glibc 2.36, transparent huge pages never)"
    assert describe({}, GLIBC, "always").startswith("huge pages")
    assert describe({}, ("", ""), None) == (
        "4 KiB pages (libc unknown, transparent huge pages unknown)")


HERE = _huge_pages.environment({}, platform.libc_ver(), thp_mode()) is not None
SCRIPT = ("import os; from jaml import _huge_pages; _huge_pages.adopt(); "
          "print(os.getpid(), os.environ.get('GLIBC_TUNABLES', ''))")


def _adopting(**env):
    base = {k: v for k, v in os.environ.items() if k != "GLIBC_TUNABLES"}
    process = subprocess.Popen([sys.executable, "-c", SCRIPT], stdout=subprocess.PIPE,
                               text=True, cwd=ROOT, env={**base, "PYTHONPATH": str(ROOT), **env})
    out, _ = process.communicate(timeout=60)
    pid, _, tunables = out.strip().partition(" ")
    return process.pid, int(pid), tunables


@pytest.mark.skipif(not HERE, reason="no glibc ≥ 2.35 with madvise huge pages here")
def test_a_process_reexecutes_itself_once_keeping_its_pid():
    started, ran, tunables = _adopting()
    assert ran == started and tunables == "glibc.malloc.hugetlb=1"
    started, ran, tunables = _adopting(GLIBC_TUNABLES="glibc.malloc.hugetlb=0")
    assert ran == started and tunables == "glibc.malloc.hugetlb=0"
