"""A `jaml suite` run directory: the learning loop with logs, figures and resumable checkpoints.

The directory's files and the resume rules are listed in docs/stream.md, "Run directory".
"""

from __future__ import annotations

import json
import logging
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from jaml._rundir import RunLog, claim, lock, truncate_jsonl, write_json
from jaml.evaluation import plots
from jaml.stream import analysis, checkpoint
from jaml.stream.config import RESOLVED, StreamConfig
from jaml.stream.executor import (
    BLOCK,
    build,
    due_by_device,
    run_stacked_epochs,
    stack_runs,
    unstack_runs,
)
from jaml.stream.loop import Stream, StreamState
from jaml.stream.timing import Stopwatch, timed

log = logging.getLogger("jaml.stream")
# What a run resumed from: the command line shows this logger at INFO (`jaml.cli.main`).
resume_log = logging.getLogger("jaml.resume")


class NonFiniteLoss(RuntimeError):
    """The learner's loss became NaN/inf; the run stopped at its last good checkpoint."""


def claim_run(out: Path, config: StreamConfig, stream: Stream | None = None) -> bool:
    """`_rundir.claim` for a stream run: config.json holds the resolved config and, given the
    run's `stream`, its learner's and env's configs whole (`StreamConfig.record`). A recorded
    run is this one when its config resolves to this one (older runs left derived fields to
    defaults) and its learner and env configs agree on every field both records have (older
    runs recorded none; a field new in the code is missing from older records)."""
    parts = () if stream is None else (getattr(stream.learner, "config", None), stream.env.config)
    record = config.record(*parts)
    resolved = config.resolved().to_dict()

    def same(recorded: dict) -> bool:
        before, now = recorded.get(RESOLVED, {}), record.get(RESOLVED, {})
        return (StreamConfig.from_dict(recorded).resolved().to_dict() == resolved
                and all(before[part].get(k, v) == v for part in before.keys() & now.keys()
                        for k, v in now[part].items()))

    return claim(out, record, same)


def analysis_epochs(config: StreamConfig) -> list[int]:
    """Epochs after which the run analyses and checkpoints: when the replay is full (the learner
    has just started), every `eval_every` epochs after that, and at the end."""
    first = config.fill_epochs
    epochs = list(range(first, config.epochs + 1, config.eval_every))
    if not epochs or epochs[-1] != config.epochs:
        epochs.append(config.epochs)
    return epochs


def _save_png(path: Path, rows: list[np.ndarray]) -> None:
    """Rows of uint8 [N, H, W, 3] images, tiled N across, with a 2-pixel gap."""
    from matplotlib.image import imsave

    tiles = [np.concatenate([np.pad(im, ((2, 2), (2, 2), (0, 0)), constant_values=255)
                             for im in row], axis=1) for row in rows]
    imsave(path, np.concatenate(tiles, axis=0))


class _Logs(RunLog):
    """metrics.jsonl (one line per epoch) + TensorBoard scalars, alignment errors included."""

    def epochs(self, first_epoch: int, metrics: dict[str, np.ndarray]) -> None:
        n = len(next(iter(metrics.values())))
        for i in range(n):
            epoch = first_epoch + i + 1  # epochs completed, like an analysis's step
            row = {k: float(v[i]) for k, v in metrics.items()}
            self.record({"epoch": epoch, **row})
            self.scalars(row, epoch)
        self.flush()

    def analysis(self, epoch: int, records: list[dict]) -> None:
        for r in records:
            self.scalars(r["errors"], epoch, prefix=f"alignment/{r['test_set']}/")
        if records and records[0].get("distortion") is not None:
            self.scalars({"alignment/distortion": records[0]["distortion"]}, epoch)
        self.flush()


class _FigureWriter:
    """Draws the runs' figures (alignment.png, distortion.png) on one background thread, so the
    loop's next epochs run while matplotlib draws (drawn in line, they held up every analysis
    of every run; docs/notes/stream.md). A run's figures are drawn from its newest history
    only: a request still queued when a newer one for the same run arrives is skipped. `wait`
    drains the queue; `check` raises the first drawing error."""

    def __init__(self):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaml-figures")
        self._newest: dict[Path, object] = {}
        self._futures: list[Future] = []

    def submit(self, out: Path, history: list[dict]) -> None:
        token = self._newest[out] = object()

        def draw():
            if self._newest.get(out) is token:
                _figures(history, out)

        self._futures.append(self._pool.submit(draw))

    def wait(self) -> None:
        self._pool.shutdown(wait=True)

    def check(self) -> None:
        for future in self._futures:
            future.result()


