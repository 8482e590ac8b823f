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
import os
import platform
import sys
import textwrap
from pathlib import Path
from typing import Annotated, Literal

import tyro

from envs_mjx.config import ALL_ENVS, default_config
from jaml import _command, _huge_pages
from jaml._command import _SUITE_FIXED, _one_line, use_compilation_cache  # noqa: F401
from jaml._options import KeyValues, key_value, key_values  # noqa: F401
from jaml.configs.learners import ALL_LEARNERS
from jaml.configs.relations import Config
from jaml.configs.stream import SCALES, StreamConfig, changed_fields, for_env, scaled
from jaml.experiments import fig2, fig3, fig9
from jaml.experiments._runs import CallOptions

# The root's description in `jaml --help`.
DESCRIPTION = __doc__.split("\n\n")[0]

# ---------------------------------------------------------------------------------------------
# Commands. Each `run()` returns the exit status.


def _bars(no_progress: bool) -> bool:
    """Progress bars unless turned off or stderr is not a terminal (in a log file a bar's
    carriage returns join every update into one line)."""
    return not no_progress and sys.stderr.isatty()


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
    report = summary.get("quality") or {}
    for line in report.get("lines", ()):
        print(f"  {line}")


@dataclasses.dataclass(frozen=True)
class Relations:
    """Learn AML relations g_1..g_K on a source's on-manifold rows (paper §3, Alg. 1) and write
    a run directory (config, metrics, checkpoint, summary, figures). Re-running with the same out
    directory and options resumes. Defaults: the paper's loss and transversality, with jaml's
    pre-mining, refinement and stopping rules (docs/relations.md lists each deviation)."""

    source: str
    """a preset (ellipse, circle, block45, block36-drag, block-drag-range, geom-on-incline,
    mesh-on-incline) or the path of a .npy file of [N, D] rows or a .csv file of N lines of D
    numbers, optionally after a header line of column names (they name the relations' inputs)"""
    out: Path
    """run directory"""
    source_opt: KeyValues = ()
    """source option or override (repeatable; presets only), e.g. for geom-on-incline /
    mesh-on-incline pool_size=65536, action_range=[0,0], friction_range=[0,0] (any field of the
    env's config); for the block presets a BlockOnIncline field, e.g. friction=0.1"""
    no_progress: bool = False
    """no progress bars (none either where stderr is not a terminal)"""
    config: Annotated[Config, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=Config)

    def run(self) -> int:
        from jaml.relations.run import run

        summary = run(self.source, self.config, self.out,
                      source_options=key_values(self.source_opt) or None,
                      progress=_bars(self.no_progress))
        _print_summary(self.out, summary)
        return 0


@dataclasses.dataclass(frozen=True)
class Suite:
    """The evaluation suite's learning loop (paper §2.1): PPO (or a random policy) acts in
    NUM_ENVS MJX envs; their 64×64 frames fill a replay that keeps its initial half; a learner
    trains on replay sequences and is analysed every EVAL_EVERY epochs by the alignment of its
    latents with the true state on π_rand and π_curr. Writes a run directory; re-running with the
    same out directory and options resumes from the last checkpoint. Defaults per env follow the
    reference suite (`jaml.stream.for_env`): `jaml suite --env ENV --learner LEARNER --help`
    shows them, with the env's and the learner's own options (env-config, learner-config)."""

    env: Literal[ALL_ENVS]
    """the MJX domain (`jaml envs list`)"""
    learner: Literal[ALL_LEARNERS]
    """the learner (jaml.learners), or your own as MODULE:FACTORY (docs/own_learner.md)"""
    out: Path
    """run directory"""
    call: Annotated[CallOptions, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=CallOptions)
    no_progress: bool = False
    """no progress bar (none either where stderr is not a terminal)"""
    scale: Literal["paper", "small", "smoke"] = "paper"
    """sizes: "paper" (the reference's, for a GPU), "small" (16 envs, 8 epochs, 1,024-sequence
    analysis sets: minutes on a CPU, the smallest whose numbers rank encoders) or "smoke"
    (8 envs, 4 epochs: plumbing only, its numbers do not rank encoders); `jaml.suite.SCALES`;
    flags given beside it win, checked over its sizes (`--help` beside it shows them)"""
    config: Annotated[StreamConfig, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=StreamConfig)

    def stream_config(self):
        """The run's StreamConfig: `for_env`'s settings at the scale, then what the flags
        changed from the defaults they were parsed over (typed learner/env configs included)."""
        default = _default(type(self), "config")
        changes = changed_fields(self.config, default, skip=_SUITE_FIXED)
        for name in ("learner_config", "env_config"):  # typed flags (`_suite_for`)
            if hasattr(self, name):
                changes |= {f"{name}.{k}": v for k, v in changed_fields(
                    getattr(self, name), _default(type(self), name)).items()}
        return scaled(for_env(self.env, self.learner), self.scale).with_overrides(changes)

    def run(self) -> int:
        import jax

        from jaml.stream.run import run

        config = self.stream_config()
        bars = _bars(self.no_progress)
        if bars and self.scale == "paper" and jax.default_backend() == "cpu":
            # Beside the bar, which would sit at 0 for minutes (errors stay one line).
            print("jaml suite: the paper's scale on a CPU takes hours a run; --scale small "
                  "takes minutes", file=sys.stderr, flush=True)
        summary = run(config, self.out, progress=bars, **self.call.run_options())
        resumed = ("" if summary.get("resumed_from") is None
                   else f", resumed from epoch {summary['resumed_from']}")
        print(f"{config.env} {config.learner} ({config.policy}): {summary['status']} at epoch "
              f"{summary['epoch']}{resumed}, checkpoint {summary['checkpoint_epoch']} -> "
              f"{self.out}")
        _print_errors(summary)
        return 0


