"""A relations run directory: resolved config, metrics (JSON lines + TensorBoard), checkpoint,
summary.json and figures. A run interrupted at any point resumes from its last finished relation
when started again with the same directory and configuration."""

from __future__ import annotations

import dataclasses
import json
import logging
import shutil
import time
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

from jaml import sources
from jaml._rundir import RunLog, claim, lock, write_json
from jaml.configs.relations import Config
from jaml.relations import checkpoint, plots
from jaml.relations.relation_set import RelationSet, Report
from jaml.relations.training import RelationSummary, fit, phase_budgets

log = logging.getLogger("jaml.relations")
UNFINISHED = ("running", "interrupted")  # summary.json statuses of a run that has not ended


class _Recorder:
    """Metrics to metrics.jsonl and TensorBoard scalars; a tqdm bar per relation. On resume,
    metrics.jsonl keeps the records of the `done` relations the checkpoint holds and of the
    next one's first `kept_steps` (the state in OUT/partial)."""

    def __init__(self, out: Path, cfg: Config, done: int, step_offset: int, progress: bool,
                 kept_steps: int = 0):
        self.log = RunLog(out, keep=lambda r: r["relation"] <= done or (
            r["relation"] == done + 1 and r["phase"] == "relation" and r["step"] <= kept_steps))
        self.cfg, self.offset, self.progress = cfg, step_offset, progress
        self.bar, self.bar_key, self.last_step = None, None, 0

    def __call__(self, phase: str, k: int, metrics: dict) -> None:
        total = self.offset + metrics["step"]
        self.log.record(
            {"phase": phase, "relation": k + 1, "total_step": total, "time": time.time(),
             **metrics}
        )
        scalars = {n: v for n, v in metrics.items() if n not in ("step", "steps")}
        self.log.scalars(scalars, total, prefix=f"g{k + 1}/{phase}/")
        self.log.flush()
        if self.progress:
            if self.bar_key != (phase, k):
                self._close_bar()
                budget = phase_budgets(self.cfg)[phase]
                # No total: a phase stops at convergence, mostly well before its budget.
                # Started at the first report's step, so the chunk run before the bar existed
                # does not count as a rate.
                self.bar = tqdm(desc=f"g{k + 1} {phase} (≤ {budget} steps)", unit="step",
                                initial=metrics["step"], leave=False)
                self.bar_key, self.last_step = (phase, k), metrics["step"]
            self.bar.update(metrics["step"] - self.last_step)
            self.last_step = metrics["step"]
            self.bar.set_postfix(
                on=f"{metrics.get('on_mean', 0):.3g}", off=f"{metrics.get('off_mean', 0):.3g}"
            )

    def relation_done(self, steps: int) -> None:
        self._close_bar()
        self.offset += steps

    def _close_bar(self):
        if self.bar is not None:
            self.bar.close()
            self.bar, self.bar_key = None, None

    def close(self):
        self._close_bar()
        self.log.close()


class _PartialDir:
    """The relation in training's loop state in OUT/partial (`training.Partial`), written every
    `every` seconds and when the relation's training ends; removed once the relation is in the
    checkpoint."""

    def __init__(self, path: Path, every: float = 30.0):
        self.path, self.every, self.last = path, every, time.monotonic()
        self.meta = checkpoint.loop_state_meta(path)

    def step(self, k: int) -> int:
        """The step relation k's kept state reached (0 when none is kept)."""
        return self.meta["step"] if self.holds(k) else 0

    def holds(self, k: int) -> bool:
        return self.meta is not None and self.meta.get("relation") == k + 1

    def restore(self, k: int, template):
        if not self.holds(k):
            return None
        state = checkpoint.load_loop_state(self.path, template)
        logging.getLogger("jaml.resume").info(
            "%s: g%d resumes at step %d", self.path.parent, k + 1, int(state.step))
        return state

    def save(self, k: int, state) -> None:
        if bool(state.done) or time.monotonic() - self.last >= self.every:
            self.meta = {"relation": k + 1, "step": int(state.step)}
            checkpoint.save_loop_state(state, self.path, self.meta)
            self.last = time.monotonic()

    def clear(self) -> None:
        if self.path.exists():
            shutil.rmtree(self.path)
        self.meta = None


def _as_now(recorded: dict) -> dict:
    """A recorded config.json with its relations config read as that run ran it
    (`Config.from_record`), comparable with today's."""
    try:
        relations = Config.from_record(recorded.get("relations", {})).to_dict()
    except (TypeError, ValueError):
        return recorded
    return recorded | {"relations": relations}


def _restored_summary(rs: RelationSet, k: int) -> dict:
    """A summary entry rebuilt from a checkpoint whose summary.json was lost."""
    on, off = float(rs.on_means[k]), float(rs.off_means[k])
    return {
        "index": k + 1,
        "width": rs.widths[k],
        "steps": 0,
        "seconds": 0.0,
        "status": "restored",
        "on_mean": on,
        "off_mean": off,
        "syzygies_found": rs.syzygies[k],
        "syzygy_rounds": [],
        "ratio": off / max(on, 1e-30),
    }


