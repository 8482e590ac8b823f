"""The `jaml` command line: `jaml relations | suite | fig2 | fig3 | fig9 | demo | envs list|show |
info`.

One mechanism (tyro over dataclasses): each command is a dataclass whose fields, and the library
configs nested in it (relations.Config, StreamConfig and its PPOConfig, the learners' and the
envs' configs), become typed flags, with help from the dataclasses' docstrings and choices from
Literal types or the registries. Entry points stay thin.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import logging
import os
import re
import signal
import sys
import threading
import traceback
import typing
from pathlib import Path
from typing import Annotated, Literal

import tyro

from jaml.experiments._runs import CallOptions


def _import_mjx_quietly() -> list[str]:
    """Import mujoco.mjx with stdout captured; return what it printed.

    mujoco 4.0's mujoco.mjx.warp probes for MuJoCo Warp (optional, GPU; jaml does not use it)
    and, when absent, `print`s "Failed to import warp: …" and "Failed to import mujoco_warp: …"
    to stdout on every import: a print, not a logging call or warning, so no logger level or
    warnings filter silences it. Only jaml's entry point captures it (libraries leave stdout
    alone); `jaml -v` logs the captured lines."""
    if "mujoco.mjx" in sys.modules:
        return []
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer), contextlib.suppress(ImportError):
        import mujoco.mjx  # noqa: F401
    return buffer.getvalue().splitlines()


# Before anything imports envs_mjx (the command classes below read its registry).
_MJX_PRINTS = _import_mjx_quietly()

# ---------------------------------------------------------------------------------------------
# The mechanism: help from docstrings, choices, hidden fields, one-line errors.


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


def _choices() -> dict[tuple[str, str], tuple[str, ...]]:
    """(class name, field) → its valid values, for `str` fields whose set is fixed elsewhere
    (registries, validation in __post_init__)."""
    from envs_mjx.domains.rearrange import ARMS
    from jaml.stream import POLICIES

    return {
        ("StreamConfig", "policy"): POLICIES,
        ("RearrangeConfig", "arm"): ARMS,
        ("LearnerConfig", "frame_nll"): ("sum", "mean"),
        ("EnvConfig", "pixels"): ("auto", "required", "off"),
    }


# (class name, field) of fields that are not flags: the suite sets them from --env/--learner
# (the learner's ld_dim is the env's LD-state size) and from the typed learner/env configs.
_SUITE_FIXED = ("env", "learner", "learner_overrides", "env_overrides")
_HIDDEN = {("StreamConfig", name) for name in _SUITE_FIXED} | {("LearnerConfig", "ld_dim")}
_in_rule = threading.local()


def _registry() -> tyro.constructors.ConstructorRegistry:
    """tyro's dataclass handling, plus: help from `field_docs` where tyro finds none, Literal
    choices from `_choices`, and the `_HIDDEN` fields fixed to their defaults."""
    registry = tyro.constructors.ConstructorRegistry()
    choices = _choices()

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
            values = next((choices[b, f.name] for b in bases if (b, f.name) in choices), None)
            if values is not None:
                kind = Literal[values]
            if any((b, f.name) in _HIDDEN for b in bases):
                kind = tyro.conf.Suppress[kind]
            helptext = f.helptext() if callable(f.helptext) else f.helptext
            helptext = " ".join((helptext or docs.get(f.name) or "").split())  # unwrapped
            if kind is bool and f.default is True and helptext:
                # FlagCreatePairsOff: a True default makes the flag `--no-NAME`, which turns off
                # what the field's doc describes; say so.
                helptext = f"turn off (default on): {helptext}"
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
    message = sections[0] if unicode or len(sections) < 2 else sections[1]
    indent = min(len(x) - len(x.lstrip()) for x in message) if message else 0
    kept = [x.strip() for x in message if len(x) - len(x.lstrip()) < indent + 8]
    return " ".join(" ".join(kept).split()) or "invalid arguments"


# ---------------------------------------------------------------------------------------------
# Commands. Each `run()` returns the exit status.

KeyValues = Annotated[tuple[str, ...], tyro.conf.UseAppendAction,
                      tyro.conf.arg(metavar="KEY=VALUE")]


def key_value(text: str) -> tuple[str, object]:
    """KEY=VALUE with VALUE read as JSON where it parses (numbers, true, lists), else a string."""
    import json

    if "=" not in text:
        raise ValueError(f"expected KEY=VALUE, got {text!r}")
    key, value = text.split("=", 1)
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def key_values(items) -> dict[str, object]:
    """{KEY: VALUE} of KEY=VALUE texts; JSON lists become tuples (config ranges are tuples)."""
    pairs = (key_value(text) for text in items)
    return {k: tuple(v) if isinstance(v, list) else v for k, v in pairs}


def _print_summary(out, summary) -> None:
    print(
        f"{summary['source']}: {summary['num_relations']} relations, {summary['status']}, "
        f"{summary['seconds']:.1f}s -> {out}"
    )
    for r in summary["relations"]:
        print(
            f"  g{r['index']} (width {r['width']}): {r['status']} after {r['steps']} steps, "
            f"{r['seconds']:.1f}s, mean |g| on {r['on_mean']:.4g} off {r['off_mean']:.4g} "
            f"(x{r['ratio']:.1f}), syzygies {r['syzygies_found']}"
        )
    codim = summary.get("codimension") or {}
    if codim:
        print(f"  gradients of all {codim['relations']} independent (Jacobian rank "
              f"{codim['relations']}) on {100 * codim['full_rank_fraction']:.0f}% of "
              f"{codim['points']} on-manifold rows")


def _relations_config():
    from jaml.relations.config import Config

    return Config


@dataclasses.dataclass(frozen=True)
class Relations:
    """Learn AML relations g_1..g_K on a source's on-manifold rows (paper §3, Alg. 1) and write
    a run directory (config, metrics, checkpoint, summary, figures). Re-running with the same out
    directory and options resumes. Config defaults follow the paper."""

    source: str
    """a preset (ellipse, block45, block36-drag, block-drag-range, geom-on-incline,
    mesh-on-incline) or the path of a .npy file of [N, D] rows or a .csv file of N lines of D
    numbers, optionally after a header line of column names (they name the relations' inputs)"""
    out: Path
    """run directory"""
    source_opt: KeyValues = ()
    """source option or override (repeatable; presets only), e.g. for geom-on-incline /
    mesh-on-incline pool_size=65536, action_range=[0,0], friction_range=[0,0] (any field of the
    env's config); for the block presets a BlockOnIncline field, e.g. friction=0.1"""
    no_progress: bool = False
    """no progress bars"""
    config: Annotated[_relations_config(), tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=_relations_config())

    def run(self) -> int:
        from jaml.relations.run import run

        summary = run(self.source, self.config, self.out,
                      source_options=key_values(self.source_opt) or None,
                      progress=not self.no_progress)
        _print_summary(self.out, summary)
        return 0


def _suite_config():
    from jaml.stream import StreamConfig

    return StreamConfig


def _envs() -> tuple[str, ...]:
    import envs_mjx

    return envs_mjx.ALL_ENVS


def _learners() -> tuple[str, ...]:
    from jaml import learners

    return learners.ALL_LEARNERS


@dataclasses.dataclass(frozen=True)
class Suite:
    """The evaluation suite's learning loop (paper §2.1): PPO (or a random policy) acts in
    NUM_ENVS MJX envs; their 64×64 frames fill a replay that keeps its initial half; a learner
    trains on replay sequences and is analysed every EVAL_EVERY epochs by the alignment of its
    latents with the true state on π_rand and π_curr. Writes a run directory; re-running with the
    same out directory and options resumes from the last checkpoint. Defaults per env follow the
    reference suite (`jaml.stream.for_env`): `jaml suite --env ENV --learner LEARNER --help`
    shows them, with the env's and the learner's own options (env-config, learner-config)."""

    env: Literal[_envs()]
    """the MJX domain (`jaml envs list`)"""
    learner: Literal[_learners()]
    """the learner (jaml.learners), or your own as MODULE:FACTORY (docs/own_learner.md)"""
    out: Path
    """run directory"""
    call: Annotated[CallOptions, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=CallOptions)
    no_progress: bool = False
    """no progress bar"""
    scale: Literal["paper", "smoke"] = "paper"
    """sizes: "paper" (the reference's, for a GPU) or "smoke" (8 envs, 4 epochs, small analysis
    sets: minutes on a CPU; `jaml.suite.SCALES`); flags given beside it win"""
    config: Annotated[_suite_config(), tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=_suite_config())

    def stream_config(self):
        """The run's StreamConfig: `for_env`'s per-domain settings, then what the flags changed
        (learner and env options: the fields that differ from their defaults)."""
        from jaml.stream import for_env

        base = for_env(self.env, self.learner)
        changed = _changed(self.config, base, skip=_SUITE_FIXED)
        learner_opt, env_opt = dict(base.learner_overrides), {}
        learner_config = getattr(self, "learner_config", None)
        if learner_config is not None:
            learner_opt |= _changed(learner_config, _learner_default(self.learner),
                                    keep=base.learner_overrides, skip=("ld_dim",))
        env_config = getattr(self, "env_config", None)
        if env_config is not None:
            env_opt = _changed(env_config, _env_default(self.env))
        from jaml.suite import scaled

        return scaled(base, self.scale).replace(**changed, learner_overrides=learner_opt,
                                                env_overrides=env_opt)

    def run(self) -> int:
        from jaml.stream.run import run

        config = self.stream_config()
        summary = run(config, self.out, progress=not self.no_progress,
                      **dataclasses.asdict(self.call))
        resumed = ("" if summary.get("resumed_from") is None
                   else f", resumed from epoch {summary['resumed_from']}")
        print(f"{config.env} {config.learner} ({config.policy}): {summary['status']} at epoch "
              f"{summary['epoch']}{resumed}, checkpoint {summary['checkpoint_epoch']} -> "
              f"{self.out}")
        for r in summary["final"]:
            errs = " ".join(f"{k}={v:.3f}" for k, v in r["errors"].items())
            print(f"  {r['test_set']}: {errs}")
        return 0


def _learner_default(name: str):
    from jaml import learners

    # ld_dim comes from the env when the stream builds the learner; 1 stands in for help.
    return learners.default_config(name, ld_dim=1)


def _env_default(name: str):
    import envs_mjx

    return envs_mjx.default_config(name)


def _changed(config, default, keep=(), skip=()) -> dict:
    """The fields of `config` that differ from `default`, or are in `keep`, less `skip`."""
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)
            if f.name not in skip and (f.name in keep or getattr(config, f.name)
                                       != getattr(default, f.name))}


