"""The run directory shared by `jaml relations` and `jaml suite`: config claim and refusal,
logs cut back to the checkpoint on resume, one process per directory."""

import json
import os
import subprocess
import sys

import pytest

from jaml import _rundir


def test_claim_creates_then_resumes_and_refuses_another_config(tmp_path):
    out = tmp_path / "a" / "run"
    assert _rundir.claim(out, {"lr": 1e-3, "widths": [8, 8]}) is False
    assert json.loads((out / "config.json").read_text()) == {"lr": 1e-3, "widths": [8, 8]}
    assert _rundir.claim(out, {"lr": 1e-3, "widths": [8, 8]}) is True
    with pytest.raises(ValueError, match="holds a run with a different configuration"):
        _rundir.claim(out, {"lr": 1e-4, "widths": [8, 8]})
    assert json.loads((out / "config.json").read_text())["lr"] == 1e-3  # left as it was
    with pytest.raises(ValueError, match=r"; use another --out or the same options \(lr 0\.001 "
                                         r"recorded, 0\.0001 now, widths \[8, 8\] recorded, "
                                         r"\[8, 4\] now; recorded in "):
        _rundir.claim(out, {"lr": 1e-4, "widths": [8, 4]})
    assert not list(out.glob("*.tmp"))


def test_run_log_keeps_the_records_up_to_the_checkpoint(tmp_path):
    log = _rundir.RunLog(tmp_path)
    for epoch in (1, 2, 3):
        log.record({"epoch": epoch, "loss": 1.0 / epoch})
    log.scalars({"loss": 0.5, "bad": float("nan")}, 3)
    log.close()
    log = _rundir.RunLog(tmp_path, keep=lambda r: r["epoch"] <= 2)  # resumed at epoch 2
    log.record({"epoch": 3, "loss": 0.25})
    log.close()
    lines = [json.loads(x) for x in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert lines == [{"epoch": 1, "loss": 1.0}, {"epoch": 2, "loss": 0.5},
                     {"epoch": 3, "loss": 0.25}]
    assert _rundir.truncate_jsonl(tmp_path / "missing.jsonl", lambda r: True) == []


def test_lock_refuses_a_second_holder_until_the_first_lets_go(tmp_path):
    out = tmp_path / "run"
    held = _rundir.lock(out)  # creates the directory
    assert (out / ".lock").read_text().startswith(f"pid {os.getpid()} on ")
    # flock conflicts between open file descriptions, so a second open in this process stands
    # in for a second process.
    mine = f"being run by another process \\(pid {os.getpid()} "
    with pytest.raises(_rundir.RunInUse, match=mine):
        _rundir.lock(out)
    held.close()
    with _rundir.lock(out):  # free again; a file object, so usable in `with`
        pass
    _rundir.lock(out).close()


def test_a_process_that_dies_releases_its_lock(tmp_path):
    out = tmp_path / "run"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from jaml import _rundir; "
         f"h = _rundir.lock({str(out)!r}); print('held', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(_rundir.RunInUse, match=f"pid {holder.pid} "):
            _rundir.lock(out)
    finally:
        holder.kill()
        holder.wait()
    _rundir.lock(out).close()  # the kernel released it with the process


def test_claim_refuses_a_folder_of_other_files_but_not_the_runs_own(tmp_path):
    """A folder with files but no config.json is not a run: refused, left as it was. The lock
    (`SIDECARS`) does not count."""
    other = tmp_path / "other"
    other.mkdir()
    for name in ("a.txt", "b.txt", "c.txt", "d"):
        (other / name).write_text("")
    with pytest.raises(ValueError, match=r"is not empty \(a\.txt, b\.txt, c\.txt, …\) and "
                                         r"holds no jaml run"):
        _rundir.claim(other, {"lr": 1})
    assert not (other / "config.json").exists()
    mine = tmp_path / "mine"
    _rundir.lock(mine).close()
    assert _rundir.claim(mine, {"lr": 1}) is False


@pytest.mark.parametrize("text, message", [
    ('{"lr": 1', "is not valid JSON"),
    ("[1, 2]", "holds a list, not a run's config"),
])
def test_a_damaged_config_json_is_named(tmp_path, text, message):
    (tmp_path / "config.json").write_text(text)
    with pytest.raises(ValueError, match=f"{tmp_path / 'config.json'} {message}"):
        _rundir.claim(tmp_path, {"lr": 1})


def test_a_config_json_the_reader_cannot_use_is_named(tmp_path):
    (tmp_path / "config.json").write_text('{"lr": 1}')

    def same(recorded):
        return recorded["widths"] == [8]  # a record of another format

    with pytest.raises(ValueError, match=r"config\.json does not describe a run this jaml can "
                                         r"read \(KeyError: 'widths'\)"):
        _rundir.claim(tmp_path, {"lr": 1}, same)


def test_an_unwritable_out_names_the_path_and_why(tmp_path, monkeypatch):
    """Run as root, permissions do not refuse a folder: the error is simulated."""
    out = tmp_path / "locked" / "run"

    def refuse(self, *args, **kwargs):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(_rundir.Path, "mkdir", refuse)
    with pytest.raises(_rundir.RunDirUnwritable,
                       match=rf"--out {out} cannot be written: Permission denied \(under "
                             rf"{tmp_path}, which exists\); choose a directory you can write"):
        _rundir.lock(out)
    assert issubclass(_rundir.RunDirUnwritable, ValueError)  # one line on the command line


def test_a_jsonl_cut_by_a_kill_loses_its_last_line_and_a_damaged_line_is_named(tmp_path):
    path = tmp_path / "metrics.jsonl"
    path.write_text('{"epoch": 1}\n{"epoch": 2}\n{"epo')  # the last write cut short
    assert _rundir.truncate_jsonl(path, lambda r: True) == [{"epoch": 1}, {"epoch": 2}]
    assert path.read_text() == '{"epoch": 1}\n{"epoch": 2}\n'
    path.write_text('{"epoch": 1}\nnot json\n{"epoch": 3}\n')
    with pytest.raises(ValueError, match=rf"{path}:2 is not valid JSON"):
        _rundir.truncate_jsonl(path, lambda r: True)
