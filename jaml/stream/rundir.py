"""A `jaml suite` run directory: its config check, state (restored or fresh), logs, analysis
records, figures, reconstructions, checkpoints and summary.

The directory's files and the resume rules are listed in docs/stream.md, "Run directory".
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np
from matplotlib.image import imsave

from jaml._rundir import RunLog, claim, describe, differing, lock, truncate_jsonl, write_json
from jaml.configs import records
from jaml.configs.stream import SMOKE_NOTE, RunConfig, changed_fields, resolve, scale_of
from jaml.evaluation import plots
from jaml.stream import analysis, checkpoint
from jaml.stream.loop import Stream, StreamState
from jaml.stream.schedule import first_non_finite
from jaml.stream.timing import timed

# What a run resumed from: the command line shows this logger at INFO (`jaml.cli.main`).
resume_log = logging.getLogger("jaml.resume")
log = logging.getLogger("jaml.stream")


def claim_run(out: Path, config: RunConfig, stream: Stream) -> bool:
    """`_rundir.claim` for a run of `stream` (`run_record`)."""
    return claim(out, *run_record(out, config, stream))


def run_record(out: Path, config: RunConfig, stream: Stream
               ) -> tuple[dict, Callable[[dict], bool], Callable[[dict], str]]:
    """What `_rundir.claim` is given for a run of `stream` in `out`: (record, same,
    differences). config.json holds the run's `config` whole (`RunConfig.to_dict`). A recorded
    run is this one when its record (`records.read`: older records, and a `penalty.json`
    beside them, read as the runs they were) resolves to this `config` (`Stream.run_config`). A
    learner of your own (MODULE:FACTORY) is recorded by the config its factory gave
    (`_own_learner_config`), compared when both records have it. A refusal names the fields
    that differ."""
    record = config.to_dict()
    own = _own_learner_config(stream)
    if own is not None:
        record["learner_config"] = own

    def then(recorded: dict) -> RunConfig:
        return resolve(records.read(recorded, out), len(stream.env.ld_state_names),
                       jax.default_backend())

    def same(recorded: dict) -> bool:
        before = records.own_learner(recorded)
        own_differs = own is not None and before is not None and before != own
        return then(recorded) == config and not own_differs

    def differences(recorded: dict) -> str:
        was = changed_fields(then(recorded), config)
        before = records.own_learner(recorded)

        def shown(path: str, value, record: dict | None):
            # A learner of your own's config, None in the tree: its record (named by class).
            return record if path == "learner_config" and value is None else value

        named = [(path, shown(path, was[path], before), shown(path, value, own))
                 for path, value in changed_fields(config, then(recorded)).items()]
        if own is not None and before is not None and before != own:
            named += differing(before, own, "learner_config.")
        return describe(named)

    return record, same, differences


def _own_learner_config(stream: Stream) -> dict | None:
    """A learner of your own's config as its factory built it (JSON-ready, with its class as
    "type"), for config.json; None for a registry learner (its config is in the tree)."""
    if stream.config.learner_config is not None:
        return None
    own = stream.learner.config
    fields = json.loads(json.dumps(dataclasses.asdict(own), default=str))
    return {"type": f"{type(own).__module__}.{type(own).__qualname__}", **fields}


def _save_png(path: Path, rows: list[np.ndarray]) -> None:
    """Rows of uint8 [N, H, W, 3] images, tiled N across, with a 2-pixel gap."""
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


class RunDir:
    """One run's directory: its config check, keys, state (restored or fresh), logs, analyses,
    reconstructions, checkpoints and summary. Its figures go to `figures`, drawn in the
    background (`plots.FigureWriter`)."""

    def __init__(self, stream: Stream, config: RunConfig, out: Path, figures: plots.FigureWriter,
                 keep_pi_rand: bool = True):
        self.config, self.out, self.figures = config, out, figures
        self.scale = _scale(config)  # summary.json's "scale" (and "note")
        # The run's π_rand sequences, kept on the host after its first analysis in this call.
        self.pi_rand_set = analysis.PiRandSet() if keep_pi_rand else None
        # Taken by `_open`; released by `close` (or, the lock, when the process ends).
        self.lock, self.logs = None, None
        try:
            self._open(stream)
        except BaseException:  # a refused config or unreadable checkpoint: let the directory go
            for held in (self.logs, self.lock):
                if held is not None:
                    held.close()
            raise

    def _open(self, stream: Stream) -> None:
        """Locked and claimed (`run_record`), its logs cut back to its latest checkpoint's
        epoch, then its state: that checkpoint restored, or a fresh one."""
        config, out = self.config, self.out
        record, same, differences = run_record(out, config, stream)
        self.lock = lock(out)
        claim(out, record, same, differences)
        (out / "recon").mkdir(exist_ok=True)
        k_init, self.k_eval, self.pi_rand_key = jax.random.split(jax.random.PRNGKey(config.seed), 3)
        self.manager = checkpoint.manager(out)
        self.resumed_from: int | None = self.manager.latest_step()  # a checkpoint's step: its epoch
        self.epoch = self.resumed_from or 0
        self.history = truncate_jsonl(out / "history.jsonl", lambda r: r["step"] <= self.epoch)
        self.logs = _Logs(out, keep=lambda r: r["epoch"] <= self.epoch)
        if self.resumed_from is not None:
            self.state = checkpoint.restore(self.manager, jax.eval_shape(stream.init, k_init))
            resume_log.info("%s: resumed from its checkpoint at epoch %d of %d", out,
                            self.resumed_from, config.epochs)
        else:
            self.state = stream.init(k_init)
        self.status = "running"
        self.error: str | None = None  # why a "nonfinite" run stopped
        self.started = time.perf_counter()
        # Wall seconds of this call by phase (first calls include compilation); the epochs of
        # runs trained together are shared among them.
        self.seconds = {"epochs": 0.0, "analysis": 0.0, "checkpoint": 0.0}
        # The analysis phase by part (`analysis.evaluate`'s, then this run's records and
        # reconstructions; figures are drawn in the background): where its time goes.
        self.analysis_parts: dict[str, float] = {}
        # The reference rows (`analysis.reference_rows`, the constant's beside them) of this
        # call's first analysis, with its epoch: summary.json's "references".
        self.references: dict | None = None

    def settle(self, stop: int) -> None:
        """Finished at the run's last epoch, interrupted at `stop` (this call's); a run that no
        longer trains lets its kept π_rand sequences go (host memory for the others)."""
        if self.status == "running" and self.epoch >= self.config.epochs:
            self.status = "finished"
        elif self.status == "running" and self.epoch >= stop:
            self.status = "interrupted"
        if self.status != "running":
            self.pi_rand_set = None

    def trained(self, metrics: dict[str, np.ndarray], seconds: float) -> bool:
        """Logs the epochs just trained (metrics [n] per name) and advances; False, with the
        run stopped ("nonfinite") and its epochs logged up to the first bad one, where its loss
        turned non-finite."""
        self.seconds["epochs"] += seconds
        bad = first_non_finite(metrics)
        if bad is not None:  # the terms that went first can be read in metrics.jsonl
            self.logs.epochs(self.epoch, {k: v[:bad + 1] for k, v in metrics.items()})
            self.status, self.error = "nonfinite", _non_finite_message(self.epoch + bad + 1)
            log.error("%s: %s", self.out, self.error)
            return False
        self.logs.epochs(self.epoch, metrics)
        self.epoch += len(next(iter(metrics.values())))
        return True

    def abort(self, status: str) -> None:
        """The run, if still going, ended by an exception: "interrupted" (Ctrl-C, SIGTERM) or
        "failed"; its summary says so."""
        if self.status == "running":
            self.status = status

    def stop(self, state: StreamState) -> None:
        """Stops before the run's end: a checkpoint at the current epoch (unless the last one is
        there), so the next call resumes here; status "interrupted"."""
        if self.manager.latest_step() != self.epoch:
            self.save(state)
        self.status = "interrupted"

    @property
    def checkpoint_epoch(self) -> int | None:
        """The epoch of the run's latest checkpoint (None before its first)."""
        return self.manager.latest_step()

    def eval_key(self) -> jax.Array:
        """The analysis key of the current epoch."""
        return jax.random.fold_in(self.k_eval, self.epoch)

    def analysed(self, result: analysis.RunAnalysis, state: StreamState, *,
                 checkpoint: bool) -> None:
        """The run's analysis at the current epoch (`analysis.analyse_runs`) kept: its time,
        records, reconstructions, figures and, with `checkpoint` (`schedule.checkpoints`), an
        atomic checkpoint of the `state` it analysed."""
        report, names = result.report, result.names
        self.seconds["analysis"] += result.seconds
        for part, seconds in result.parts.items():
            self.analysis_parts[part] = self.analysis_parts.get(part, 0.0) + seconds
        if "references" in report:
            self.references = {"epoch": self.epoch, "validation_split":
                               report["validation_split"], **report["references"]}
        floor = _floor(self.references, names)
        with timed(self.seconds, "analysis"), timed(self.analysis_parts, "records"):
            _save_png(self.out / "recon" / f"epoch_{self.epoch:06d}.png", list(result.frames))
            records = _records(self.config.learner, names, self.epoch, report,
                               seed=self.config.seed)
            self.history += records
            with (self.out / "history.jsonl").open("a") as f:
                # One write per analysis, so a report read beside it (`_runs.read_history`
                # skips an unterminated line) almost never sees part of an epoch's records.
                f.write("".join(json.dumps(r) + "\n" for r in records))
            self.figures.submit(self.out, list(self.history), floor)
            self.logs.analysis(self.epoch, records)
        if checkpoint:
            self.save(state)
        # A progress summary (status "running"): a process that dies without reaching `close`
        # (a machine taken back, SIGKILL) still leaves its epoch, phase times and last records.
        write_json(self.out / "summary.json", self.summary())

    def save(self, state: StreamState) -> None:
        """An atomic checkpoint of `state` at the current epoch."""
        with timed(self.seconds, "checkpoint"):
            checkpoint.save(self.manager, self.epoch, state)

    def summary(self) -> dict:
        """summary.json's record of this call so far; its checkpoint the newest on disk (read
        again: a save that an interrupt cut short may still have been finalised)."""
        last = max((h["step"] for h in self.history), default=-1)
        self.manager.reload()
        return {
            "status": self.status,
            "epoch": self.epoch,
            "seconds_this_call": time.perf_counter() - self.started,
            "seconds_by_phase": self.seconds,
            "seconds_in_analysis": self.analysis_parts,
            "checkpoint_epoch": self.manager.latest_step(),
            "resumed_from": self.resumed_from,
            "final": [r for r in self.history if r["step"] == last],
            "references": self.references,
            **self.scale,
            **({"error": self.error} if self.error is not None else {}),
        }

    def close(self) -> dict:
        self.logs.close()
        self.manager.close()
        summary = self.summary()
        write_json(self.out / "summary.json", summary)
        self.lock.close()
        return summary