def _suite_for(argv: list[str]) -> type:
    """Suite, or when argv names a valid --env and --learner, a Suite whose defaults are that
    pair's (`for_env`) with the learner's and the env's configs as typed flags."""

    env, learner = _flag(argv, "--env"), _flag(argv, "--learner")
    if learner is not None and ":" in learner:
        # Your own learner, MODULE:FACTORY (jaml.stream.loop.make_learner): any name.
        return dataclasses.make_dataclass(
            "Suite", [("learner", str)], bases=(Suite,), frozen=True,
            namespace={"__doc__": Suite.__doc__, "__module__": __name__})
    if env not in _envs() or learner not in _learners():
        return Suite
    from jaml.stream import for_env

    base = for_env(env, learner)
    learner_config = _learner_default(learner).replace(**base.learner_overrides)
    env_config = _env_default(env)
    return dataclasses.make_dataclass(
        "Suite",
        [
            ("config", Annotated[_suite_config(), tyro.conf.arg(name="")],
             dataclasses.field(default=base)),
            ("learner_config", type(learner_config), dataclasses.field(default=learner_config)),
            ("env_config", type(env_config), dataclasses.field(default=env_config)),
        ],
        bases=(Suite,),
        frozen=True,
        namespace={"__doc__": Suite.__doc__, "__module__": __name__},
    )


