"""What the figure drivers share: the command's skeleton (train, then report), training one
cell's seeds together, reading run histories, and table cells (their intervals:
`jaml.evaluation.intervals`)."""

from __future__ import annotations

import dataclasses
import gzip
import json
import sys
import time
from pathlib import Path

from jaml import _command
from jaml.configs.records import RESOLVED, settings
from jaml.configs.stream import SCALES, StreamConfig

# jaml.evaluation (JAX, SciPy, Matplotlib) is imported by `cell`: the figure commands' --help
# imports none of them (tests/test_launch.py).

# When the command started (this module is imported as its flags are parsed): the origin of
# --time-limit.
_STARTED = time.monotonic()


@dataclasses.dataclass(frozen=True)
class Driver:
    """A figure's command: `train()` (skipped with --report-only), then `report()` printed.
    Subclasses are the drivers' `Args` dataclasses; their fields become the command's flags."""

    def train(self) -> bool | None:
        """Trains (or resumes) the figure's runs; False ends the command without a report."""
        raise NotImplementedError

    def report(self) -> str:
        """Writes the figure's markdown and images from the runs found; returns the markdown."""
        raise NotImplementedError

    def run(self) -> int:
        if not getattr(self, "report_only", False):
            started = time.perf_counter()
            if self.train() is False:
                return 0
            print(f"training: {time.perf_counter() - started:.0f}s in this call", flush=True)
        print(self.report())
        return 0


def _size(path: str):
    """A `Sizes` field: the `StreamConfig` default at `path` ("eval.train"), the path kept as
    the field's override (`Sizes.overrides`)."""
    value = StreamConfig()
    for part in path.split("."):
        value = getattr(value, part)
    return dataclasses.field(default=value, metadata={"path": path})


@dataclasses.dataclass(frozen=True)
class Sizes:
    """A figure's per-epoch and analysis sizes, as its command's flags (`sizes:
    Annotated[Sizes, tyro.conf.arg(name="")]`: --num-envs, …; the reports show them by these
    names too); defaults are `StreamConfig`'s, the paper's and the reference's."""

    num_envs: int = _size("num_envs")
    """envs stepped in parallel (the paper's 64)"""
    replay_slots: int | None = _size("replay.slots")
    """replay columns; None: the reference's 5000, rounded down to a multiple of num_envs"""
    eval_train: int = _size("eval.train")
    """sequences in the alignment regressor's training set"""
    eval_rand: int = _size("eval.rand")
    """sequences in the π_rand test set"""
    eval_curr: int = _size("eval.curr")
    """sequences in the π_curr test set"""
    regressor_iterations: int = _size("eval.regressor_iterations")
    """alignment regressor steps"""

    def overrides(self) -> dict:
        """These sizes as `StreamConfig.with_overrides` paths ("eval.train", …)."""
        return {f.metadata["path"]: getattr(self, f.name) for f in dataclasses.fields(self)}

    def under(self, scale: str) -> dict:
        """`overrides()` at the paper's scale; none at another: that scale's own sizes replace
        these (`scaled`), so they are not checked against sizes no run has. A flag set to other
        than its default is named on stderr as replaced."""
        if scale == "paper":
            return self.overrides()
        given = [f"--{f.name.replace('_', '-')} {getattr(self, f.name)}"
                 for f in dataclasses.fields(self) if getattr(self, f.name) != f.default]
        if given:
            print(f"--scale {scale} replaces {', '.join(given)}: the scale's sizes are used",
                  file=sys.stderr, flush=True)
        return {}


SIZES = tuple(f.name for f in dataclasses.fields(Sizes))  # their names in `settings`


def scale_of(settings: dict) -> str | None:
    """The `SCALES` entry whose sizes a cell's flat `settings` (`cell_config`) has, else None."""
    for name, sizes in SCALES.items():
        if sizes and all(settings.get(f.name) == sizes[f.metadata["path"]]
                         for f in dataclasses.fields(Sizes)):
            return name
    return None