class _RunDir:
    """One run's directory: its config check, keys, state (restored or fresh), logs, analyses,
    checkpoints and summary. Its figures go to `figures`, drawn in the background."""

    def __init__(self, stream: Stream, config: StreamConfig, out: Path, figures: _FigureWriter,
                 final_checkpoint: bool = True, keep_pi_rand: bool = True):
        self.config, self.out, self.figures = config, out, figures
        self.final_checkpoint = final_checkpoint
        # The run's π_rand sequences, kept on the host after its first analysis in this call.
        self.pi_rand_set = analysis.PiRandSet() if keep_pi_rand else None
        self.lock = lock(out)  # released by `close` (or when the process ends)
        try:
            self._open(stream, config, out)
        except BaseException:  # a refused config or unreadable checkpoint: let the directory go
            self.lock.close()
            raise

    def _open(self, stream: Stream, config: StreamConfig, out: Path) -> None:
        claim_run(out, config, stream)
        (out / "recon").mkdir(exist_ok=True)
        k_init, self.k_eval, self.pi_rand_key = jax.random.split(jax.random.PRNGKey(config.seed), 3)
        self.manager = checkpoint.manager(out)
        self.resumed_from: int | None = None
        if self.manager.latest_step() is not None:
            self.state = checkpoint.restore(self.manager, jax.eval_shape(stream.init, k_init))
            self.resumed_from = int(self.state.epoch)
            resume_log.info("%s: resumed from its checkpoint at epoch %d of %d", out,
                            self.resumed_from, config.epochs)
        else:
            self.state = stream.init(k_init)
        self.epoch = int(self.state.epoch)
        self.history = truncate_jsonl(out / "history.jsonl", lambda r: r["step"] <= self.epoch)
        self.logs = _Logs(out, keep=lambda r: r["epoch"] <= self.epoch)
        self.status = "running"
        self.error: str | None = None  # why a "nonfinite" run stopped
        self.targets = [t for t in analysis_epochs(config) if t > self.epoch]
        self.started = time.perf_counter()
        # Wall seconds of this call by phase (first calls include compilation); the epochs of
        # runs trained together are shared among them.
        self.seconds = {"epochs": 0.0, "analysis": 0.0, "checkpoint": 0.0}
        # The analysis phase by part (`analysis.evaluate`'s, then this run's records and
        # reconstructions; figures are drawn in the background): where its time goes.
        self.analysis_parts: dict[str, float] = {}

    def eval_key(self) -> jax.Array:
        """The analysis key of the current epoch."""
        return jax.random.fold_in(self.k_eval, self.epoch)

    def analyse(self, stream: Stream, state: StreamState, report: dict, names: list[str],
                checkpoint_every: int | None = None) -> None:
        """Records, figures and (see `checkpoint_due`) an atomic checkpoint at the current
        epoch, from this run's `analysis.evaluate_runs` report and its error names (see
        `_analyse_together`)."""
        with timed(self.seconds, "analysis"), timed(self.analysis_parts, "records"):
            records = _records(stream, names, self.epoch, report, seed=self.config.seed)
            self.history += records
            with (self.out / "history.jsonl").open("a") as f:
                # One write per analysis, so a report read beside it (`_runs.read_history`
                # skips an unterminated line) almost never sees part of an epoch's records.
                f.write("".join(json.dumps(r) + "\n" for r in records))
            self.logs.analysis(self.epoch, records)
            self.figures.submit(self.out, list(self.history))
        if checkpoint_due(self.epoch, self.manager.latest_step(), checkpoint_every,
                          last=not self.targets and self.final_checkpoint):
            self.save(state)
        # A progress summary (status "running"): a process that dies without reaching `close`
        # (a machine taken back, SIGKILL) still leaves its epoch, phase times and last records.
        write_json(self.out / "summary.json", self.summary())

    def save(self, state: StreamState) -> None:
        """An atomic checkpoint of `state` at the current epoch."""
        with timed(self.seconds, "checkpoint"):
            checkpoint.save(self.manager, self.epoch, state)

    def summary(self) -> dict:
        """summary.json's record of this call so far."""
        last = max((h["step"] for h in self.history), default=-1)
        return {
            "status": self.status,
            "epoch": self.epoch,
            "seconds_this_call": time.perf_counter() - self.started,
            "seconds_by_phase": self.seconds,
            "seconds_in_analysis": self.analysis_parts,
            "checkpoint_epoch": self.manager.latest_step(),
            "resumed_from": self.resumed_from,
            "final": [r for r in self.history if r["step"] == last],
            **({"error": self.error} if self.error is not None else {}),
        }

    def close(self) -> dict:
        self.logs.close()
        self.manager.close()
        summary = self.summary()
        write_json(self.out / "summary.json", summary)
        self.lock.close()
        return summary