@dataclasses.dataclass(frozen=True)
class Demo:
    """The quick tour: learn two relations with transversality on the ellipse and on the 45°
    block-on-incline, writing run directories and figures."""

    out: Path = Path("runs/demo")
    """parent run directory"""
    no_progress: bool = False
    """no progress bars"""

    def run(self) -> int:
        from jaml.relations.config import Config
        from jaml.relations.run import run

        for source in ("ellipse", "block45"):
            print(f"== AML with transversality on {source} (2 relations) ==", flush=True)
            summary = run(source, Config(max_relations=2), self.out / source,
                          progress=not self.no_progress)
            _print_summary(self.out / source, summary)
        print(f"figures: {sorted(str(p) for p in self.out.rglob('*.png'))}")
        return 0


@dataclasses.dataclass(frozen=True)
class EnvsList:
    """Each env with its action size and LD state (size and names)."""

    def run(self) -> int:
        from envs_mjx.show import format_list, list_envs

        print(format_list(list_envs()))
        return 0


@dataclasses.dataclass(frozen=True)
class EnvsShow:
    """PNG grid of rendered frames from random-action rollouts: rows are resets (so per-episode
    colours show), columns are time; frames come from the env's own pixels path
    (envs_mjx.render). `jaml envs show --env ENV --help` lists the env's own options
    (env-config), e.g. `--env-config.arm franka` for the Rearrange domains."""

    env: Literal[_envs()]
    """the MJX domain (`jaml envs list`)"""
    out: Path | None = None
    """PNG path (default: ENV.png)"""
    resets: int = 4
    """rows: independent resets"""
    steps: int = 8
    """columns: frames per reset"""
    seed: int = 0
    """PRNG seed"""

    def run(self) -> int:
        from envs_mjx.show import show

        out = self.out or Path(f"{self.env}.png")
        env_config = getattr(self, "env_config", None)
        overrides = {} if env_config is None else _changed(env_config, _env_default(self.env))
        path = show(self.env, out, resets=self.resets, steps=self.steps, seed=self.seed,
                    **overrides)
        options = "".join(f", {k}={v}" for k, v in overrides.items())
        print(f"{self.env}{options}: {self.resets} resets x {self.steps} frames -> {path}")
        return 0


