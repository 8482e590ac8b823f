"""A `jaml suite` run directory: the learning loop with logs, figures and resumable checkpoints.

    OUT/config.json       resolved StreamConfig (a different config in the same OUT is refused)
    OUT/metrics.jsonl     one line per epoch (episode return, PPO and learner losses); "epoch"
                          counts epochs completed, as an analysis's "step" does
    OUT/history.jsonl     one record per analysis and test set (`jaml.evaluation.plots` format)
    OUT/tensorboard/      the same scalars
    OUT/checkpoints/      Orbax: the whole StreamState (envs, PPO, learner, optimiser states,
                          replay, RNG key), written atomically after every analysis
    OUT/alignment.png, distortion.png, recon/epoch_XXXXXX.png, summary.json

Restarted with the same config, a run resumes from its newest checkpoint and drops the JSON-lines
records written after it, so the logs and the state agree and nothing is counted twice
(TensorBoard event files are append-only: a resumed run's scalars overlap the lost ones). A
non-finite learner loss stops the run with a message; the last good checkpoint stays.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import time
from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp
from tqdm.auto import tqdm

from jaml._files import write_json
from jaml.evaluation import plots
from jaml.stream.config import StreamConfig
from jaml.stream.loop import Stream, StreamState, build

log = logging.getLogger("jaml.stream")


class NonFiniteLoss(RuntimeError):
    """The learner's loss became NaN/inf; the run stopped at its last good checkpoint."""


def _truncate_jsonl(path: Path, keep) -> list[dict]:
    """Keeps the records for which keep(record) holds (atomically); returns them."""
    if not path.exists():
        return []
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    kept = [r for r in records if keep(r)]
    tmp = path.with_suffix(".tmp")
    tmp.write_text("".join(json.dumps(r) + "\n" for r in kept))
    os.replace(tmp, path)
    return kept


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


class _Logs:
    """metrics.jsonl + TensorBoard scalars."""

    def __init__(self, out: Path):
        from tensorboardX import SummaryWriter

        self.jsonl = (out / "metrics.jsonl").open("a")
        self.tb = SummaryWriter(str(out / "tensorboard"))

    def epochs(self, first_epoch: int, metrics: dict[str, np.ndarray]) -> None:
        n = len(next(iter(metrics.values())))
        for i in range(n):
            epoch = first_epoch + i + 1  # epochs completed, like an analysis's step
            row = {k: float(v[i]) for k, v in metrics.items()}
            self.jsonl.write(json.dumps({"epoch": epoch, **row}) + "\n")
            for k, v in row.items():
                if np.isfinite(v):
                    self.tb.add_scalar(k, v, epoch)
        self.jsonl.flush()

    def analysis(self, epoch: int, records: list[dict]) -> None:
        for r in records:
            for name, v in r["errors"].items():
                self.tb.add_scalar(f"alignment/{r['test_set']}/{name}", v, epoch)
        if records and records[0].get("distortion") is not None:
            self.tb.add_scalar("alignment/distortion", records[0]["distortion"], epoch)
        self.tb.flush()

    def close(self) -> None:
        self.jsonl.close()
        self.tb.close()


def _flat(state) -> dict[str, jax.Array]:
    """The state's non-empty leaves by position (Orbax refuses zero-size arrays, and mjx.Data
    has some, e.g. `act` for a model without actuator state)."""
    leaves = jax.tree.leaves(state)
    return {f"leaf_{i:05d}": x for i, x in enumerate(leaves) if np.prod(x.shape) > 0}


def _unflat(abstract, flat: dict[str, jax.Array]):
    leaves, treedef = jax.tree.flatten(abstract)
    restored = [flat[f"leaf_{i:05d}"] if np.prod(a.shape) > 0 else jax.numpy.zeros(a.shape,
                                                                                   a.dtype)
                for i, a in enumerate(leaves)]
    return jax.tree.unflatten(treedef, restored)


def _checkpointer(out: Path) -> ocp.CheckpointManager:
    return ocp.CheckpointManager(
        (out / "checkpoints").absolute(),
        options=ocp.CheckpointManagerOptions(max_to_keep=2, create=True),
    )


