"""The command-line mechanism under `jaml.cli` and `python -m jaml.experiments.COMMAND`: tyro
over dataclasses, help from docstrings, choices, one-line errors, and the run loop (logging, the
compilation cache, SIGTERM as an interrupt). The commands themselves are given by the caller.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import logging
import os
import re
import shlex
import sys
import threading
import traceback
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import tyro

from jaml import _huge_pages, _interrupts


def _import_mjx_quietly() -> list[str]:
    """Import mujoco.mjx; return what its MuJoCo Warp probe printed, kept off stdout by
    `envs_mjx._quiet` (`jaml -v` logs it). Called once the arguments are parsed: the help and
    the parse itself import neither MuJoCo nor JAX (the configs they read are plain
    dataclasses)."""
    from envs_mjx import _quiet

    _quiet.install()
    with contextlib.suppress(ImportError):
        import mujoco.mjx  # noqa: F401
    return list(_quiet.probe_lines)

# ---------------------------------------------------------------------------------------------
# The mechanism: help from docstrings, hidden fields, one-line errors.


def field_docs(cls: type) -> dict[str, str]:
    """Field → help from the `name: text` entries of `cls`'s docstrings (its bases' first, so
    subclasses inherit them). Continuation lines (indented deeper) are joined; an entry may name
    several fields (`a, b: text` or `a / b: text`)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        current, indent = [], None
        for line in (klass.__dict__.get("__doc__") or "").splitlines():
            stripped = line.strip()
            depth = len(line) - len(stripped)
            head, _, text = stripped.partition(":")
            names = [n.strip() for n in re.split(r"[,/]", head)]
            if text and all(n.isidentifier() for n in names) and (indent is None
                                                                   or depth <= indent):
                current, indent = names, depth
                for n in names:
                    docs[n] = text.strip()
            elif current and stripped and depth > indent:
                for n in current:
                    docs[n] += " " + stripped
            else:
                current = []
    return docs


# (class name, field) of fields that are not flags: the suite sets them from --env/--learner
# (the learner's ld_dim is the env's LD-state size) and from the typed learner/env configs,
# which it holds with their concrete types (`jaml.cli._suite_for`).
_SUITE_FIXED = ("env", "learner", "env_config", "learner_config")
_HIDDEN = {("StreamConfig", name) for name in _SUITE_FIXED} | {("LearnerConfig", "ld_dim")}
_in_rule = threading.local()


def _registry() -> tyro.constructors.ConstructorRegistry:
    """tyro's dataclass handling, plus: help from `field_docs` where tyro finds none, and the
    `_HIDDEN` fields fixed to their defaults. Choices come from the fields' Literal types."""
    registry = tyro.constructors.ConstructorRegistry()

    @registry.struct_rule
    def documented(info: tyro.constructors.StructTypeInfo):
        cls = info.type
        if getattr(_in_rule, "active", False) or not (
            isinstance(cls, type) and dataclasses.is_dataclass(cls)
            and cls.__module__.split(".")[0] in ("jaml", "envs_mjx")
        ):
            return None
        _in_rule.active = True
        try:
            spec = tyro.constructors.ConstructorRegistry.get_struct_spec(info)
        finally:
            _in_rule.active = False
        if not isinstance(spec, tyro.constructors.StructConstructorSpec):
            return spec
        docs = field_docs(cls)
        bases = [k.__name__ for k in cls.__mro__]
        fields = []
        for f in spec.fields:
            kind = f.type
            if any((b, f.name) in _HIDDEN for b in bases):
                kind = tyro.conf.Suppress[kind]
            helptext = f.helptext() if callable(f.helptext) else f.helptext
            helptext = " ".join((helptext or docs.get(f.name) or "").split())  # unwrapped
            if kind is bool and f.default is True:
                # FlagCreatePairsOff: a True default makes the flag `--no-NAME`, which turns off
                # what the field's doc describes: say so, and give the default as "on" rather
                # than tyro's "(default: True)", which beside `--no-NAME` reads as the opposite.
                helptext = f"turn off: {helptext}" if helptext else f"turn off {f.name}"
                kind = Annotated[bool, tyro.conf.arg(help_behavior_hint="(default: on)")]
            fields.append(dataclasses.replace(f, type=kind, helptext=helptext or None))
        return dataclasses.replace(spec, fields=tuple(fields))

    return registry


