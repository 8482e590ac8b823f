"""The benchmark harness refuses results that name no commit, writes those that do (a redirected
run's RESULTS.md beside its results), and names the code a row ran as its commit, "+dirty" for
uncommitted changes other than its own outputs; the Fig. 9 timing reads its runs' summaries
right."""

import json
import os
import subprocess
import sys

import pytest

from benchmarks import harness


def test_record_refuses_rows_without_a_commit_and_writes_rows_with_one(tmp_path, monkeypatch):
    env = {"device": "cpu:cpu", "device_count": 1, "cpu": "x", "cpu_cores": 2, "python": "3",
           "versions": {"jax": "0"}, "commit": "", "date": "2026-01-01T00:00:00+00:00"}
    monkeypatch.setattr(harness, "RESULTS_JSONL", tmp_path / "results.jsonl")
    monkeypatch.setattr(harness, "RESULTS_MD", tmp_path / "RESULTS.md")
    monkeypatch.setattr(harness, "environment", lambda: dict(env))
    with pytest.raises(ValueError, match="no commit"):
        harness.record("b", [{"case": "c", "wall_s": 1.0}])
    assert not (tmp_path / "results.jsonl").exists()
    env["commit"] = "abc1234"
    harness.record("b", [{"case": "c", "modelled_wall_s": 2.0}])
    row = json.loads((tmp_path / "results.jsonl").read_text())
    assert row["commit"] == "abc1234" and row["modelled_wall_s"] == 2.0
    assert "modelled_wall_s" in (tmp_path / "RESULTS.md").read_text()


def test_redirected_results_write_their_results_md_beside_them(tmp_path):
    """With JAML_BENCH_RESULTS set (read when the harness is imported), a benchmark's record
    writes its RESULTS.md next to the redirected results, not over the checkout's."""
    redirected = tmp_path / "out" / "results.jsonl"
    redirected.parent.mkdir()
    code = ("from benchmarks import harness; "
            "print(harness.RESULTS_JSONL); print(harness.RESULTS_MD)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=harness.HERE.parent,
                         env={**os.environ, "JAML_BENCH_RESULTS": str(redirected)})
    assert out.stdout.split() == [str(redirected), str(tmp_path / "out" / "RESULTS.md")]