def options(part: str, fields: dict) -> dict:
    """`fields` of the tree's `part` ("learner_config", "env_config") as override paths."""
    return {f"{part}.{k}": v for k, v in fields.items()}


@dataclasses.dataclass(frozen=True)
class CallOptions:
    """How one call trains its runs: the flags shared by the commands that train (`jaml suite`,
    fig2, fig3), given to `stream.run.run` / `train_seeds` as they are (`dataclasses.asdict`).
    A command holds them as `call: Annotated[CallOptions, tyro.conf.arg(name="")]`: the flags
    keep their names (--stop-after, …); the help lists them after the command's own."""

    stop_after: int | None = None
    """epochs per run in this call (a session's share; the stop writes a checkpoint); the next
    call resumes"""
    checkpoint_every: int | None = None
    """epochs between checkpoints (default: one with every analysis); the last analysis and a
    --stop-after stop always checkpoint. A checkpoint holds each run's replay (2–4 GB): thin
    them on a machine whose disk does not outlive the call"""
    final_checkpoint: bool = True
    """checkpoint each run at its last analysis (--no-final-checkpoint: only where
    --checkpoint-every says so; for a machine whose disk goes with the runs, one checkpoint
    write per run saved)"""
    keep_pi_rand: bool = True
    """keep each run's π_rand test sequences on the host after its first analysis in this call
    and encode them again at the later ones (≈ 2 GB per run at 16 frames per sequence; the
    records are the same); --no-keep-pi-rand rolls them out at every analysis"""
    time_limit: float | None = None
    """seconds this command may train, from its start: no block of epochs starts that would end
    later (at the pace so far); the runs then checkpoint and stop, and the next call resumes.
    Leave a margin for those checkpoints"""

    def __post_init__(self):
        if self.time_limit is not None and self.time_limit <= 0:
            raise ValueError(f"--time-limit must be a positive number of seconds, got "
                             f"{self.time_limit}")

    def run_options(self) -> dict:
        """The keyword arguments of `stream.run.run` / `train_seeds`: these fields, the time
        limit as a `time.monotonic()` deadline."""
        options = dataclasses.asdict(self)
        limit = options.pop("time_limit")
        return options | {"deadline": None if limit is None else _STARTED + limit}


def main(command: str, args: type, argv=None) -> int:
    """`python -m jaml.experiments.COMMAND ARGS` is `jaml COMMAND ARGS`: `args` (the driver's
    `Args`) parsed and run by the command line's mechanism (`jaml._command`), the only command."""
    return _command.main([command, *(sys.argv[1:] if argv is None else argv)],
                         lambda _: {command: args}, command)


def train_seeds(label: str, configs, dirs, *, stop_after: int | None = None,
                checkpoint_every: int | None = None, final_checkpoint: bool = True,
                keep_pi_rand: bool = True, deadline: float | None = None) -> list[dict]:
    """Every seed of one cell trained together (`run_many`: one program, the seeds stacked),
    each in its resumable directory; prints one line per seed (status, seconds by phase) and
    one for the cell. Returns the runs' summaries. The cell's programs go with its Stream when
    `run_many` returns: a driver's next cell shares none of them."""
    from jaml.stream.run import run_many

    started = time.perf_counter()
    summaries = run_many(list(configs), list(dirs), progress=False, stop_after=stop_after,
                         checkpoint_every=checkpoint_every, final_checkpoint=final_checkpoint,
                         keep_pi_rand=keep_pi_rand, deadline=deadline)
    for config, summary in zip(configs, summaries, strict=True):
        if summary is None:  # a run another process trains (`run_many`)
            continue
        phases = ", ".join(f"{k} {v:.0f}s" for k, v in summary["seconds_by_phase"].items())
        print(f"{label} seed {config.seed}: {summary['status']} at epoch {summary['epoch']} "
              f"({phases})", flush=True)
    statuses = "/".join(sorted({s["status"] for s in summaries if s is not None}))
    print(f"{label}: {len(summaries)} seeds {statuses} in {time.perf_counter() - started:.0f}s",
          flush=True)
    return summaries


