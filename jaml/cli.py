"""The `jaml` command line: `jaml relations …`, `jaml suite …`, `jaml demo`, `jaml envs list|show`,
`jaml info`. Entry points stay thin."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import logging
import sys
import types
import typing
from pathlib import Path


def _field_type(field: dataclasses.Field):
    """argparse type for a Config field: the non-None member of `T | None` parses 'none'."""
    hint = typing.get_type_hints(_relations_config())[field.name]
    args = typing.get_args(hint)
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        inner = next(a for a in args if a is not type(None))
        return lambda text: None if text.lower() == "none" else inner(text)
    return hint


def _relations_config():
    from jaml.relations.config import Config

    return Config


def _add_config_options(parser: argparse.ArgumentParser) -> None:
    """One --option per relations.Config field, generated from the dataclass (no repetition)."""
    group = parser.add_argument_group("relations.Config fields (defaults follow the paper)")
    doc = _relations_config().__doc__ or ""
    for field in dataclasses.fields(_relations_config()):
        flag = "--" + field.name.replace("_", "-")
        described = next(
            (
                line.split(":", 1)[1].strip()
                for line in doc.splitlines()
                if line.strip().startswith(field.name + ":")
            ),
            "",
        )
        group.add_argument(
            flag,
            dest=field.name,
            type=_field_type(field),
            default=None,
            help=f"{described} (default: {field.default})".replace("%", "%%"),
        )


def _config_from(args):
    values = {
        f.name: getattr(args, f.name)
        for f in dataclasses.fields(_relations_config())
        if getattr(args, f.name) is not None
    }
    return _relations_config()(**values)


def _cmd_relations(args) -> int:
    from jaml.relations.run import run

    # JSON lists become tuples: config ranges are (lo, hi) tuples.
    options = {k: tuple(v) if isinstance(v, list) else v for k, v in (args.source_opt or [])}
    summary = run(
        args.source,
        _config_from(args),
        args.out,
        source_options=options or None,
        progress=not args.no_progress,
    )
    _print_summary(args.out, summary)
    return 0


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


def _cmd_demo(args) -> int:
    from jaml.relations.config import Config
    from jaml.relations.run import run

    out = Path(args.out)
    for source in ("ellipse", "block45"):
        print(f"== AML with transversality on {source} (2 relations) ==", flush=True)
        summary = run(source, Config(max_relations=2), out / source, progress=not args.no_progress)
        _print_summary(out / source, summary)
    print(f"figures: {sorted(str(p) for p in out.rglob('*.png'))}")
    return 0


_SUITE_FIELDS = ("seed", "num_envs", "rollout_len", "replay_slots", "replay_keep_fraction",
                 "learner_steps", "frames_per_batch", "epochs", "eval_every", "eval_train",
                 "eval_rand", "eval_curr", "eval_transient", "regressor_iterations")


def key_value(text: str) -> tuple[str, object]:
    """KEY=VALUE with VALUE read as JSON where it parses (numbers, true, lists), else a string."""
    import json

    if "=" not in text:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    key, value = text.split("=", 1)
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


def _field_docs(doc: str) -> dict[str, str]:
    """`name: text` entries of a docstring, continuation lines (indented deeper) joined."""
    docs, current, indent = {}, None, None
    for line in doc.splitlines():
        stripped = line.strip()
        depth = len(line) - len(stripped)
        head = stripped.split(":", 1)[0]
        if ":" in stripped and head.isidentifier() and (indent is None or depth <= indent):
            current, indent = head, depth
            docs[current] = stripped.split(":", 1)[1].strip()
        elif current and stripped and depth > indent:
            docs[current] += " " + stripped
        else:
            current = None
    return docs


def _cmd_suite(args) -> int:
    from jaml.stream import for_env
    from jaml.stream.run import run

    overrides = {f: getattr(args, f) for f in _SUITE_FIELDS if getattr(args, f) is not None}
    learner_overrides = dict(args.learner_opt or [])
    config = for_env(args.env, args.learner, policy=args.policy,
                     learner_overrides=learner_overrides,
                     env_overrides=dict(args.env_opt or []), **overrides)
    summary = run(config, args.out, progress=not args.no_progress, stop_after=args.stop_after)
    print(f"{args.env} {args.learner} ({args.policy}): {summary['status']} at epoch "
          f"{summary['epoch']}, checkpoint {summary['checkpoint_epoch']} -> {args.out}")
    for r in summary["final"]:
        errs = " ".join(f"{k}={v:.3f}" for k, v in r["errors"].items())
        print(f"  {r['test_set']}: {errs}")
    return 0


def _add_suite_parser(sub) -> None:
    import envs_mjx
    from jaml import learners
    from jaml.stream import POLICIES, StreamConfig

    suite = sub.add_parser(
        "suite",
        help="the evaluation suite's learning loop (paper §2.1): PPO frames → replay → learner",
        description="PPO (or a random policy) acts in NUM_ENVS MJX envs; their 64×64 frames fill "
        "a replay that keeps its initial half; a learner trains on replay sequences and is "
        "analysed every EVAL_EVERY epochs by the alignment of its latents with the true state "
        "on π_rand and π_curr. Writes a run directory; re-running with the same --out and "
        "options resumes from the last checkpoint. Defaults per env follow the reference suite.",
    )
    suite.add_argument("--env", required=True, choices=envs_mjx.ALL_ENVS)
    suite.add_argument("--learner", required=True, choices=learners.ALL_LEARNERS)
    suite.add_argument("--policy", default="ppo", choices=POLICIES)
    suite.add_argument("--out", required=True, type=Path, help="run directory")
    docs = _field_docs(StreamConfig.__doc__ or "")
    hints = typing.get_type_hints(StreamConfig)
    for name in _SUITE_FIELDS:
        described = docs.get(name, "")
        kind = float if "float" in str(hints[name]) else int
        suite.add_argument("--" + name.replace("_", "-"), dest=name, type=kind, default=None,
                           help=described.replace("%", "%%"))
    suite.add_argument("--learner-opt", type=key_value, action="append", metavar="KEY=VALUE",
                       help="learner config field, e.g. beta=20 or hist=16 (repeatable)")
    suite.add_argument("--env-opt", type=key_value, action="append", metavar="KEY=VALUE",
                       help="env config field, e.g. multicolor=false (repeatable)")
    suite.add_argument("--stop-after", type=int, default=None,
                       help="stop after this many epochs in this call; the next call resumes "
                       "from the last checkpoint (written with each analysis), redoing the "
                       "epochs after it")
    suite.add_argument("--no-progress", action="store_true", help="no progress bar")
    suite.set_defaults(func=_cmd_suite)


def _cmd_envs_list(args) -> int:
    from envs_mjx.show import format_list, list_envs

    print(format_list(list_envs()))
    return 0


def _cmd_envs_show(args) -> int:
    from envs_mjx.show import show

    out = args.out or Path(f"{args.name}.png")
    path = show(args.name, out, resets=args.resets, steps=args.steps, seed=args.seed)
    print(f"{args.name}: {args.resets} resets x {args.steps} frames -> {path}")
    return 0


_INFO_PACKAGES = ("jax", "jaxlib", "flax", "optax", "orbax-checkpoint", "brax", "mujoco",
                  "mujoco-mjx")


def _cmd_info(args) -> int:
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
    for label, module in (("MJX physics", "mujoco.mjx"), ("MJX renderer", "envs_mjx.render")):
        try:
            importlib.import_module(module)
            print(f"{label} ({module}): import ok")
        except Exception as error:  # report any failure, this is a diagnostic
            print(f"{label} ({module}): import FAILED: {type(error).__name__}: {error}")
    with contextlib.suppress(Exception):
        from mujoco.mjx import warp

        print(f"MuJoCo Warp (optional, unused by jaml): "
              f"{'installed' if warp.WARP_INSTALLED else 'not installed'}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from jaml.sources import PRESETS

    parser = argparse.ArgumentParser(prog="jaml", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="log at INFO level")
    sub = parser.add_subparsers(dest="command", required=True)

    rel = sub.add_parser(
        "relations",
        help="learn AML relations on a source (paper §3, Alg. 1)",
        description="Learn relations g_1..g_K on a source's on-manifold data and "
        "write a run directory (config, metrics, checkpoint, summary, figures). "
        "Re-running with the same --out and options resumes.",
    )
    rel.add_argument("--source", required=True, choices=sorted(PRESETS), help="data source")
    rel.add_argument(
        "--source-opt",
        type=key_value,
        action="append",
        metavar="KEY=VALUE",
        help="source option or override (repeatable), e.g. for geom-on-incline / "
        "mesh-on-incline pool_size=65536, action_range=[0,0], friction_range=[0,0] (any field "
        "of the env's config); for the block presets a BlockOnIncline field, e.g. friction=0.1",
    )
    rel.add_argument("--out", required=True, type=Path, help="run directory")
    rel.add_argument("--no-progress", action="store_true", help="no progress bars")
    _add_config_options(rel)
    rel.set_defaults(func=_cmd_relations)

    _add_suite_parser(sub)

    demo = sub.add_parser(
        "demo",
        help="the quick tour: relations on the analytic and block domains",
        description="Learn two relations with transversality on the ellipse "
        "and on the 45° block-on-incline, writing run directories and figures.",
    )
    demo.add_argument("--out", type=Path, default=Path("runs/demo"), help="parent run directory")
    demo.add_argument("--no-progress", action="store_true", help="no progress bars")
    demo.set_defaults(func=_cmd_demo)

    envs = sub.add_parser("envs", help="the MJX domains (envs_mjx): list them, look at them")
    envs_sub = envs.add_subparsers(dest="envs_command", required=True)
    envs_sub.add_parser(
        "list", help="each env with its action size and LD state (size and names)"
    ).set_defaults(func=_cmd_envs_list)
    show = envs_sub.add_parser(
        "show",
        help="PNG grid of rendered frames from random-action rollouts",
        description="Rows are resets (so per-episode colours show), columns are time; "
        "frames come from the env's own pixels path (envs_mjx.render).",
    )
    show.add_argument("name", help="env name (see `jaml envs list`)")
    show.add_argument("--out", type=Path, default=None, help="PNG path (default: NAME.png)")
    show.add_argument("--resets", type=int, default=4, help="rows: independent resets")
    show.add_argument("--steps", type=int, default=8, help="columns: frames per reset")
    show.add_argument("--seed", type=int, default=0, help="PRNG seed")
    show.set_defaults(func=_cmd_envs_show)

    sub.add_parser(
        "info",
        help="JAX version, backend and devices; package versions; whether MJX imports",
    ).set_defaults(func=_cmd_info)
    return parser


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


def main(argv=None) -> int:
    captured = _import_mjx_quietly()
    args = build_parser().parse_args(argv)
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
    try:
        return args.func(args)
    except (ValueError, TypeError, FileNotFoundError) as error:
        print(f"jaml: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