def run(config: StreamConfig, out, *, progress: bool = True, stop_after: int | None = None,
        checkpoint_every: int | None = None, final_checkpoint: bool = True,
        latent_penalty=None, keep_pi_rand: bool = True, deadline: float | None = None) -> dict:
    """Runs (or resumes) the loop in `out`; returns the summary. `stop_after` (epochs) and
    `deadline` (a `time.monotonic()` instant) end the process's work early, with a checkpoint
    (a deliberate interruption, for jobs with a time limit); the next call resumes. A
    non-finite loss raises `NonFiniteLoss`."""
    summary = run_many([config], [out], progress=progress, stop_after=stop_after,
                       checkpoint_every=checkpoint_every, final_checkpoint=final_checkpoint,
                       latent_penalty=latent_penalty, keep_pi_rand=keep_pi_rand,
                       deadline=deadline)[0]
    if summary["status"] == "nonfinite":
        raise NonFiniteLoss(summary["error"])
    return summary


def run_many(configs: list[StreamConfig], outs: list, *, progress: bool = True,
             stop_after: int | None = None, checkpoint_every: int | None = None,
             final_checkpoint: bool = True, latent_penalty=None, mesh=None,
             keep_pi_rand: bool = True, deadline: float | None = None) -> list[dict]:
    """Runs (or resumes) several runs of one program, each in its own directory, trained
    together: the configs may differ only in their seeds, and their states are stacked and
    advanced by one compiled loop (`run_stacked_epochs`; several devices split the runs, see
    `mesh`). Runs resumed at different epochs first advance in groups by epoch until they meet.
    Returns one summary per run; a run whose loss turns non-finite stops alone (status
    "nonfinite", its last good checkpoint kept) and the others go on.

    Checkpoints are written with the analyses; `checkpoint_every` (epochs) thins them to the
    first analysis at least that many epochs after the last checkpoint, plus each run's last
    analysis and where `stop_after` stops it. A checkpoint holds the replay (≈ 2 GB per
    pendulum run, 4 GB per locomotion run at 64×64), so on a machine that is not kept, whose
    disk goes with the runs, writing one at every analysis buys little and costs minutes.
    There, `final_checkpoint=False` also drops the forced one at the last analysis (the run's
    records and summary are written as always): the last analysis then checkpoints only where
    `checkpoint_every` says so.

    `keep_pi_rand`: each run keeps its π_rand test sequences on the host after its first
    analysis in this call (`analysis.PiRandSet`; ≈ 2 GB per run at the paper's eval_rand and 16
    frames per sequence), so later analyses encode them again instead of rolling them out
    again; the reports are the same. False rolls them out at every analysis.

    `deadline`: a `time.monotonic()` instant (a job's wall-clock limit). Epochs then run in
    blocks of at most `DEADLINE_BLOCK`, and a block that would end past the deadline (at the
    last block's pace, plus the last analysis's time if it ends at one, each without the time
    JAX spent compiling in it: a call's first block and first analysis compile their programs)
    is not started: every run still going checkpoints where it is and stops ("interrupted").
    Leave a margin for those checkpoints."""
    if len(configs) != len(outs) or not configs:
        raise ValueError(f"run_many needs one out directory per config, got {len(configs)} "
                         f"configs and {len(outs)} directories")
    if checkpoint_every is not None and checkpoint_every < 1:
        raise ValueError(f"checkpoint_every must be a positive number of epochs or None, got "
                         f"{checkpoint_every}")
    keys = {c.program_key() for c in configs}
    if len(keys) > 1:
        raise ValueError("runs trained together must differ only in their seeds; got "
                         f"{len(keys)} different configurations")
    outs = [Path(o) for o in outs]
    if len(set(outs)) < len(outs):
        raise ValueError(f"two runs share an out directory: {[str(o) for o in outs]}")
    stream = build(configs[0], latent_penalty)  # every config problem surfaces before any file
    figures = _FigureWriter()
    runs: list[_RunDir] = []
    try:
        for c, o in zip(configs, outs, strict=True):
            runs.append(_RunDir(stream, c, o, figures, final_checkpoint, keep_pi_rand))
    except BaseException:  # one directory refused: the ones opened before it are let go too
        for r in runs:
            r.lock.close()
        raise
    label = f"{configs[0].env} {configs[0].learner}" + (f" ×{len(runs)}" if len(runs) > 1 else "")
    bar = tqdm(total=configs[0].epochs * len(runs), initial=sum(r.epoch for r in runs),
               desc=label, unit="epoch", disable=not progress)
    budget = {id(r): stop_after for r in runs}
    # The runs being trained and their stacked states, kept stacked from one analysis to the
    # next while the group stays the same (the common case: all runs at one epoch).
    members: list[_RunDir] = []
    states = None
    pace = None  # seconds per epoch of the last block, and of the last analysis (deadline)
    analysis_seconds = 0.0
    try:
        while True:
            for r in runs:
                if r.status == "running" and not r.targets:
                    r.status = "finished"
                if r.status != "running":  # finished, stopped or non-finite: no more analyses
                    r.pi_rand_set = None  # its host memory, for the runs still going
            active = [r for r in runs if r.status == "running"]
            if not active:
                break
            epoch = min(r.epoch for r in active)
            group = [r for r in active if r.epoch == epoch]
            target = group[0].targets[0]
            n = target - epoch if stop_after is None else min(target - epoch, budget[id(group[0])])
            if n == 0:
                for r in group:
                    r.status = "interrupted"
                continue
            if deadline is not None:
                n = min(n, DEADLINE_BLOCK)
                ahead = 0.0 if pace is None else pace * n + (
                    analysis_seconds if epoch + n == target else 0.0)
                if _clock() + ahead > deadline:
                    _stop_in_time(active, members, states)
                    continue
            if group != members:
                if states is not None:
                    for r, state in zip(members, unstack_runs(states), strict=True):
                        r.state = state
                states = stack_runs([r.state for r in group])
                members = group
                for r in group:
                    r.state = None
            with Stopwatch() as block:
                states, metrics = run_stacked_epochs(stream, states, n, mesh=mesh)
                metrics = jax.tree.map(np.asarray, metrics)
            pace = block.steady / n
            share = block.wall / len(group)
            bar.update(n * len(group))
            due = []  # (index, run) of the runs at an analysis epoch, analysed together
            for i, r in enumerate(group):
                mine = {k: v[:, i] for k, v in metrics.items()}
                r.seconds["epochs"] += share
                if stop_after is not None:
                    budget[id(r)] -= n
                bad = _first_non_finite(mine)
                if bad is not None:  # this run stops; its stacked state is dropped at the next
                    # regroup. Its metrics up to the first bad epoch are logged, so the terms
                    # that went first can be read.
                    r.logs.epochs(r.epoch, {k: v[:bad + 1] for k, v in mine.items()})
                    r.status, r.error = "nonfinite", _non_finite_message(r.epoch + bad + 1)
                    log.error("%s: %s", r.out, r.error)
                    continue
                r.logs.epochs(r.epoch, mine)
                r.epoch += n
                if r.epoch == target:
                    r.targets.pop(0)
                    due.append((i, r))
            with Stopwatch() as analysing:
                _analyse_together(stream, states, due, checkpoint_every)
            if due:
                analysis_seconds = analysing.steady
            # A run stopped by `stop_after` between analyses keeps its epochs: checkpointed
            # here (no analysis), so the next call resumes where this one stopped.
            for i, r in enumerate(group):
                if (stop_after is not None and budget[id(r)] == 0 and r.status == "running"
                        and r.targets and r.manager.latest_step() != r.epoch):
                    r.save(jax.tree.map(lambda x, i=i: x[i], states))
            # Only what has a value: no episode ended yet reads "ret=nan", a learner that has
            # not started "loss=nan".
            shown = {"ret": _last_finite(metrics["episode_return"][:, 0]),
                     "loss": _last_finite(metrics["learner/loss"][:, 0])}
            bar.set_postfix({k: f"{v:.4g}" for k, v in shown.items() if np.isfinite(v)})
    except KeyboardInterrupt:
        for r in runs:
            r.status = "interrupted" if r.status == "running" else r.status
        raise
    except BaseException:
        for r in runs:
            r.status = "failed" if r.status == "running" else r.status
        raise
    finally:
        bar.close()
        figures.wait()
        summaries = []
        for r in runs:
            summaries.append(r.close())
    figures.check()  # a figure that failed to draw, after every summary is written
    return summaries