def _flag(argv: list[str], flag: str) -> str | None:
    """The value given to `flag` in argv (`--flag VALUE` or `--flag=VALUE`), else None."""
    for i, arg in enumerate(argv):
        if arg == flag and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(flag + "="):
            return arg.split("=", 1)[1]
    return None


def _envs_for(argv: list[str]) -> type:
    """Envs, or when argv names a valid --env, an Envs whose `show` takes that env's config as
    typed flags (env-config)."""
    env = _flag(argv, "--env")
    if env not in _envs():
        return Envs
    env_config = _env_default(env)
    show = dataclasses.make_dataclass(
        "EnvsShow",
        [("env_config", type(env_config), dataclasses.field(default=env_config))],
        bases=(EnvsShow,),
        frozen=True,
        namespace={"__doc__": EnvsShow.__doc__, "__module__": __name__},
    )
    return dataclasses.make_dataclass(
        "Envs",
        [("action", tyro.conf.OmitSubcommandPrefixes[
            Annotated[EnvsList, tyro.conf.subcommand("list")]
            | Annotated[show, tyro.conf.subcommand("show")]])],
        bases=(Envs,),
        frozen=True,
        namespace={"__doc__": Envs.__doc__, "__module__": __name__},
    )


@dataclasses.dataclass(frozen=True)
class Envs:
    """The MJX domains (envs_mjx): list them, look at them."""

    action: tyro.conf.OmitSubcommandPrefixes[
        Annotated[EnvsList, tyro.conf.subcommand("list")]
        | Annotated[EnvsShow, tyro.conf.subcommand("show")]
    ]

    def run(self) -> int:
        return self.action.run()


_INFO_PACKAGES = ("jax", "jaxlib", "flax", "optax", "orbax-checkpoint", "brax", "mujoco",
                  "mujoco-mjx")


@dataclasses.dataclass(frozen=True)
class Info:
    """JAX version, backend and devices; package versions; whether MJX imports."""

    def run(self) -> int:
        import importlib
        import importlib.metadata

        import jax

        print(f"jax {jax.__version__}, default backend {jax.default_backend()}")
        for device in jax.devices():
            print(f"  device {device.id}: platform {device.platform}, kind {device.device_kind}")
        for name in _INFO_PACKAGES:
            try:
                version = importlib.metadata.version(name)
            except importlib.metadata.PackageNotFoundError:
                version = "not installed"
            print(f"{name} {version}")
        for label, module in (("MJX physics", "mujoco.mjx"),
                              ("MJX renderer", "envs_mjx.render")):
            try:
                importlib.import_module(module)
                print(f"{label} ({module}): import ok")
            except Exception as error:  # report any failure, this is a diagnostic
                print(f"{label} ({module}): import FAILED: {type(error).__name__}: {error}")
        with contextlib.suppress(Exception):
            from mujoco.mjx import warp

            print(f"MuJoCo Warp (optional, unused by jaml): "
                  f"{'installed' if warp.WARP_INSTALLED else 'not installed'}")
        cache = jax.config.jax_compilation_cache_dir
        print(f"XLA compilation cache: {cache or 'off'} (JAML_XLA_CACHE)")
        return 0


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
    # compile (1 s by default). On CPU a relation's Flax init and its mean-|g| program take
    # 0.4-0.8 s each, ~2 s of every `jaml relations` run, against a file read of milliseconds.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)
    return str(path)


