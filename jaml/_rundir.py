"""The run directory shared by `jaml relations` and `jaml suite` (and the experiment drivers
built on them): its config check, atomic JSON, and the append-only logs cut back on resume.

    OUT/config.json     the resolved configuration (a stream run's: its learner's and env's
                        configs too); a different one in the same OUT is refused, and so is
                        an OUT that holds other files but no config.json (not a jaml run)
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


class RunDirUnwritable(ValueError):
    """The run directory cannot be created or written (see `lock`)."""


def lock(out: Path):
    """An exclusive claim on the run directory `out` for as long as the returned file stays
    open (close it to release; the kernel releases it when the process dies, so a killed run
    leaves no stale lock). Two processes training one directory would interleave its
    checkpoints and logs; the second is refused with `RunInUse`, naming the holder. A directory
    that cannot be created or written raises `RunDirUnwritable`, saying where and why; one that
    is not a jaml run (`claim`) is refused before the lock file is written into it."""
    out = Path(out)
    _refuse_foreign(out)  # before the lock file is written into someone else's folder
    try:
        out.mkdir(parents=True, exist_ok=True)
        handle = (out / ".lock").open("a+")
    except OSError as error:
        raise RunDirUnwritable(_unwritable(out, error)) from None
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


def _unwritable(out: Path, error: OSError) -> str:
    """Why `out` cannot be a run directory, in one line: the nearest folder that exists and
    what the system said (creating a folder under /proc says "No such file or directory" of a
    folder that exists, so the bare message misleads)."""
    parent = next((p for p in (out, *out.parents) if p.exists()), None)
    where = "" if parent is None or parent == out else f" (under {parent}, which exists)"
    reason = error.strerror or type(error).__name__
    return (f"--out {out} cannot be written: {reason}{where}; choose a directory you can "
            "write")


# The lock `lock` creates: a directory holding only it is new.
SIDECARS = frozenset({".lock"})


def _refuse_foreign(out: Path) -> None:
    """Raise ValueError when `out` holds files but no config.json: a folder that is not a jaml
    run, whose files the run's would be mixed into."""
    if not out.is_dir() or (out / "config.json").exists():
        return
    foreign = sorted(p.name for p in out.iterdir() if p.name not in SIDECARS)
    if foreign:
        shown = ", ".join(foreign[:3]) + (", …" if len(foreign) > 3 else "")
        raise ValueError(f"{out} is not empty ({shown}) and holds no jaml run (no "
                         "config.json); choose a new or empty --out")


def claim(out: Path, resolved: dict, same: Callable[[dict], bool] | None = None,
          differences: Callable[[dict], str] | None = None) -> bool:
    """Make `out` the directory of the run that `resolved` (JSON-ready) describes: created if
    missing, config.json written. Returns True when it held this run already (a resume).

    Raises ValueError when `out` holds a run with another configuration (`same(recorded)` is
    False; default: the recorded JSON differs from `resolved`), so that resuming never mixes
    two runs' checkpoints and logs; `differences(recorded)` names what differs, in the
    message (default: the JSON fields that differ, `describe`). Also when `out` holds files
    but no config.json (a folder that is not a jaml run: the run's files would be mixed into
    it), or a config.json that cannot be read."""
    config_path = Path(out) / "config.json"
    resuming = config_path.exists()
    same = (lambda recorded: recorded == resolved) if same is None else same
    differences = differences or (lambda recorded: describe(differing(recorded, resolved)))
    _refuse_foreign(Path(out))
    recorded = _read_config(config_path) if resuming else None
    try:
        matches = resuming and same(recorded)
    except (TypeError, KeyError, ValueError, AttributeError) as error:
        raise ValueError(f"{config_path} does not describe a run this jaml can read "
                         f"({type(error).__name__}: {error}); choose a new --out") from None
    if resuming and not matches:
        what = differences(recorded)  # after the advice: a long line is cut at its end
        raise ValueError(f"{out} holds a run with a different configuration; use another "
                         f"--out or the same options ({what + '; ' if what else ''}recorded in "
                         f"{config_path})")
    Path(out).mkdir(parents=True, exist_ok=True)
    write_json(config_path, resolved)
    return resuming


def differing(recorded, now, at: str = "") -> list[tuple[str, object, object]]:
    """(path, recorded value, value now) of each field where two JSON-ready configs differ,
    nested dicts by their fields ("eval.every")."""
    if not (isinstance(recorded, dict) and isinstance(now, dict)):
        return [] if recorded == now else [(at.rstrip("."), recorded, now)]
    return [d for key in sorted(set(recorded) | set(now), key=str)
            for d in differing(recorded.get(key), now.get(key), f"{at}{key}.")]


def describe(differences: list[tuple[str, object, object]], most: int = 6) -> str:
    """`differing`'s fields as one compact line, `path OLD recorded, NEW now`: a config by
    its class name, a long value cut, at most `most` fields named."""

    def compact(value) -> str:
        if hasattr(value, "__dataclass_fields__"):
            return type(value).__name__
        if isinstance(value, dict):
            return str(value.get("type", "{…}")).rsplit(".", 1)[-1]
        text = repr(value)
        return text if len(text) <= 40 else text[:39] + "…"

    named = [f"{path} {compact(old)} recorded, {compact(new)} now"
             for path, old, new in differences[:most]]
    if len(differences) > most:
        named.append(f"and {len(differences) - most} more")
    return ", ".join(named)


def _read_config(path: Path) -> dict:
    """A run's config.json; a damaged one is a one-line error naming the file."""
    try:
        recorded = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"{path} is not valid JSON ({error}); restore it or choose a new "
                         "--out") from None
    if not isinstance(recorded, dict):
        raise ValueError(f"{path} holds a {type(recorded).__name__}, not a run's config; "
                         "restore it or choose a new --out")
    return recorded


def truncate_jsonl(path: Path, keep: Callable[[dict], bool]) -> list[dict]:
    """Keep the records of a JSON-lines file for which keep(record) holds (atomically); returns
    them ([] when the file does not exist). An unterminated last line (a write cut short by a
    killed process) is dropped; any other line that is not JSON is an error naming the line."""
    if not path.exists():
        return []
    text = path.read_text()
    lines = text.splitlines()
    records = []
    for number, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError as error:
            if number == len(lines) and not text.endswith("\n"):
                break
            raise ValueError(f"{path}:{number} is not valid JSON ({error}); remove that line "
                             "or choose a new --out") from None
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