# Epochs between deadline checks: the device loop's block, so no block is split.
DEADLINE_BLOCK = BLOCK
_clock = time.monotonic  # what deadlines are read against


def _stop_in_time(active: list[_RunDir], members: list[_RunDir], states) -> None:
    """The deadline's stop: each active run checkpoints at its epoch (unless its last
    checkpoint is there) and is marked interrupted. `members` are the runs whose states are
    stacked in `states`; the others hold theirs in `run.state`."""
    for r in active:
        if r.targets and r.manager.latest_step() != r.epoch:
            if r in members:
                i = members.index(r)
                r.save(jax.tree.map(lambda x, i=i: x[i], states))
            else:
                r.save(r.state)
        r.status = "interrupted"


def checkpoint_due(epoch: int, last_checkpoint: int | None, every: int | None, *,
                   last: bool) -> bool:
    """Whether the analysis at `epoch` also checkpoints: always with `every` None; otherwise
    once `every` epochs have passed since the last checkpoint (a fresh run's epoch 0 counting
    as one), and at the run's `last` analysis."""
    if every is None or last:
        return True
    return epoch - (last_checkpoint or 0) >= every


def _last_finite(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite[-1]) if finite.size else float("nan")


def _first_non_finite(metrics: dict[str, np.ndarray]) -> int | None:
    """Index of the first epoch of these whose learner loss is NaN/inf while training, else
    None (before the replay fills the learner does not train and its loss is NaN by design)."""
    bad = (metrics["learner/training"] > 0) & ~np.isfinite(metrics["learner/loss"])
    return int(np.argmax(bad)) if bad.any() else None