def _commands(argv: list[str]) -> dict[str, type]:
    from jaml.experiments import fig2, fig3, fig9

    return {"relations": Relations, "suite": _suite_for(argv), "fig2": fig2.Args,
            "fig3": fig3.Args, "fig9": fig9.Args, "demo": Demo, "envs": _envs_for(argv),
            "info": Info}


def _root(argv: list[str]) -> type:
    """The `jaml` dataclass: global flags and one subcommand per command."""
    union = typing.Union[tuple(Annotated[cls, tyro.conf.subcommand(name)]  # noqa: UP007
                               for name, cls in _commands(argv).items())]

    help_debug = "show full tracebacks (and tyro's full parse errors) instead of one line"
    jaml = dataclasses.make_dataclass("Jaml", [
        ("command", tyro.conf.OmitSubcommandPrefixes[union]),
        ("debug", Annotated[bool, tyro.conf.CascadeSubcommandArgs,
                            tyro.conf.arg(help=help_debug)], False),
        ("verbose", Annotated[bool, tyro.conf.CascadeSubcommandArgs,
                              tyro.conf.arg(aliases=("-v",), help="log at INFO level")], False),
    ], frozen=True, namespace={"__doc__": __doc__.split("\n\n")[0], "__module__": __name__})
    return jaml


# ---------------------------------------------------------------------------------------------
# The entry point.


def _deprecated_forms(argv: list[str]) -> list[str]:
    """`envs show NAME` (positional) → `envs show --env NAME`, with a deprecation note."""
    for i in range(len(argv) - 2):
        if argv[i:i + 2] == ["envs", "show"] and not argv[i + 2].startswith("-"):
            print(f"jaml: `envs show {argv[i + 2]}` is deprecated; use `envs show --env "
                  f"{argv[i + 2]}`", file=sys.stderr)
            return [*argv[:i + 2], "--env", *argv[i + 2:]]
    return argv


def parse(argv: list[str]):
    """The parsed `jaml` dataclass. Parse errors exit with status 2 after one line on stderr
    (tyro's full message with --debug); --help exits 0."""
    argv = _deprecated_forms(list(argv))
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
            return tyro.cli(_root(argv), args=argv, prog="jaml", registry=_registry(),
                            config=(tyro.conf.FlagCreatePairsOff,))
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


def main(argv=None) -> int:
    captured = [*_MJX_PRINTS, *_import_mjx_quietly()]
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parse(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(asctime)s %(name)s %(message)s",
        datefmt="%H:%M:%S",
        # Importing orbax-checkpoint logs through absl (ArrayHandler's vlog), and absl calls
        # logging.basicConfig() when the root logger has no handler; ours would then be a no-op
        # and `-v` silent: replace that handler.
        force=True,
    )
    for line in captured:
        logging.getLogger(__name__).info("import mujoco.mjx: %s", line)
    # What a resumed run resumed from (jaml.stream.run), shown without -v.
    logging.getLogger("jaml.resume").setLevel(logging.INFO)
    if not args.verbose:
        # Orbax's absl warnings ("Waiting for previous save to complete took 1.7 seconds. If
        # this number is high, consider checkpointing less frequently.") are about its own
        # timing, not a problem of the run: shown with -v.
        logging.getLogger("absl").setLevel(logging.ERROR)
    use_compilation_cache()
    try:
        with _sigterm_as_interrupt():
            return args.command.run()
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
        print("jaml: interrupted; run directories keep their last checkpoint and summary, and "
              "the same command resumes", file=sys.stderr)
        return 130


def error_line(error: BaseException) -> str:
    """One line naming the problem: the message unwrapped (its type for errors not raised by
    jaml's own checks), cut at 400 characters."""
    text = " ".join(str(error).split()) or "(no message)"
    if not isinstance(error, ValueError | TypeError | FileNotFoundError | RuntimeError):
        text = f"{type(error).__name__}: {text}"
    return text if len(text) <= 400 else text[:399] + "…"


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """SIGTERM (`timeout`, a batch scheduler's preemption) raises KeyboardInterrupt like Ctrl-C,
    so runs unwind through their `finally` blocks and write their summaries instead of dying
    mid-epoch. Only the main thread can install handlers; elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
