"""`jaml suite`'s driver: trains runs of one program together, each in its own run directory
(`jaml.stream.rundir`), to their analyses, a deadline or a stop, and analyses them together.
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

from jaml import _interrupts
from jaml.configs.stream import StreamConfig
from jaml.evaluation.plots import FigureWriter
from jaml.stream import analysis
from jaml.stream.executor import BLOCK, Stacked, held_runs, run_stacked_epochs, runs_mesh
from jaml.stream.loop import Stream, StreamState, build_runs
from jaml.stream.rundir import RunDir, claim_run, open_runs
from jaml.stream.schedule import (
    Block,
    analysis_epochs,
    checkpoint_due,
    checkpoints,
    in_time,
    next_block,
    stop_epoch,
    stopped_here,
)
from jaml.stream.timing import Stopwatch

__all__ = ["DEADLINE_BLOCK", "NonFiniteLoss", "analysis_epochs", "checkpoint_due", "claim_run",
           "run", "run_many"]


class NonFiniteLoss(RuntimeError):
    """The learner's loss became NaN/inf; the run stopped at its last good checkpoint."""


def run(config: StreamConfig, out, *, progress: bool = True, stop_after: int | None = None,
        checkpoint_every: int | None = None, final_checkpoint: bool = True,
        keep_pi_rand: bool = True, deadline: float | None = None) -> dict:
    """Runs (or resumes) the loop in `out`; returns the summary. `stop_after` (epochs) and
    `deadline` (a `time.monotonic()` instant) end the process's work early, with a checkpoint
    (a deliberate interruption, for jobs with a time limit); the next call resumes. A
    non-finite loss raises `NonFiniteLoss`."""
    summary = run_many([config], [out], progress=progress, stop_after=stop_after,
                       checkpoint_every=checkpoint_every, final_checkpoint=final_checkpoint,
                       keep_pi_rand=keep_pi_rand, deadline=deadline)[0]
    if summary["status"] == "nonfinite":
        raise NonFiniteLoss(summary["error"])
    return summary


