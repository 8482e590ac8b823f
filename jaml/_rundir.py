"""The run directory shared by `jaml relations` and `jaml suite` (and the experiment drivers
built on them): its config check, atomic JSON, and the append-only logs cut back on resume.

    OUT/config.json     the resolved configuration (a stream run's: its learner's and env's
                        configs too); a different one in the same OUT is refused
    OUT/.lock           held (flock) by the process training the run; a second one is refused
    OUT/metrics.jsonl   one JSON record per logged step, cut back to the checkpoint on resume
    OUT/tensorboard/    the same scalars for TensorBoard

A run that resumes from its last checkpoint would otherwise append the records logged after that
checkpoint a second time; `RunLog` drops them first, so the logs read as one uninterrupted run.
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import socket
from collections.abc import Callable
from pathlib import Path


def write_atomically(path: Path, write: Callable[[Path], None]) -> None:
    """`write(tmp)` to a temporary name of this process's own beside `path`, then rename it over
    `path`: a reader never sees a half-written file, and processes rewriting one shared file
    (the experiment reports, when several processes train cells of one grid) leave it whole,
    the last writer's. The temporary is removed if `write` fails."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text(path: Path, text: str) -> None:
    """Write a text file atomically (`write_atomically`)."""
    write_atomically(path, lambda tmp: tmp.write_text(text))


def write_json(path: Path, value) -> None:
    """Write JSON atomically (`write_atomically`)."""
    write_text(path, json.dumps(value, indent=2, default=float) + "\n")


class RunInUse(RuntimeError):
    """Another process holds the run directory (see `lock`)."""


def lock(out: Path):
    """An exclusive claim on the run directory `out` for as long as the returned file stays
    open (close it to release; the kernel releases it when the process dies, so a killed run
    leaves no stale lock). Two processes training one directory would interleave its
    checkpoints and logs; the second is refused with `RunInUse`, naming the holder."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    handle = (out / ".lock").open("a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = handle.read().strip() or "a process that did not say which"
        handle.close()
        raise RunInUse(f"{out} is being run by another process ({holder}); wait for it to end "
                       "or choose another --out") from None
    handle.seek(0)
    handle.truncate()
    handle.write(f"pid {os.getpid()} on {socket.gethostname()}\n")
    handle.flush()
    return handle


def claim(out: Path, resolved: dict, same: Callable[[dict], bool] | None = None,
          differences: Callable[[dict], str] | None = None) -> bool:
    """Make `out` the directory of the run that `resolved` (JSON-ready) describes: created if
    missing, config.json written. Returns True when it held this run already (a resume).

    Raises ValueError when `out` holds a run with another configuration (`same(recorded)` is
    False; default: the recorded JSON differs from `resolved`), so that resuming never mixes
    two runs' checkpoints and logs; `differences(recorded)` names what differs, in the
    message."""
    config_path = Path(out) / "config.json"
    resuming = config_path.exists()
    same = (lambda recorded: recorded == resolved) if same is None else same
    recorded = json.loads(config_path.read_text()) if resuming else None
    if resuming and not same(recorded):
        what = "" if differences is None else f": {differences(recorded)}"
        raise ValueError(f"{out} holds a run with a different configuration ({config_path}"
                         f"{what}); resume with the same options or choose a new --out")
    Path(out).mkdir(parents=True, exist_ok=True)
    write_json(config_path, resolved)
    return resuming


def truncate_jsonl(path: Path, keep: Callable[[dict], bool]) -> list[dict]:
    """Keep the records of a JSON-lines file for which keep(record) holds (atomically); returns
    them ([] when the file does not exist)."""
    if not path.exists():
        return []
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    kept = [r for r in records if keep(r)]
    write_text(path, "".join(json.dumps(r) + "\n" for r in kept))
    return kept


class RunLog:
    """metrics.jsonl records and TensorBoard scalars of one run.

    `keep` (optional) selects the records of metrics.jsonl that survive a resume: those written
    up to the checkpoint the run restarts from."""

    def __init__(self, out: Path, keep: Callable[[dict], bool] | None = None):
        from tensorboardX import SummaryWriter

        if keep is not None:
            truncate_jsonl(Path(out) / "metrics.jsonl", keep)
        self.jsonl = (Path(out) / "metrics.jsonl").open("a")
        self.tb = SummaryWriter(str(Path(out) / "tensorboard"))

    def record(self, record: dict) -> None:
        """One metrics.jsonl line (flushed with the next `flush`)."""
        self.jsonl.write(json.dumps(record) + "\n")

    def scalars(self, values: dict[str, float], step: int, prefix: str = "") -> None:
        """TensorBoard scalars at `step`, named prefix + key; non-finite values are skipped
        (TensorBoard draws them as gaps at best)."""
        for name, value in values.items():
            if math.isfinite(value):
                self.tb.add_scalar(prefix + name, value, step)

    def flush(self) -> None:
        self.jsonl.flush()
        self.tb.flush()

    def close(self) -> None:
        self.jsonl.close()
        self.tb.close()