def _one_line(box: str) -> str:
    """tyro's boxed error as one line: the message section, unwrapped, less the help texts of
    the arguments it names (indented under them). The box is drawn in UTF-8 (title in the top
    border) or, when stdout is not UTF-8, in ASCII (title, then a rule)."""
    text = re.sub(r"\x1b\[[0-9;]*m", "", box)
    unicode = text.lstrip().startswith("╭")
    sections: list[list[str]] = [[]]
    for line in text.splitlines():
        if line.strip().startswith(("╭", "╰")):
            continue
        content = line.strip().strip("│").rstrip()
        if content.strip() and set(content.strip()) <= set("─-"):
            sections.append([])
        elif content.strip():
            sections[-1].append(content)
    sections = [s for s in sections if s]
    if not sections:
        return "invalid arguments"
    first = 0 if unicode or len(sections) < 2 else 1
    message = sections[first]
    indent = min(len(x) - len(x.lstrip()) for x in message) if message else 0
    kept = [x.strip() for x in message if len(x) - len(x.lstrip()) < indent + 8]
    line = " ".join(" ".join(kept).split()) or "invalid arguments"
    # A union's value that fits none of its types: tyro lists each type's own error after it.
    union = re.match(r"(Error parsing \S+): no type matching (\S+) could be instantiated from "
                     r"\[(.*?)\]\.", line)
    if union:
        kinds = " or ".join(k.strip("{}") for k in union[2].split("|"))
        line = f"{union[1]}: {union[3]} is not {kinds}"
    # tyro's closest flag to a misspelt one, the first of its "Perhaps you meant" section.
    for section in sections[first + 1:]:
        if section[0].strip().startswith("Perhaps you meant"):
            flags = [x.split()[0] for x in section[1:] if x.strip().startswith("-")]
            if flags:
                return f"{line}; perhaps you meant {flags[0]}"
    return line


def _closed_loop_callback(unraisable) -> bool:
    """Whether an unraisable exception (`sys.unraisablehook`'s argument) is asyncio refusing a
    callback on an event loop already closed, from a thread nothing waits on any more: what
    Orbax leaves behind when a checkpoint read fails. It runs each read in a fresh event loop
    and closes it on the first error, while TensorStore completes the other reads later."""
    if unraisable.object is not None or not isinstance(unraisable.exc_value, RuntimeError):
        return False
    if str(unraisable.exc_value) != "Event loop is closed":
        return False
    return any(frame.name == "call_soon_threadsafe"
               and Path(frame.filename).parts[-2:] == ("asyncio", "base_events.py")
               for frame in traceback.extract_tb(unraisable.exc_traceback))


def quiet_closed_loop_callbacks(hook: Callable) -> Callable:
    """`hook`, a `sys.unraisablehook`, less `_closed_loop_callback`'s tracebacks: the command
    line's one-line error for an unreadable checkpoint is then not followed by asyncio's."""
    if getattr(hook, "quiets_closed_loops", False):
        return hook

    def quiet(unraisable) -> None:
        if not _closed_loop_callback(unraisable):
            hook(unraisable)

    quiet.quiets_closed_loops = True
    return quiet


def use_compilation_cache() -> str | None:
    """Turn on JAX's persistent compilation cache for the command line; returns its directory.

    Most of a short command's time on CPU is XLA compiling (`jaml relations` on the ellipse:
    the two relations' training loops take longer to compile than to run), and a second run of
    the same command compiles the same programs. The cache lives in $JAML_XLA_CACHE, default
    $XDG_CACHE_HOME/jaml/xla (~/.cache/jaml/xla); JAML_XLA_CACHE=off turns it off. A cache
    directory configured already (JAX_COMPILATION_CACHE_DIR, or by the caller) is kept. Only the
    command line does this: importing jaml as a library changes no global JAX setting."""
    import jax

    if jax.config.jax_compilation_cache_dir:
        return jax.config.jax_compilation_cache_dir
    setting = os.environ.get("JAML_XLA_CACHE", "")
    if setting.lower() == "off":
        return None
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    path = Path(setting) if setting else base / "jaml" / "xla"
    jax.config.update("jax_compilation_cache_dir", str(path))
    # JAX caches only programs that took over jax_persistent_cache_min_compile_time_secs to
    # compile (1 s by default); a relation's Flax init and its mean-|g| program compile in less
    # on a CPU, yet cost more than a cache read (docs/notes/relations.md).
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    return str(path)


