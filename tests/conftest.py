"""Test-session setup: two XLA:CPU devices, cheap XLA codegen where compiling dominates, and a
persistent XLA cache shared by the run's workers.

Two host devices let the default suite run the multi-device code (runs split across a mesh,
`tests/stream/test_stacked.py`) on a CPU-only machine; XLA reads the flag when its backend
starts, so it is set before JAX is imported. Single-device code is unaffected: arrays live on
device 0 unless a test shards them.

Most tests run small shapes for a few steps, so their time is XLA compilation: they compile
with `jax_disable_most_optimizations` (LLVM backend level 0; the same HLO passes, so the same
programs), which cut the learner tests from 240 s to 172 s. Modules that run long training
loops are marked `xla_optimized` and compile at XLA's full level: at level 0 the relation
learning tests took 185 s against 118 s. `JAML_TEST_XLA=optimized|fast` forces one setting for
every module (to compare). A test's own long loop in a cheap module compiles at the full level
inside `xla_optimized()`. In the cheap modules a program's own LLVM level (the relation loops
ask for 1) is lowered to 0 as well: their loops are short there. A test whose relation loops run
thousands of steps is marked `loop_level` and keeps the level it asks for. The persistent cache
is shared by the xdist workers of one run (the controller makes it, the workers inherit its
path), so a program one worker compiled is read, not rebuilt, by the other; it is removed when
the run ends.
The cheap setting also compiles with XLA:CPU's older (elemental) fusion emitters, the option
jaml already gives its env programs (`envs_mjx/compile.py`): the same HLO, emitted by the older
code generator, which compiles the stream's rendering rollouts and learner steps faster (on two
cores test_suite_api took 163 s of CPU against 227 s). A module whose checks compare two code
paths' floats at the default emitters' rounding is marked `xla_fusion_emitters` and keeps them.
Modules marked `first` are collected first, and xdist's loadfile hands out whole modules in
collection order: by default xdist reorders them by their number of tests, which started the long
modules of a few tests (test_suite_api, the Franka's contract) last, each then ending the run on
one worker while the other sat idle; `pytest_configure` turns that reordering off.
"""

import contextlib
import os
import shutil
import sys
import tempfile

import pytest

_TWO_DEVICES = "--xla_force_host_platform_device_count=2"
os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_TWO_DEVICES}".strip()

import jax  # noqa: E402
from jax._src import compiler as _compiler  # noqa: E402

from jaml._command import quiet_closed_loop_callbacks  # noqa: E402

# The run's first process (xdist's controller, or the only one) makes the cache directory and
# removes it at its end; the workers it starts find the directory in their environment.
_cache = os.environ.get(_CACHE_VARIABLE := "JAML_TEST_XLA_CACHE")
_OWN_CACHE = _cache is None
if _OWN_CACHE:
    _cache = os.environ[_CACHE_VARIABLE] = tempfile.mkdtemp(prefix="jaml-xla-cache-")
# Each `relations.fit` builds fresh jitted closures; with a persistent cache the XLA
# compilation of an identical program is reused across fits and across the run's workers
# (the cache key includes the optimisation setting).
jax.config.update("jax_compilation_cache_dir", _cache)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)

_FORCED = os.environ.get("JAML_TEST_XLA")
if _FORCED not in (None, "optimized", "fast"):
    raise ValueError(f"JAML_TEST_XLA must be 'optimized' or 'fast', got {_FORCED!r}")


_OLDER_EMITTERS = [False]  # the current module's setting, read at each compile
_CHEAP = [False]  # the module compiles cheaply: no program's own backend level above 0
_SETTING = [None]  # (optimized, older emitters) of the worker's previous module
_get_compile_options = _compiler.get_compile_options


def _compile_options(*args, env_options_overrides=None, **kwargs):
    """JAX's compile options, with the older fusion emitters while `_OLDER_EMITTERS` holds (a
    program's own `compiler_options` still win), and LLVM's level 0 while `_CHEAP` holds, even
    for a program that asks for more (the relation loops' level 1 is for long fits)."""
    if _OLDER_EMITTERS[0]:
        env_options_overrides = {"xla_cpu_use_fusion_emitters": False,
                                 **(env_options_overrides or {})}
    if _CHEAP[0] and (env_options_overrides or {}).get("xla_backend_optimization_level"):
        env_options_overrides = {**env_options_overrides, "xla_backend_optimization_level": 0}
    return _get_compile_options(*args, env_options_overrides=env_options_overrides, **kwargs)


_compiler.get_compile_options = _compile_options


@pytest.fixture(autouse=True, scope="module")
def _xla_optimization(request):
    """Full XLA optimisation for modules marked `xla_optimized`, most of it off (and the older
    fusion emitters, unless marked `xla_fusion_emitters`) for the rest (read at each compile, so
    it holds for what the module's fixtures and tests compile)."""
    optimized = request.node.get_closest_marker("xla_optimized") is not None
    if _FORCED:
        optimized = _FORCED == "optimized"
    older = not optimized and request.node.get_closest_marker("xla_fusion_emitters") is None
    if _SETTING[0] not in (None, (optimized, older)):
        # Neither setting is in JAX's in-memory executable keys: without this, a module would
        # run ops an earlier module of the worker compiled at the other setting (test_api's
        # checkpoint round trip after test_learning got two roundings of one function).
        jax.clear_caches()
    _SETTING[0] = (optimized, older)
    jax.config.update("jax_disable_most_optimizations", not optimized)
    _OLDER_EMITTERS[0] = older
    _CHEAP[0] = not optimized
    yield


@pytest.fixture(autouse=True)
def _loop_level(request):
    """A test marked `loop_level` in a cheap module compiles its programs at the LLVM level they
    ask for (the relation loops' 1): its loops run thousands of steps, slower at level 0."""
    if request.node.get_closest_marker("loop_level") is None:
        yield
        return
    cheap = _CHEAP[0]
    _CHEAP[0] = False
    try:
        yield
    finally:
        _CHEAP[0] = cheap


@contextlib.contextmanager
def xla_optimized():
    """Inside the block, programs compile as in a module marked `xla_optimized`: for one long
    loop in a module that otherwise compiles cheaply. A program compiled inside is what JAX runs
    again for the same call outside (its in-memory keys hold neither setting): keep the block to
    the loop's own calls. `JAML_TEST_XLA=fast` keeps it cheap here too."""
    if _FORCED == "fast":
        yield
        return
    optimized, older = _SETTING[0]
    jax.config.update("jax_disable_most_optimizations", False)
    _OLDER_EMITTERS[0] = _CHEAP[0] = False
    try:
        yield
    finally:
        jax.config.update("jax_disable_most_optimizations", not optimized)
        _OLDER_EMITTERS[0], _CHEAP[0] = older, not optimized


@pytest.hookimpl(trylast=True)  # after pytest's own unraisable-exception hook is in place
def pytest_configure(config):
    """xdist's loadfile keeps the collection order (`--no-loadscope-reorder`), `first` included.
    The command line's filter of Orbax's closed-loop callbacks wraps pytest's unraisable hook:
    after a checkpoint read fails, they land in whichever test runs next, as a warning."""
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False
    sys.unraisablehook = quiet_closed_loop_callbacks(sys.unraisablehook)


def pytest_unconfigure(config):
    """The run's persistent cache goes with it (tens of MB a run, left in the temp directory)."""
    if _OWN_CACHE:
        shutil.rmtree(_cache, ignore_errors=True)


def pytest_collection_modifyitems(items):
    """Modules marked `first` before the rest (a stable sort: the order within each is kept)."""
    items.sort(key=lambda item: item.get_closest_marker("first") is None)
