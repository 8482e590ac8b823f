"""`jaml suite`'s driver: trains runs of one program together, each in its own run directory
(`jaml.stream.rundir`), to their analyses, a deadline or a stop, and analyses them together.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from jaml import _interrupts
from jaml.stream import analysis
from jaml.stream.config import StreamConfig
from jaml.stream.executor import (
    BLOCK,
    build,
    due_by_device,
    run_stacked_epochs,
    stack_runs,
    unstack_runs,
)
from jaml.stream.loop import Stream, StreamState
from jaml.stream.rundir import FigureWriter, RunDir, analysis_epochs, checkpoint_due, claim_run
from jaml.stream.timing import Stopwatch, timed

__all__ = ["DEADLINE_BLOCK", "NonFiniteLoss", "analysis_epochs", "checkpoint_due", "claim_run",
           "run", "run_many"]

log = logging.getLogger("jaml.stream")


class NonFiniteLoss(RuntimeError):
    """The learner's loss became NaN/inf; the run stopped at its last good checkpoint."""


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
    analysis in this call (`analysis.PiRandSet`; ≈ 2 GB per run at the paper's eval.rand and 16
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
    figures = FigureWriter()
    runs: list[RunDir] = []
    try:
        for c, o in zip(configs, outs, strict=True):
            runs.append(RunDir(stream, c, o, figures, final_checkpoint, keep_pi_rand))
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
    members: list[RunDir] = []
    states = None
    pace = None  # seconds per epoch of the last block, and of the last analysis (deadline)
    analysis_seconds = 0.0
    try:
        while True:
            _interrupts.raise_if_pending()  # a Ctrl-C that a callback swallowed (gc, JAX)
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
        _interrupts.delivered()
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


def _stop_in_time(active: list[RunDir], members: list[RunDir], states) -> None:
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
        # The reference rows at a run's first analysis in this call only: three more fits.
        evaluated = analysis.evaluate_runs(stream, device_states,
                                           jnp.stack([r.eval_key() for r in runs]),
                                           jnp.stack([r.pi_rand_key for r in runs]),
                                           seconds=parts,
                                           pi_rand_sets=None if None in kept else kept,
                                           references=any(r.references is None for r in runs))
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
            r.save_reconstructions(frames)
        r.analyse(stream, state, reports[i], names, checkpoint_every)
