"""When runs trained together stop: their analyses, `stop_after`, a deadline, thinned checkpoints
and a non-finite loss, as pure functions of epochs, times and metrics (`jaml.stream.run` obeys).

A call trains blocks: the runs still going at the lowest epoch, together, to the nearest of their
next analysis, their stop (`stop_after` epochs into this call) and an optional cap (a deadline's
check). Runs resumed at different epochs thus advance apart until they meet.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np


def analysis_epochs(first: int, last: int, every: int) -> list[int]:
    """Epochs after which a run analyses and checkpoints: at `first`, when the replay is full
    (the learner has just started: `RunConfig.fill_epochs`), every `every` epochs after that
    (`eval.every`), and at its `last` epoch."""
    epochs = list(range(first, last + 1, every))
    if not epochs or epochs[-1] != last:
        epochs.append(last)
    return epochs


def stop_epoch(epoch: int, epochs: int, stop_after: int | None) -> int:
    """Where a run at `epoch` stops in this call: its last epoch, or `stop_after` epochs on."""
    return epochs if stop_after is None else min(epochs, epoch + stop_after)


@dataclasses.dataclass(frozen=True)
class Block:
    """The runs `runs` (indices) trained together from epoch `start` to `end`; `analysis`:
    `end` is one of their analysis epochs."""

    runs: tuple[int, ...]
    start: int
    end: int
    analysis: bool

    @property
    def epochs(self) -> int:
        return self.end - self.start


def next_block(epochs: Sequence[int | None], stops: Sequence[int], analyses: Sequence[int],
               cap: int | None = None) -> Block | None:
    """The next block of a call, or None when no run is left: run i is at `epochs[i]` (None: it
    stopped, e.g. non-finite) and stops at `stops[i]`; the runs below their stops at the lowest
    epoch train to the first of their next analysis, their stops and `cap` epochs."""
    going = [i for i, e in enumerate(epochs) if e is not None and e < stops[i]]
    if not going:
        return None
    start = min(epochs[i] for i in going)
    runs = tuple(i for i in going if epochs[i] == start)
    end = min(next(a for a in analyses if a > start), *(stops[i] for i in runs))
    if cap is not None:
        end = min(end, start + cap)
    return Block(runs, start, end, end in analyses)


def in_time(block: Block, now: float, deadline: float | None, pace: float | None,
            analysis_seconds: float) -> bool:
    """Whether `block` ends before `deadline` at `pace` seconds an epoch (None: not measured
    yet), plus `analysis_seconds` if it ends at an analysis; always without a deadline."""
    if deadline is None:
        return True
    ahead = 0.0 if pace is None else pace * block.epochs + (
        analysis_seconds if block.analysis else 0.0)
    return now + ahead <= deadline


def checkpoint_due(epoch: int, last_checkpoint: int | None, every: int | None, *,
                   last: bool) -> bool:
    """Whether the analysis at `epoch` also checkpoints: always with `every` None; otherwise
    once `every` epochs have passed since the last checkpoint (a fresh run's epoch 0 counting
    as one), and at the run's `last` analysis."""
    if every is None or last:
        return True
    return epoch - (last_checkpoint or 0) >= every


def checkpoints(block: Block, last: Sequence[int | None], every: int | None, epochs: int,
                final: bool) -> list[bool]:
    """Whether each run of `block` checkpoints with the analysis at the block's end, decided
    before the block trains: never without an analysis there; else `checkpoint_due` of the
    run's last checkpoint (`last[i]`, by run), the run's last epoch (`epochs`) counting as its
    last analysis where `final` (`final_checkpoint`)."""
    return [block.analysis and checkpoint_due(block.end, last[i], every,
                                              last=final and block.end == epochs)
            for i in block.runs]


def stopped_here(block: Block, stops: Sequence[int], epochs: int) -> list[bool]:
    """Whether each run of `block` stops at the block's end before its last epoch (`epochs`),
    at its stop (`stops[i]`, by run: `stop_epoch`'s): it checkpoints there, so that the next
    call resumes where this one stopped."""
    return [block.end == stops[i] < epochs for i in block.runs]


def first_non_finite(metrics: dict[str, np.ndarray]) -> int | None:
    """Index of the first epoch of these whose learner loss is NaN/inf while training, else
    None (before the replay fills the learner does not train and its loss is NaN by design)."""
    bad = (metrics["learner/training"] > 0) & ~np.isfinite(metrics["learner/loss"])
    return int(np.argmax(bad)) if bad.any() else None