def read_jsonl(path: Path) -> list[dict]:
    """The records of a run's JSON-lines file (history.jsonl, metrics.jsonl), read from its
    gzip copy `path.gz` where a committed record keeps it so; [] when it has none yet. A last
    line without its newline is a record still being appended by the process training the run
    (a report written beside it, see fig2's "Several GPUs") and is left for the next read."""
    packed = path.with_name(path.name + ".gz")
    if path.exists():
        text = path.read_text()
    else:
        text = gzip.decompress(packed.read_bytes()).decode() if packed.exists() else ""
    complete = text[:text.rfind("\n") + 1]
    return [json.loads(x) for x in complete.splitlines() if x.strip()]


def stopped_runs(directory: Path) -> dict[str, str]:
    """seed_N → the error of each run under `directory` that a non-finite learner loss stopped
    (its summary.json says "nonfinite"; `stream.run.run_many` stops such a run alone)."""
    stopped = {}
    for d in sorted(directory.glob("seed_*")):
        path = d / "summary.json"
        summary = json.loads(path.read_text()) if path.exists() else {}
        if summary.get("status") == "nonfinite":
            stopped[d.name] = summary.get("error", "learner loss became non-finite")
    return stopped


def seed_histories(directory: Path) -> list[list[dict]]:
    """The histories of the seed_N runs under `directory` that have analysed at least once,
    in seed-directory order. Runs stopped by a non-finite loss (`stopped_runs`) are left out:
    their last analysis would hold every table at the epoch they stopped before, and a report
    names them instead."""
    stopped = stopped_runs(directory)
    histories = (read_jsonl(d / "history.jsonl") for d in sorted(directory.glob("seed_*"))
                 if d.name not in stopped)
    return [h for h in histories if h]


def cell_config(directory: Path) -> dict:
    """The settings every seed_N run under `directory` shares, flat (`settings`): its config.json
    without the seed (and without the learner's and env's resolved configs where a seed's older
    record lacks them).
    Seeds that disagree (say one call trained in bfloat16, another in float32) are not one cell:
    pooling them would mix two experiments, so this raises, naming the runs and the settings."""
    configs = [(d.name, json.loads((d / "config.json").read_text()))
               for d in sorted(directory.glob("seed_*")) if (d / "config.json").exists()]
    if not configs:
        raise FileNotFoundError(f"no seed_*/config.json under {directory}")
    if not all(RESOLVED in c for _, c in configs):  # some older record holds no resolved configs
        configs = [(n, {k: v for k, v in c.items() if k != RESOLVED}) for n, c in configs]
    (first, shared), *others = [(n, {k: v for k, v in c.items() if k != "seed"})
                                for n, c in configs]
    for name, config in others:
        if config != shared:
            keys = sorted(k for k in shared.keys() | config.keys()
                          if shared.get(k) != config.get(k))
            raise ValueError(f"{directory}: {first} and {name} differ in {', '.join(keys)}; "
                             "one cell's seeds must share their settings (move one set apart)")
    return settings(shared)


def last_common_step(histories: list[list[dict]]) -> int:
    """The last analysis step every run reached."""
    return min(max(r["step"] for r in h) for h in histories)


def true_state_errors(cell_dir: Path, names: list[str]) -> dict[str, list[dict]]:
    """test set → one {name: error} per seed_N run under `cell_dir` whose summary.json holds the
    regressor's errors with the true state as the latent (the floor: "references", from its
    last call's first analysis); runs from before the analysis computed them hold none."""
    out = {}
    for path in sorted(Path(cell_dir).glob("seed_*/summary.json")):
        true_state = (json.loads(path.read_text()).get("references") or {}).get("true_state")
        for test_set, errors in (true_state or {}).items():
            out.setdefault(test_set, []).append(dict(zip(names, errors, strict=True)))
    return out


def cell(values, digits: int = 3) -> str:
    """'0.123' for one run, '0.123 ± 0.045' (90 % confidence half-width) for several."""
    from jaml.evaluation import intervals

    mean, low, high = intervals.mean_interval(values)
    if len(values) < 2:
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} ± {(high - low) / 2:.{digits}f}"