def open_runs(stream: Stream, configs: list[RunConfig], outs: list[Path], **options
              ) -> list[RunDir]:
    """A `RunDir` per (config, out), `stream`'s runs (`Stream.run_config`), `options` RunDir's;
    one refused lets the ones opened before it go too."""
    runs: list[RunDir] = []
    try:
        for config, out in zip(configs, outs, strict=True):
            runs.append(RunDir(stream, config, out, **options))
    except BaseException:
        for r in runs:
            r.lock.close()
        raise
    return runs


def _non_finite_message(epoch: int) -> str:
    return (f"learner loss became non-finite at epoch {epoch}; the run stopped and its last "
            "good checkpoint is kept (lower the learning rate or check the inputs, then start a "
            "new --out or resume from the checkpoint)")


def _records(learner: str, names: list[str], epoch: int, report: dict, *,
             seed: int) -> list[dict]:
    """One run's history records from its report."""
    errors = {k: v for k, v in report["errors"].items() if k != "validation"}
    records = plots.history_records(epoch, learner, errors, names,
                                    report["distortion"], run=seed)
    # The held-out replay rows' error, for choices made without the test sets, and what a latent
    # with no information scores on each test set's rows (`evaluation.constant_errors`).
    validation = dict(zip(names, report["errors"]["validation"], strict=True))
    trimmed = report.get("distortion_trimmed") or {}
    records = [r | {"validation": validation,
                    "baseline": dict(zip(names, report["baseline"][r["test_set"]], strict=True)),
                    "irregularity": report.get("irregularity"),
                    "distortion_trimmed": trimmed.get("value"),
                    "distortion_left_out": trimmed.get("left_out"),
                    "validation_split": report.get("validation_split")}
               for r in records]
    return records


def _scale(config: RunConfig) -> dict:
    """{"scale": the `config.SCALES` entry whose set sizes the run has (`config.scale_of`)},
    and at the smoke scale a "note" that its numbers do not rank encoders."""
    scale = scale_of(config)
    return {"scale": scale, **({"note": SMOKE_NOTE} if scale == "smoke" else {})}


def _floor(references: dict | None, names: list[str]) -> dict | None:
    """The true state's errors of this call's reference rows by test set and state name (the
    alignment figure's floor), or None before the call's first analysis."""
    if references is None:
        return None
    return {test_set: dict(zip(names, errors, strict=True))
            for test_set, errors in references["true_state"].items()}