def _print_errors(summary: dict) -> None:
    """The last analysis's errors per test set, each under its reference rows (the constant
    predictor, the ceiling; the true state, the floor; raw pixels' PCA and random projection),
    and at the smoke scale the note that its numbers do not rank encoders."""
    refs = summary.get("references") or {}
    final = summary["final"]
    rows = [(r["test_set"], r["errors"]) for r in final]
    if final and final[0].get("validation"):  # the held-out replay rows, the same for each
        rows.append((f"validation ({final[0].get('validation_split') or 'leading'} split)",
                     final[0]["validation"]))
    def show(indent: str, head: str, names, values) -> None:  # wrapped: Ant has 28 names
        print(textwrap.fill(" ".join(f"{k}={v:.3f}" for k, v in zip(names, values,
                                                                      strict=False)),
                            width=100, initial_indent=f"{indent}{head}: ",
                            subsequent_indent=indent + "    ", break_long_words=False))

    for label, errors in rows:
        show("  ", label, errors, errors.values())
        for ref in ("constant", "true_state", "pca", "random_projection"):
            values = (refs.get(ref) or {}).get(label.split(" ")[0])
            if values is not None:
                show("    ", f"{ref} (epoch {refs['epoch']})", errors, values)
    if summary.get("note"):
        print(f"  note: {summary['note']}")


def _default(cls: type, name: str):
    """The default of dataclass `cls`'s field `name`."""
    field = next(f for f in dataclasses.fields(cls) if f.name == name)
    return field.default_factory() if field.default is dataclasses.MISSING else field.default


def _suite_for(argv: list[str]) -> type:
    """Suite, or when argv names a valid --env and --learner (a registry's, or your own as
    MODULE:FACTORY), a Suite whose defaults are that pair's (`for_env`) at the --scale given,
    so that flags are checked over them, with the env's config (and a registry learner's) as
    typed flags."""

    env, learner = _flag(argv, "--env"), _flag(argv, "--learner")
    own = learner is not None and ":" in learner  # MODULE:FACTORY: any name
    fields: list[tuple] = [("learner", str)] if own else []
    if env not in ALL_ENVS or not (own or learner in ALL_LEARNERS):
        return Suite if not fields else dataclasses.make_dataclass(
            "Suite", fields, bases=(Suite,), frozen=True,
            namespace={"__doc__": Suite.__doc__, "__module__": __name__})
    scale = _flag(argv, "--scale")
    base = for_env(env, learner)
    if scale in SCALES:
        base = scaled(base, scale)
    # The typed configs with their concrete types, so that their fields are flags; the
    # learner's ld_dim comes from the env when the stream builds the learner, and your own
    # learner's config from its factory.
    typed = [("env_config", base.env_config)] + (
        [] if own else [("learner_config", base.learner_config)])
    fields += [("config", Annotated[StreamConfig, tyro.conf.arg(name="")],
                dataclasses.field(default=base))]
    fields += [(name, type(value), dataclasses.field(default=value)) for name, value in typed]
    return dataclasses.make_dataclass(
        "Suite", fields, bases=(Suite,), frozen=True,
        namespace={"__doc__": Suite.__doc__, "__module__": __name__})


@dataclasses.dataclass(frozen=True)
class Demo:
    """The quick tour: learn two relations with transversality on the ellipse and on the 45°
    block-on-incline, writing run directories and figures."""

    out: Path = Path("runs/demo")
    """parent run directory"""
    no_progress: bool = False
    """no progress bars (none either where stderr is not a terminal)"""

    def run(self) -> int:
        from jaml.relations.run import run

        for source in ("ellipse", "block45"):
            print(f"== AML with transversality on {source} (2 relations) ==", flush=True)
            summary = run(source, Config(max_relations=2), self.out / source,
                          progress=_bars(self.no_progress))
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

    env: Literal[ALL_ENVS]
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
        options = ({} if env_config is None
                   else changed_fields(env_config, default_config(self.env)))
        path = show(self.env, out, resets=self.resets, steps=self.steps, seed=self.seed,
                    **options)
        shown = "".join(f", {k}={v}" for k, v in options.items())
        print(f"{self.env}{shown}: {self.resets} resets x {self.steps} frames -> {path}")
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
    if env not in ALL_ENVS:
        return Envs
    env_config = default_config(env)
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
        from jaml.stream.loop import cuda_graphs_wanted, on_cuda

        graphs = "on" if cuda_graphs_wanted() else "off"
        print(f"CUDA graphs of the stream's loops: {graphs if on_cuda() else 'no CUDA GPU'} "
              "(JAML_CUDA_GRAPHS)")
        print("malloc: " + _huge_pages.describe(os.environ, platform.libc_ver(),
                                                _huge_pages.thp_mode()))
        return 0


def _commands(argv: list[str]) -> dict[str, type]:
    return {"relations": Relations, "suite": _suite_for(argv), "fig2": fig2.Args,
            "fig3": fig3.Args, "fig9": fig9.Args, "demo": Demo, "envs": _envs_for(argv),
            "info": Info}


def parse(argv: list[str]):
    """The parsed `jaml` dataclass (`_command.parse` over every command)."""
    return _command.parse(argv, _commands, DESCRIPTION)


def main(argv=None) -> int:
    return _command.main(argv, _commands, DESCRIPTION)


if __name__ == "__main__":
    sys.exit(main())