def join_processes() -> int:
    """`jax.distributed.initialize` for a command started as one of several processes (on one
    host or several; docs/stream.md, "Several seeds and GPUs"); returns the process count.

    JAML_NUM_PROCESSES (N) and JAML_PROCESS_ID (0 … N-1) name this process, JAX_COORDINATOR_ADDRESS
    (host:port of process 0, read by JAX) where they meet; JAML_NUM_PROCESSES=auto leaves all
    three to JAX's cluster detection (SLURM, Open MPI, Cloud TPU). Unset: one process."""
    setting = os.environ.get("JAML_NUM_PROCESSES")
    if setting is None:
        return 1
    import jax

    if setting == "auto":
        jax.distributed.initialize()
    else:
        try:
            count, index = int(setting), int(os.environ["JAML_PROCESS_ID"])
        except (KeyError, ValueError):
            raise ValueError(f"JAML_NUM_PROCESSES={setting!r} needs an integer (or auto) and "
                             "JAML_PROCESS_ID this process's index from 0") from None
        jax.distributed.initialize(num_processes=count, process_id=index)
    return jax.process_count()


def _root(argv: list[str], commands: Callable[[list[str]], dict[str, type]],
          description: str) -> type:
    """The `jaml` dataclass: global flags and one subcommand per command (`commands(argv)`)."""
    choices = [Annotated[cls, tyro.conf.subcommand(name)] for name, cls in commands(argv).items()]
    if len(choices) < 2:  # a Union needs two members: one command is padded as tyro.extras does
        choices.append(Annotated[None, tyro.conf.Suppress])
    union = typing.Union[tuple(choices)]  # noqa: UP007

    help_debug = "show full tracebacks (and tyro's full parse errors) instead of one line"
    jaml = dataclasses.make_dataclass("Jaml", [
        ("command", tyro.conf.OmitSubcommandPrefixes[union]),
        ("debug", Annotated[bool, tyro.conf.CascadeSubcommandArgs,
                            tyro.conf.arg(help=help_debug)], False),
        ("verbose", Annotated[bool, tyro.conf.CascadeSubcommandArgs,
                              tyro.conf.arg(aliases=("-v",),
                                            help="jaml's own logs at INFO level")], False),
    ], frozen=True, namespace={"__doc__": description, "__module__": __name__})
    return jaml


# ---------------------------------------------------------------------------------------------
# The entry point.


def parse(argv: list[str], commands: Callable[[list[str]], dict[str, type]],
          description: str):
    """The parsed `jaml` dataclass. Parse errors exit with status 2 after one line on stderr
    (tyro's full message with --debug); --help exits 0."""
    argv = list(argv)
    debug = "--debug" in argv
    helping = "-h" in argv or "--help" in argv
    captured = io.StringIO()
    # One line per error message (so that it reads back as one line), unless shown in full.
    environ = {} if helping or debug else {"COLUMNS": "10000"}
    with contextlib.ExitStack() as stack:
        if not helping:
            stack.enter_context(contextlib.redirect_stderr(captured))
        old = {k: os.environ.get(k) for k in environ}
        os.environ.update(environ)
        try:
            return tyro.cli(_root(argv, commands, description), args=argv, prog="jaml",
                            registry=_registry(), config=(tyro.conf.FlagCreatePairsOff,))
        except SystemExit as exit_:
            if exit_.code:
                stack.close()
                prog = " ".join(["jaml", *[a for a in argv[:1] if not a.startswith("-")]])
                if debug:
                    sys.stderr.write(captured.getvalue())
                elif not helping:  # with --help, tyro's own message went to stderr as is
                    print(f"{prog}: error: {_one_line(captured.getvalue())} "
                          f"(see `{prog} --help`)", file=sys.stderr)
            raise
        finally:
            for k, v in old.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v