def run_many(configs: list[StreamConfig], outs: list, *, progress: bool = True,
             stop_after: int | None = None, checkpoint_every: int | None = None,
             final_checkpoint: bool = True, mesh=None, keep_pi_rand: bool = True,
             deadline: float | None = None) -> list[dict]:
    """Runs (or resumes) several runs of one program, each in its own directory, trained
    together: the configs may differ only in their seeds (one Stream is built for the first and
    resolves them all, `build_runs`), and their states are stacked and
    advanced by one compiled loop (`run_stacked_epochs`; several devices split the runs, see
    `mesh`). Runs resumed at different epochs first advance in groups by epoch until they meet.
    Returns one summary per run; a run whose loss turns non-finite stops alone (status
    "nonfinite", its last good checkpoint kept) and the others go on.

    Several processes (`jax.distributed` initialised; every process calls with the same
    arguments): the mesh spans every process's devices (`runs_mesh`), each process opens,
    trains and writes only the runs it holds (`executor.held_runs`), and the summaries of the
    others are None. Its runs must advance together (resumed from one epoch): a process whose
    runs split into groups stops with an error.

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
    outs = _checked(len(configs), outs, checkpoint_every)
    stream, resolved = build_runs(configs)  # every config problem surfaces before any file
    processes = jax.process_count() > 1
    if processes and mesh is None:
        mesh = runs_mesh(len(configs))
    held = held_runs(len(configs), mesh) if processes else range(len(configs))
    figures = FigureWriter()
    runs = open_runs(stream, [resolved[i] for i in held], [outs[i] for i in held],
                     figures=figures, keep_pi_rand=keep_pi_rand)
    stacked = Stacked(runs)
    epochs = stream.config.epochs
    analyses = analysis_epochs(stream.config.fill_epochs, epochs, stream.config.eval.every)
    stops = [stop_epoch(r.epoch, epochs, stop_after) for r in runs]
    label = f"{stream.config.env} {stream.config.learner}" + (
        f" ×{len(runs)}" if len(runs) > 1 else "")
    bar = tqdm(total=epochs * len(runs), initial=sum(r.epoch for r in runs), desc=label,
               unit="epoch", disable=not progress)
    pace = None  # seconds per epoch of the last block, and of the last analysis (deadline)
    analysis_seconds = 0.0
    try:
        while True:
            _interrupts.raise_if_pending()  # a Ctrl-C that a callback swallowed (gc, JAX)
            for r, stop in zip(runs, stops, strict=True):
                r.settle(stop)
            block = next_block([r.epoch if r.status == "running" else None for r in runs],
                               stops, analyses, None if deadline is None else DEADLINE_BLOCK)
            if block is None:
                break
            saves = checkpoints(block, [r.checkpoint_epoch for r in runs], checkpoint_every,
                                epochs, final_checkpoint)
            stopping = stopped_here(block, stops, epochs)
            if not in_time(block, _clock(), deadline, pace, analysis_seconds):
                for i, r in enumerate(runs):  # every run still going stops where it is
                    if r.status == "running":
                        r.stop(stacked.state(i))
                break
            if processes and len(block.runs) < len(runs):
                raise ValueError(f"process {jax.process_index()}'s runs are at different "
                                 "epochs or some stopped; over several processes a process's "
                                 "runs advance together: resume them from one epoch")
            with Stopwatch() as watch:
                states, metrics = run_stacked_epochs(stream, stacked.of(block.runs),
                                                     block.epochs, mesh=mesh,
                                                     num_runs=len(configs) if processes else None)
                metrics = jax.tree.map(np.asarray, metrics)
            stacked.states = states
            pace = watch.steady / block.epochs
            bar.update(block.epochs * len(block.runs))
            trained = [(j, runs[i]) for j, i in enumerate(block.runs)
                       if runs[i].trained({k: v[:, j] for k, v in metrics.items()},
                                          watch.wall / len(block.runs))]
            with Stopwatch() as analysing:
                _ended(stream, states, stacked, block, trained, saves, stopping)
            if block.analysis and trained:
                analysis_seconds = analysing.steady
            bar.set_postfix(_shown(metrics))
    except KeyboardInterrupt:
        _interrupts.delivered()
        for r in runs:
            r.abort("interrupted")
        raise
    except BaseException:
        for r in runs:
            r.abort("failed")
        raise
    finally:
        bar.close()
        figures.wait()
        summaries = dict(zip(held, (r.close() for r in runs), strict=True))
    figures.check()  # a figure that failed to draw, after every summary is written
    return [summaries.get(i) for i in range(len(configs))]


# Epochs between deadline checks: the device loop's block, so no block is split.
DEADLINE_BLOCK = BLOCK
_clock = time.monotonic  # what deadlines are read against


def _checked(count: int, outs: list, checkpoint_every: int | None) -> list[Path]:
    """`run_many`'s arguments checked: one out directory for each of its `count` configs, each
    its own; the directories as Paths (that the configs are one program, `build_runs`
    checks)."""
    if count != len(outs) or not count:
        raise ValueError(f"run_many needs one out directory per config, got {count} "
                         f"configs and {len(outs)} directories")
    if checkpoint_every is not None and checkpoint_every < 1:
        raise ValueError(f"checkpoint_every must be a positive number of epochs or None, got "
                         f"{checkpoint_every}")
    outs = [Path(o) for o in outs]
    if len(set(outs)) < len(outs):
        raise ValueError(f"two runs share an out directory: {[str(o) for o in outs]}")
    return outs


def _shown(metrics: dict[str, np.ndarray]) -> dict[str, str]:
    """The progress bar's figures, the group's first run's: only what has a value (no episode
    ended yet reads "ret=nan", a learner that has not started "loss=nan")."""
    shown = {"ret": _last_finite(metrics["episode_return"][:, 0]),
             "loss": _last_finite(metrics["learner/loss"][:, 0])}
    return {k: f"{v:.4g}" for k, v in shown.items() if np.isfinite(v)}


def _last_finite(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite[-1]) if finite.size else float("nan")


def _ended(stream: Stream, states: StreamState, stacked: Stacked, block: Block,
           trained: list[tuple[int, RunDir]], saves: list[bool], stopping: list[bool]) -> None:
    """The runs `trained` [(index in the block's stacked `states`, run)] at the end of `block`
    (`stacked` holds those states): where it ends at their analysis, analysed together
    (`analysis.analyse_runs`), each run's directory keeping its analysis with a checkpoint
    where `saves` (by index) says so (`schedule.checkpoints`); a run `stopping` there
    (`schedule.stopped_here`) stops with a checkpoint, resumable. A run's state is taken from
    the stack as its turn comes, one at a time."""
    results = [None] * len(trained)
    if block.analysis:
        results = analysis.analyse_runs(
            stream, states, [j for j, _ in trained], [r.eval_key() for _, r in trained],
            [r.pi_rand_key for _, r in trained], [r.pi_rand_set for _, r in trained],
            [r.references is None for _, r in trained])
    for (j, r), result in zip(trained, results, strict=True):
        if result is None and not stopping[j]:
            continue
        state = stacked.state(block.runs[j])
        if result is not None:
            r.analysed(result, state, checkpoint=saves[j])
        if stopping[j]:
            r.stop(state)