def run(
    source_name: str,
    cfg: Config,
    out,
    *,
    source_options: dict | None = None,
    progress: bool = True,
    figures: bool = True,
) -> dict:
    """Learn relations on a preset source, or a .npy / .csv file of rows, into the run directory
    `out`; returns the summary.

    `source_options` are `sources.make` overrides (recorded in config.json when given). A file's
    rows are recorded by their SHA-256, so a run does not resume on changed data."""
    source = sources.make(source_name, **(source_options or {}))
    out = Path(out)
    resolved = {"source": source_name, "relations": cfg.to_dict()}
    if isinstance(source, sources.FileSource):
        resolved["source_sha256"] = source.fingerprint()
    if source_options:
        resolved["source_options"] = source_options
    with lock(out):  # one process per run directory (`_rundir.lock`)
        summary_path, ckpt_path = out / "summary.json", out / "checkpoint"
        start, done = None, []
        resuming = claim(out, resolved, same=lambda recorded: _as_now(recorded) == resolved)
        previous = (json.loads(summary_path.read_text())
                    if resuming and summary_path.exists() else None)
        if previous is not None and previous.get("status") not in UNFINISHED:
            # A run that ended stays ended: nothing is trained again.
            logging.getLogger("jaml.resume").info("%s: finished (%s) before; nothing to train",
                                                  out, previous["status"])
            return previous
        partial = _PartialDir(out / "partial")
        if not resuming:
            partial.clear()
        if resuming and ckpt_path.exists():
            start = checkpoint.load(ckpt_path)
            recorded = previous["relations"] if previous is not None else []
            done = recorded[: start.num_relations] + [
                _restored_summary(start, k) for k in range(len(recorded), start.num_relations)
            ]
            if start.quality is None:  # checkpointed mid-fit: the ends are in summary.json
                start = start.replace(quality=Report(
                    {"relations": [{"index": r["index"], "status": r["status"]} for r in done]}))
            logging.getLogger("jaml.resume").info(
                "%s: resumed from its checkpoint with %d of %d relations", out,
                start.num_relations, cfg.max_relations)

        # Seconds of the calls before this one (summary.json's "seconds" counts every call).
        earlier = float(previous.get("seconds", 0.0)) if previous is not None else 0.0
        started = time.perf_counter()
        recorder = _Recorder(out, cfg, len(done), sum(r["steps"] for r in done), progress,
                             partial.step(len(done)))
        summaries = list(done)

        def write_summary(rs: RelationSet | None, status: str):
            report = rs.quality.to_dict() if rs is not None and rs.quality is not None else None
            write_json(
                summary_path,
                {
                    "source": source_name,
                    "status": status,
                    "num_relations": len(summaries),
                    "seconds": earlier + time.perf_counter() - started,
                    # Rank of the K×D Jacobian of all K relations on on-manifold rows.
                    "codimension": summaries[-1].get("codimension", {}) if summaries else {},
                    "relations": summaries,
                    # The fit's quality report on held-out rows (`relations.quality.assess`).
                    "quality": report,
                },
            )

        def on_relation(rs: RelationSet, summary: RelationSummary):
            recorder.relation_done(summary.steps)
            # A fit that trains its first relations again reports the kept ones once more.
            del summaries[summary.index - 1:]
            summaries.append(dataclasses.asdict(summary) | {"ratio": summary.ratio})
            # Summary first, then the checkpoint (atomic: Orbax renames a finished temporary
            # directory): a run killed in between resumes from the checkpoint it has, and the
            # summary is cut back to it.
            write_summary(rs, "running")
            checkpoint.save(rs, ckpt_path)
            partial.clear()

        try:
            rs = fit(source, cfg, start=start, callback=recorder, on_relation=on_relation,
                     partial=partial)
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM (`jaml`): the suite's word for it
            write_summary(None, "interrupted")
            raise
        finally:
            recorder.close()
        partial.clear()  # a relation dropped at the end leaves its state: the fit is over
        # "done" only where every relation met its stopping rule; the reason otherwise.
        capped = [r["index"] for r in summaries if r["status"] not in ("done", "restored")]
        if capped:
            status = "capped: " + ", ".join(f"g{i}" for i in capped)
        elif rs.num_relations < cfg.max_relations:
            status = "done: complete at " + str(rs.num_relations)
        else:
            status = "done"
        if rs.num_relations:
            checkpoint.save(rs, ckpt_path)  # again, now with the quality report
        else:
            status = "no relation: none separated on- from off-manifold rows"
        write_summary(rs, status)
        if figures and rs.num_relations:
            draw_figures(rs, source, out)
        return json.loads(summary_path.read_text())


def draw_figures(rs: RelationSet, source, out: Path, note: str = "") -> list[Path]:
    """The paper-style figures that fit this source's data (`note` ends their captions)."""
    key = jax.random.key(0)
    paths = []
    if rs.dim != 3 and not hasattr(source, "widened"):
        return paths  # no figure fits; skip the sample (an MJX rollout for the incline envs)
    on = np.asarray(source.sample(key, 2500))
    if rs.dim == 3:
        paths.append(
            plots.plot_zero_sets_3d(rs, on, out / "zero_sets.png", key, names=source.dim_names,
                                    note=note)
        )
    elif hasattr(source, "widened") and rs.dim >= 4:
        wide = np.asarray(source.widened(2.0).sample(key, 2500))
        paths.append(
            plots.plot_phase_space(
                rs, {"training range": on, "2x training range": wide}, out / "phase_space.png", key,
                note=note,
            )
        )
    return paths