def test_results_md_keeps_the_latest_row_per_case_machine_and_settings(tmp_path, monkeypatch):
    """A later row supersedes an earlier one of the same case only on the same machine at the
    same settings: two CPU models (both "cpu:cpu") and two device counts stay apart."""
    monkeypatch.setattr(harness, "RESULTS_JSONL", tmp_path / "results.jsonl")
    monkeypatch.setattr(harness, "RESULTS_MD", tmp_path / "RESULTS.md")
    base = {"benchmark": "b", "case": "c", "impl": "jaml", "device": "cpu:cpu", "cpu_cores": 2,
            "versions": {}, "commit": "abc1234", "date": "2026-01-01T00:00:00+00:00"}
    rows = [base | {"cpu": "AMD EPYC", "value": 1.0},
            base | {"cpu": "Intel Xeon", "value": 2.0},
            base | {"cpu": "AMD EPYC", "value": 3.0},  # supersedes the first
            base | {"device": "gpu:H200", "cpu": "Intel Xeon", "value": 4.0},  # before `devices`
            base | {"device": "gpu:H200", "cpu": "AMD EPYC", "devices": 1, "value": 6.0},
            base | {"device": "gpu:H200", "cpu": "Intel Xeon", "devices": 4, "value": 5.0},
            base | {"device": "gpu:H200", "cpu": "Intel Xeon", "runs": 4, "value": 7.0},
            base | {"device": "gpu:H200", "cpu": "Intel Xeon", "batch": 64, "value": 8.0},
            # pinned to one core (taskset): beside the unpinned Xeon row, not over it; a row
            # that records every core as its affinity is the unpinned one (supersedes "2")
            base | {"cpu": "Intel Xeon", "cpu_affinity": 1, "value": 9.0},
            base | {"cpu": "Intel Xeon", "cpu_affinity": 2, "value": 10.0},
            # malloc on huge pages: beside the 4 KiB row, whose later run (hugetlb=0, the
            # same as unrecorded) supersedes "3"
            base | {"cpu": "AMD EPYC", "glibc_tunables": "glibc.malloc.hugetlb=1", "value": 11.0},
            base | {"cpu": "AMD EPYC", "glibc_tunables": "glibc.malloc.hugetlb=0", "value": 12.0}]
    (tmp_path / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    harness.write_markdown()
    table = [line for line in (tmp_path / "RESULTS.md").read_text().splitlines()
             if line.startswith("| c |")]
    values = sorted(line.split(" | ")[-2] for line in table)
    # 1 superseded by 3 (same CPU); 4 (one device, recorded before the key) by 6: a GPU row's
    # host CPU model does not tell machines apart, its core count does (both 2 here).
    assert values == ["10", "11", "12", "5", "6", "7", "8", "9"]
    assert sum("pinned to 1" in line for line in table) == 1
    assert sum("malloc on huge pages" in line for line in table) == 1
    # A list of rates (each round's) is written as the floats are, in four digits.
    assert harness._fmt([186.93217, 0.5]) == "[186.9, 0.5]" and harness._fmt([1, 2]) == "[1, 2]"


def test_a_commit_is_dirty_for_changed_code_not_for_the_harness_outputs(tmp_path):
    def git(*args):
        subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=tmp_path,
                       check=True, capture_output=True)

    bench = tmp_path / "benchmarks"
    bench.mkdir()
    for path in (bench / "results.jsonl", bench / "bench.py", tmp_path / "lib.py"):
        path.write_text("0\n")
    git("init", "-q")
    git("add", ".")
    git("commit", "-q", "-m", "first")
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=tmp_path, text=True,
                          capture_output=True, check=True).stdout.strip()
    assert harness.git_commit(bench, ignore=("results.jsonl",)) == head
    (bench / "results.jsonl").write_text("0\n1\n")  # an earlier row of the same run
    (tmp_path / "untracked.txt").write_text("x")
    assert harness.git_commit(bench, ignore=("results.jsonl",)) == head
    (tmp_path / "lib.py").write_text("1\n")  # code outside the benchmarks folder counts
    assert harness.git_commit(bench, ignore=("results.jsonl",)) == head + "+dirty"
    assert harness.git_commit(tmp_path / "nowhere") == ""


def test_fig9_time_counts_a_methods_seeds_trained_together_once(tmp_path):
    from benchmarks import fig9_time

    def summary(path, seconds, phases, status="finished"):
        path.mkdir(parents=True)
        path.joinpath("summary.json").write_text(json.dumps(
            {"status": status, "epoch": 316, "seconds_this_call": seconds,
             "seconds_by_phase": phases}))

    (tmp_path / "relations" / "trnsv").mkdir(parents=True)
    (tmp_path / "relations" / "trnsv" / "summary.json").write_text(
        json.dumps({"relations": [{"seconds": 20.0}, {"seconds": 10.0}]}))
    summary(tmp_path / "pilot" / "w100" / "seed_100", 500.0, {"epochs": 400.0})
    # Three seeds of one call: each summary holds the call's wall time and its share of phases.
    for seed, seconds in enumerate((800.0, 810.0, 805.0)):
        summary(tmp_path / "PRED" / f"seed_{seed}", seconds, {"epochs": 200.0, "analysis": 60.0})
    summary(tmp_path / "VAE_rpl" / "seed_0", 700.0, {"epochs": 600.0, "analysis": 90.0})
    summary(tmp_path / "VAE_rpl" / "seed_1", 300.0, {"epochs": 250.0, "analysis": 40.0},
            status="running")  # unfinished: not counted
    rows = {r["case"]: r for r in fig9_time.rows(tmp_path)}
    assert rows["relations trnsv"]["wall_s"] == 30.0
    pred = rows["PRED x 3 seeds"]
    assert pred["wall_s"] == 810.0 and pred["epochs_s"] == 600.0 and pred["analysis_s"] == 180.0
    assert rows["VAE_rpl x 1 seeds"]["wall_s"] == 700.0
    total = "Fig. 9 total (relations + pilot + runs, {})"
    assert rows[total.format("methods one after another")]["wall_s"] == 30 + 500 + 810 + 700
    concurrent = {r["case"]: r for r in fig9_time.rows(tmp_path, concurrent=True)}
    assert concurrent[total.format("methods as parallel processes")]["wall_s"] == 30 + 500 + 810