def run(config: StreamConfig, out, *, progress: bool = True, stop_after: int | None = None,
        latent_penalty=None) -> dict:
    """Runs (or resumes) the loop in `out`; returns the summary. `stop_after` ends the process's
    work after that many epochs in this call (a deliberate interruption, for tests and jobs
    with a time limit); the next call resumes."""
    out = Path(out)
    stream = build(config, latent_penalty)  # every config problem surfaces before any file
    resolved = config.to_dict()
    config_path = out / "config.json"
    if config_path.exists() and json.loads(config_path.read_text()) != resolved:
        raise ValueError(f"{out} holds a run with a different configuration ({config_path}); "
                         "resume with the same options or choose a new --out")
    out.mkdir(parents=True, exist_ok=True)
    write_json(config_path, resolved)
    (out / "recon").mkdir(exist_ok=True)

    key = jax.random.PRNGKey(config.seed)
    k_init, k_eval, pi_rand_key = jax.random.split(key, 3)
    manager = _checkpointer(out)
    state = None
    if manager.latest_step() is not None:
        abstract = jax.eval_shape(stream.init, k_init)
        flat = manager.restore(manager.latest_step(),
                               args=ocp.args.StandardRestore(_flat(abstract)))
        state = _unflat(abstract, flat)
        log.info("resuming %s at epoch %d", out, int(state.epoch))
    if state is None:
        state = stream.init(k_init)
    epoch = int(state.epoch)
    _truncate_jsonl(out / "metrics.jsonl", lambda r: r["epoch"] <= epoch)
    history = _truncate_jsonl(out / "history.jsonl", lambda r: r["step"] <= epoch)

    logs = _Logs(out)
    names = list(stream.env.ld_state_names)
    bar = tqdm(total=config.epochs, initial=epoch, desc=f"{config.env} {config.learner}",
               unit="epoch", disable=not progress)
    status, started, budget = "running", time.perf_counter(), stop_after
    # Wall seconds of this call by phase (first calls include compilation).
    seconds = {"epochs": 0.0, "analysis": 0.0, "checkpoint": 0.0}
    try:
        for target in [t for t in analysis_epochs(config) if t > epoch]:
            while epoch < target:
                n = target - epoch if budget is None else min(target - epoch, budget)
                if n == 0:
                    status = "interrupted"
                    break
                with _timed(seconds, "epochs"):
                    state, metrics = stream.run_epochs(state, n)
                    metrics = jax.tree.map(np.asarray, metrics)
                _check_finite(metrics, epoch)
                logs.epochs(epoch, metrics)
                epoch += n
                budget = None if budget is None else budget - n
                bar.update(n)
                bar.set_postfix(ret=f"{_last_finite(metrics['episode_return']):.3g}",
                                loss=f"{_last_finite(metrics['learner/loss']):.4g}")
            if status == "interrupted":
                break
            with _timed(seconds, "analysis"):
                records = _analyse(stream, state, jax.random.fold_in(k_eval, epoch),
                                   pi_rand_key, names, out, epoch)
            history += records
            with (out / "history.jsonl").open("a") as f:
                f.writelines(json.dumps(r) + "\n" for r in records)
            logs.analysis(epoch, records)
            _figures(history, out)
            with _timed(seconds, "checkpoint"):
                manager.save(epoch, args=ocp.args.StandardSave(_flat(state)))
                manager.wait_until_finished()
        else:
            status = "finished"
    except NonFiniteLoss:
        status = "nonfinite"
        raise
    except KeyboardInterrupt:
        status = "interrupted"
        raise
    except BaseException:
        status = "failed"
        raise
    finally:
        bar.close()
        logs.close()
        manager.close()
        summary = {
            "status": status,
            "epoch": epoch,
            "seconds_this_call": time.perf_counter() - started,
            "seconds_by_phase": seconds,
            "checkpoint_epoch": manager.latest_step(),
            "final": [r for r in history if r["step"] == max((h["step"] for h in history),
                                                            default=-1)],
        }
        write_json(out / "summary.json", summary)
    return summary


@contextlib.contextmanager
def _timed(seconds: dict[str, float], phase: str):
    """Adds the wall time of the block to seconds[phase]."""
    tic = time.perf_counter()
    try:
        yield
    finally:
        seconds[phase] += time.perf_counter() - tic


def _last_finite(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite[-1]) if finite.size else float("nan")


def _check_finite(metrics: dict[str, np.ndarray], first_epoch: int) -> None:
    loss = metrics["learner/loss"]
    training = metrics["learner/training"] > 0
    bad = training & ~np.isfinite(loss)
    if bad.any():
        raise NonFiniteLoss(
            f"learner loss became non-finite at epoch {first_epoch + int(np.argmax(bad)) + 1}; "
            "the run stopped and its last good checkpoint is kept (lower the learning rate or "
            "check the inputs, then start a new --out or resume from the checkpoint)"
        )


def _analyse(stream: Stream, state: StreamState, key, pi_rand_key, names, out: Path,
             epoch: int) -> list[dict]:
    report = stream.evaluate(state, key, pi_rand_key)
    errors = {k: v for k, v in report["errors"].items() if k != "validation"}
    records = plots.history_records(epoch, stream.config.learner, errors, names,
                                    report["distortion"], run=stream.config.seed)
    # The held-out replay rows' error, for choices made without the test sets.
    validation = dict(zip(names, report["errors"]["validation"], strict=True))
    records = [r | {"validation": validation} for r in records]
    truth, recon = stream.reconstructions(state, jax.random.fold_in(key, 7))
    _save_png(out / "recon" / f"epoch_{epoch:06d}.png", [truth, recon])
    return records


def _figures(history: list[dict], out: Path) -> None:
    plots.plot_alignment(history, out / "alignment.png")
    plots.plot_distortion(history, out / "distortion.png")