def _non_finite_message(epoch: int) -> str:
    return (f"learner loss became non-finite at epoch {epoch}; the run stopped and its last "
            "good checkpoint is kept (lower the learning rate or check the inputs, then start a "
            "new --out or resume from the checkpoint)")


def _analyse_together(stream: Stream, states: StreamState, due: list,
                      checkpoint_every: int | None = None) -> None:
    """Analyses the runs `due` [(index in the stacked states, run)] at their (common) epoch.

    The runs that one device holds are evaluated by one `analysis.evaluate_runs` call on that
    device (on a GPU about the cost of one run's `evaluate`: the analysis is latency bound), the
    time shared among them; with the runs split across devices that is one call per device, the
    devices taken in turn. Not one host thread per device, as the epochs run: the analysis
    traces its programs as it goes, and a worker thread does not see the caller's JAX config
    contexts (e.g. `jax.threefry_partitionable`, which decides the random bits of the test
    sets and the regressor). Each run then writes its records, figures and checkpoint as
    alone."""
    reports = {}
    for device_states, members in due_by_device(states, due):
        tic = time.perf_counter()
        runs = [r for _, r in members]
        parts: dict[str, float] = {}
        kept = [r.pi_rand_set for r in runs]
        evaluated = analysis.evaluate_runs(stream, device_states,
                                           jnp.stack([r.eval_key() for r in runs]),
                                           jnp.stack([r.pi_rand_key for r in runs]),
                                           seconds=parts,
                                           pi_rand_sets=None if None in kept else kept)
        share = (time.perf_counter() - tic) / len(members)
        for (i, r), report in zip(members, evaluated, strict=True):
            r.seconds["analysis"] += share
            for part, seconds in parts.items():
                r.analysis_parts[part] = r.analysis_parts.get(part, 0.0) + seconds / len(members)
            reports[i] = report
    names = analysis.error_names(stream)
    for i, r in due:
        state = jax.tree.map(lambda x, i=i: x[i], states)
        with timed(r.seconds, "analysis"), timed(r.analysis_parts, "reconstructions"):
            frames = analysis.reconstructions(stream, state, jax.random.fold_in(r.eval_key(), 7))
            _save_png(r.out / "recon" / f"epoch_{r.epoch:06d}.png", list(frames))
        r.analyse(stream, state, reports[i], names, checkpoint_every)


def _records(stream: Stream, names: list[str], epoch: int, report: dict, *,
             seed: int) -> list[dict]:
    """One run's history records from its report."""
    # `seed` is the run's own: runs trained together share one Stream, whose config carries
    # the first run's seed.
    errors = {k: v for k, v in report["errors"].items() if k != "validation"}
    records = plots.history_records(epoch, stream.config.learner, errors, names,
                                    report["distortion"], run=seed)
    # The held-out replay rows' error, for choices made without the test sets, and what a latent
    # with no information scores on each test set's rows (`evaluation.constant_errors`).
    validation = dict(zip(names, report["errors"]["validation"], strict=True))
    records = [r | {"validation": validation,
                    "baseline": dict(zip(names, report["baseline"][r["test_set"]], strict=True)),
                    "irregularity": report.get("irregularity")}
               for r in records]
    return records


def _figures(history: list[dict], out: Path) -> None:
    plots.plot_alignment(history, out / "alignment.png")
    plots.plot_distortion(history, out / "distortion.png")