def test_stream_throughput_times_each_mesh_once_and_scales_against_one_device(monkeypatch):
    """--runs 1 4 --devices 1 2 4 on this two-device process: R = 1 gets one device whatever
    was asked, 4 devices are the 2 there are, so three settings are timed, not six; the
    speed-ups are read against the one-device row of the same R (and R = 1)."""
    from benchmarks import stream_throughput

    calls = []

    def bench(env, learner, runs, num_envs, epochs, frames_per_batch, replay_slots, repeats,
              devices, dtype, activation_dtype, eval_sizes, only, cuda_graphs):
        calls.append((runs, devices, dtype, activation_dtype, eval_sizes, only))
        rate = {1: 10.0, 2: 18.0}[devices] * runs * (1 if cuda_graphs else 0.5)
        return [{"case": "c/loop", "impl": f"jaml{'' if cuda_graphs else ', off'}", "runs": runs,
                 "devices": devices, "env_frames_per_s": rate}]

    monkeypatch.setattr(stream_throughput, "bench", bench)
    recorded = []
    monkeypatch.setattr(harness, "record", lambda name, rows, notes: recorded.extend(rows))
    assert stream_throughput.main(["--runs", "1", "4", "--devices", "1", "2", "4"]) == 0
    assert calls == [(runs, devices, "float32", "float32", None, stream_throughput.CASES)
                     for runs, devices in ((1, 1), (4, 1), (4, 2))]
    by = {(r["runs"], r["devices"]): r for r in recorded}
    assert by[(4, 2)]["speedup_vs_one_device"] == pytest.approx(1.8)
    assert by[(4, 1)]["speedup_vs_one_run"] == pytest.approx(4.0)
    assert "speedup_vs_one_device" not in by[(4, 1)]
    with pytest.raises(SystemExit):
        stream_throughput.main(["--devices", "0"])
    calls.clear()
    assert stream_throughput.main(["--cases", "stream", "loop"]) == 0
    assert [c[-1] for c in calls] == [("stream", "loop")]
    # Both graph settings in one process: each row's speed-ups are read within its own impl.
    recorded.clear()
    assert stream_throughput.main(["--runs", "1", "4", "--devices", "1", "--cuda-graphs", "on",
                                   "off"]) == 0
    by = {(r["impl"], r["runs"]): r for r in recorded}
    assert by[("jaml, off", 4)]["speedup_vs_one_run"] == pytest.approx(4.0)
    assert by[("jaml", 4)]["env_frames_per_s"] == 2 * by[("jaml, off", 4)]["env_frames_per_s"]


def test_a_form_row_times_the_value_and_the_gradients_it_names(monkeypatch, capsys):
    """`form_row` differentiates `fn` for the arguments at `wrt` only (all by default), and its
    row and printed line name the case and the formulation."""
    import jax.numpy as jnp

    timed = []

    def measure_calls(step, args, reps, steps):
        timed.append(step(*args))
        return 0.5, 2e-6, None

    monkeypatch.setattr(harness, "measure_calls", measure_calls)
    x, w = jnp.arange(3.0), jnp.full(3, 2.0)
    row = harness.form_row("layer, 3", "plain", lambda x, w: x * w, (x, w), jnp.ones(3), 7, 20,
                           wrt=(1,))
    assert row == {"case": "layer, 3", "impl": "plain", "us_per_step": 2.0, "compile_s": 0.5}
    (y, grads), = timed
    assert y.tolist() == [0.0, 2.0, 4.0] and [g.tolist() for g in grads] == [[0.0, 1.0, 2.0]]
    harness.form_row("layer, 3", "all", lambda x, w: x * w, (x, w), jnp.ones(3), 1, 1)
    assert [g.tolist() for g in timed[1][1]] == [[2.0, 2.0, 2.0], [0.0, 1.0, 2.0]]
    assert "plain" in capsys.readouterr().out