# The exit status of a command whose stdout was closed early (`jaml … --help | head`): 128 +
# SIGPIPE, what a shell reports for a process that signal ends.
CLOSED_STDOUT = 141


def main(argv, commands: Callable[[list[str]], dict[str, type]], description: str) -> int:
    """Parses `argv` (sys.argv[1:] when None) over `commands(argv)` (name → dataclass with a
    `run()` returning the exit status) and runs the command: every failure one line on stderr
    (status 2), an interrupt status 130, a stdout closed early quietly `CLOSED_STDOUT`. A
    process's own arguments (`argv` None) may first re-execute it with malloc on huge pages
    (`jaml._huge_pages`)."""
    if argv is None:
        _huge_pages.adopt()
    try:
        try:
            status = _main(argv, commands, description)
        finally:  # the help's SystemExit too: its text is written out here, inside the try
            sys.stdout.flush()
    except BrokenPipeError:
        # Python's recipe: stdout's reader has gone; point stdout at devnull so that the
        # interpreter's own flush at exit does not fail again.
        with contextlib.suppress(OSError, ValueError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return CLOSED_STDOUT
    return status


def _main(argv, commands: Callable[[list[str]], dict[str, type]], description: str) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parse(argv, commands, description)
    captured = _import_mjx_quietly()
    logging.basicConfig(
        level=logging.WARNING,
        format="%(asctime)s %(name)s %(message)s",
        datefmt="%H:%M:%S",
        # Importing orbax-checkpoint logs through absl (ArrayHandler's vlog), and absl calls
        # logging.basicConfig() when the root logger has no handler; ours would then be a no-op
        # and `-v` silent: replace that handler.
        force=True,
    )
    # -v: jaml's own INFO lines; other libraries' (absl, Orbax, JAX) stay at WARNING.
    logging.getLogger("jaml").setLevel(logging.INFO if args.verbose else logging.NOTSET)
    for line in captured:
        logging.getLogger("jaml.cli").info("import mujoco.mjx: %s", line)
    # What a resumed run resumed from (jaml.stream.run), shown without -v.
    logging.getLogger("jaml.resume").setLevel(logging.INFO)
    if not args.verbose:
        # Orbax's absl warnings ("Waiting for previous save to complete took 1.7 seconds. If
        # this number is high, consider checkpointing less frequently.") are about its own
        # timing, not a problem of the run: shown with -v.
        logging.getLogger("absl").setLevel(logging.ERROR)
    use_compilation_cache()
    sys.unraisablehook = quiet_closed_loop_callbacks(sys.unraisablehook)
    try:
        join_processes()
        with _interrupts.as_interrupt():
            return args.command.run()
    except BrokenPipeError:
        raise  # stdout closed early: `main`'s, quietly
    except Exception as error:  # every failure one line; the traceback with --debug
        if args.debug:
            traceback.print_exc()
        else:
            print(f"jaml: error: {error_line(error)} (--debug shows the traceback)",
                  file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        if args.debug:
            traceback.print_exc()
        print(f"jaml: interrupted; resume with: {resume_command(argv)}", file=sys.stderr)
        return 130


def resume_command(argv: list[str]) -> str:
    """The command line that resumes an interrupted command: the same one (a run directory
    resumes from its last checkpoint), shell-quoted."""
    return shlex.join(["jaml", *argv])


def error_line(error: BaseException) -> str:
    """One line naming the problem: the message unwrapped (its type for errors not raised by
    jaml's own checks), cut at 400 characters."""
    text = " ".join(str(error).split()) or "(no message)"
    if not isinstance(error, ValueError | TypeError | FileNotFoundError | RuntimeError):
        text = f"{type(error).__name__}: {text}"
    return text if len(text) <= 400 else text[:399] + "…"
