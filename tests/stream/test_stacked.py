"""Stacked runs: R seeds trained as one program must compute what each seed computes alone.

The reference is the host loop of one run (`Stream.host_epoch`: jitted `act` and `learn_step`
per call, the CPU path): the device loop (`fori_loop` over whole epochs, the GPU/TPU path) over R
vmapped runs, with the runs split across two devices (the two XLA:CPU devices of
tests/conftest.py) by one SPMD program, must reproduce every run's PPO and learner losses; one
process per device (`jax.distributed`) must train bit for bit what one process with both devices
does.
"""

import dataclasses
import json
import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from jax.sharding import NamedSharding
from jax.sharding import PartitionSpec as P

from jaml import stream
from jaml.stream import executor, loop
from jaml.stream import run as run_lib
from tests.stream.test_loop import tiny

SEEDS = (0, 1, 2)
EPOCHS = 2
METRICS = ("ppo/total_loss", "ppo/v_loss", "learner/training", "learner/loss")


def small():
    """VAE_v0 (no kept slots) with narrow convolutions (XLA:CPU runs convolutions inside the
    device loop's while loop slowly), one learner step per epoch: epoch 1 fills the replay (the
    learner waits), epoch 2 trains."""
    narrow = {"learner_config.conv_filters": (8, 8, 8, 8), "learner_config.conv_features": 16,
              "learner_config.deconv_filters": (8, 8, 8, 8)}
    return tiny(learner="VAE_v0", overrides=narrow, learner_steps=1)


@pytest.fixture(autouse=True, scope="module")
def _fast_compiling_prng():
    with jax.threefry_partitionable(False):  # see tests/learners/conftest.py
        yield


def _device_loop(s, seeds, epochs, mesh, inits=None):
    """Fresh runs of `seeds` trained through the device loop on `mesh`: (states, metrics).
    `inits`: each seed's initial state, made once for several calls (else made here)."""
    inits = inits or {seed: s.init(jax.random.PRNGKey(seed)) for seed in seeds}
    states = stream.stack_runs([inits[seed] for seed in seeds])
    return stream.run_stacked_epochs(s, states, epochs, mesh=mesh, host_loop=False)


def test_one_spmd_program_trains_every_seed_on_two_devices():
    """Three runs on the two XLA:CPU devices of tests/conftest.py (two on one, one and a
    padding copy on the other) as one `shard_map` program: compiled once for every seed and
    block length, and each seed's bits the same wherever the stacking puts it."""
    assert jax.device_count() == 2, "tests/conftest.py asks XLA for two CPU devices"
    s = stream.build(small())
    mesh = stream.runs_mesh(len(SEEDS))
    assert mesh.size == 2
    inits = {seed: s.init(jax.random.PRNGKey(seed)) for seed in SEEDS}  # both stackings'
    states, first = _device_loop(s, SEEDS, 1, mesh, inits)
    states, second = stream.run_stacked_epochs(s, states, 1, mesh=mesh, host_loop=False)
    assert states.epoch.tolist() == [2, 2, 2]
    together = jax.tree.map(lambda a, b: np.concatenate([a, b]), first, second)
    # The seeds in another order, two epochs in one call: device 0 now steps seeds 2 and 0.
    order = (2, 0, 1)
    _, reordered = _device_loop(s, order, 2, mesh, inits)
    program = executor.sharded_program(s)
    assert program._cache_size() == 1, "one compilation for both calls, both orders"
    assert not [k for k in s.programs if k[0] is executor._block], "no per-device programs"
    for k, v in together.items():
        for j, seed in enumerate(order):
            assert np.array_equal(np.asarray(reordered[k])[:, j], np.asarray(v)[:, seed],
                                  equal_nan=True), (k, seed)
    assert [np.asarray(together["learner/training"])[:, i].tolist() for i in range(3)] == (
        [[0, 1]] * 3)
    # CartPole's state holds empty arrays (no contacts); none crosses the shard_map (an empty
    # array returned as it came segfaults XLA's GPU compiler under Shardy): neither the
    # per-device inputs (the region's arguments) nor what the region returns.
    padded = stream.stack_runs([inits[seed] for seed in (0, 1, 2, 2)])  # what the loop ran
    assert [x for x in jax.tree.leaves(padded) if not x.size]
    text = program.lower(mesh, padded, np.int32(1)).as_text()
    crossing = [line for line in text.splitlines()
                if "sdy.manual_computation(" in line or line.lstrip().startswith("sdy.return")]
    assert crossing and not [line for line in crossing
                             if re.search(r"tensor<(\d+x)*0x", line)], "an empty array crosses"


def test_runs_are_laid_out_a_devices_share_at_a_time():
    """`_layout`: ceil(R / devices) runs per device in order, spare slots copies of the
    device's first run (of run 0 where it holds none); `held_runs` on one process: all."""
    assert executor._layout(3, 2, 2) == ([0, 1, 2, 2], [0, 1, 2])
    assert executor._layout(4, 2, 2) == ([0, 1, 2, 3], [0, 1, 2, 3])
    assert executor._layout(5, 4, 2) == ([0, 1, 2, 3, 4, 4, 0, 0], [0, 1, 2, 3, 4])
    # A process holding the last run of three, its one device at the mesh's 2-per-device share.
    assert executor._layout(1, 1, 2) == ([0, 0], [0])
    assert executor.held_runs(3, stream.runs_mesh(3)) == range(3)
    with pytest.raises(ValueError, match="pass its share"):
        stream.run_stacked_epochs(None, _FakeState(np.zeros(2)), 1, mesh=stream.runs_mesh(3),
                                  host_loop=False, num_runs=3)


class _FakeState:  # what `run_stacked_epochs` reads before it refuses a wrong share
    def __init__(self, epoch):
        self.epoch = epoch


@pytest.mark.slow  # more compiles: the host loop's pieces, the one-device program, the HLO
def test_runs_split_across_two_devices_match_each_run_alone():
    s = stream.build(small())
    alone = []
    for seed in SEEDS:
        _, metrics = stream.run_epochs(s, s.init(jax.random.PRNGKey(seed)), EPOCHS)
        alone.append(metrics)
    # The CPU's host loop compiled its learner step once (with the learner's compiler options,
    # `Stream.learner_jit`) and reused it for every step of every seed.
    assert s.learner_jit(loop._learn_step_runs)._cache_size() == 1
    _, together = _device_loop(s, SEEDS, EPOCHS, stream.runs_mesh(len(SEEDS)))
    # Each device's runs through the one-device program (what one device holds on the mesh).
    one = stream.runs_mesh(1)
    _, head = _device_loop(s, SEEDS[:2], EPOCHS, one)
    _, tail = _device_loop(s, SEEDS[2:] * 2, EPOCHS, one)
    per_device = jax.tree.map(lambda a, b: np.concatenate([a, b[:, :1]], axis=1), head, tail)
    # The partitioned program communicates nothing: each device runs its own runs' loop.
    mesh = stream.runs_mesh(len(SEEDS))
    fresh = stream.stack_runs([s.init(jax.random.PRNGKey(seed)) for seed in SEEDS[:2]])
    fresh = jax.device_put(fresh, NamedSharding(mesh, P("runs")))
    text = executor.sharded_program(s).lower(mesh, fresh, np.int32(1)).compile().as_text()
    assert not [op for op in ("all-gather", "all-to-all", "all-reduce", "collective-permute")
                if op in text]
    assert [np.asarray(m["learner/training"]).tolist() for m in alone] == [[0, 1]] * 3
    for k in METRICS:
        # vmapped device loops fuse differently from the host loop: float rounding, which the
        # renderer can turn into a few flipped pixels of the epoch-2 frames (after a PPO
        # update), moving the learner's summed-pixel loss by up to ~1e-3 of itself; the seeds'
        # losses differ from each other by 0.5–1 %.
        rtol = 2e-3 if k.startswith("learner/") else 2e-5
        np.testing.assert_allclose(np.asarray(together[k]).T, [m[k] for m in alone],
                                   rtol=rtol, atol=1e-6, err_msg=k)
        # The two-device program is partitioned by XLA's SPMD pipeline, the one-device program
        # not: they round apart in the last bits (docs/notes/stream.md).
        np.testing.assert_allclose(together[k], per_device[k], rtol=1e-5, atol=1e-6, err_msg=k)


@pytest.mark.slow  # three processes, each compiling the device loop at XLA's full level
def test_two_processes_of_one_device_train_what_one_process_with_two_does():
    """`benchmarks/stream_mesh.py` on XLA:CPU: the same three runs, one process holding two
    devices against two processes of one device each joined by `jax.distributed` (the second
    holding one run and a padding copy): bit-identical metrics and learner parameters."""
    from benchmarks import stream_mesh

    assert stream_mesh.main(["--cpu", "--quick", "--case", "CartPole/VAE_v0", "--runs", "3",
                             "--epochs", "1", "--no-record"]) == 0


def test_runs_trained_together_must_share_their_program(tmp_path):
    with pytest.raises(ValueError, match="differ only in their seeds"):
        run_lib.run_many([tiny(), tiny(seed=1, learner_steps=3)], [tmp_path / "a", tmp_path / "b"])
    with pytest.raises(ValueError, match="share an out directory"):
        run_lib.run_many([tiny(), tiny(seed=1)], [tmp_path / "a", tmp_path / "a"])
    with pytest.raises(ValueError, match="one out directory per config"):
        run_lib.run_many([tiny(), tiny(seed=1)], [tmp_path / "a"])


def test_a_refused_run_lets_go_of_the_directories_opened_before_it(tmp_path):
    from jaml import _rundir

    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "config.json").write_text(json.dumps(tiny(seed=7).to_dict()))
    with pytest.raises(ValueError, match="different configuration"):
        run_lib.run_many([tiny(), tiny(seed=1)], [tmp_path / "a", tmp_path / "b"], progress=False)
    for name in ("a", "b"):
        _rundir.lock(tmp_path / name).close()


@pytest.mark.slow
def test_run_many_writes_what_each_run_writes_alone_and_regroups_resumed_runs(tmp_path):
    """Seed 1 resumed at epoch 2 while seed 0 starts: they advance apart, then together."""
    configs = [tiny(seed=0), tiny(seed=1)]
    run_lib.run(configs[1], tmp_path / "many" / "1", progress=False, stop_after=2)
    summaries = run_lib.run_many(configs, [tmp_path / "many" / "0", tmp_path / "many" / "1"],
                                 progress=False)
    assert [s["status"] for s in summaries] == ["finished", "finished"]
    for summary in summaries:  # the analysis phase by part, the runs' shares of shared calls
        parts = summary["seconds_in_analysis"]
        assert {"train_set", "pi_rand", "regressor", "reconstructions",
                "records"} <= set(parts) and min(parts.values()) > 0
        assert sum(parts.values()) <= summary["seconds_by_phase"]["analysis"]
    for seed, config in enumerate(configs):
        run_lib.run(config, tmp_path / "alone" / str(seed), progress=False)
        for name in ("metrics.jsonl", "history.jsonl"):
            many = (tmp_path / "many" / str(seed) / name).read_text().splitlines()
            single = (tmp_path / "alone" / str(seed) / name).read_text().splitlines()
            assert len(many) == len(single), name
            for a, b in zip(many, single, strict=True):
                a, b = json.loads(a), json.loads(b)
                np.testing.assert_allclose(_numbers(a), _numbers(b), rtol=1e-4, atol=1e-5)


def _numbers(record) -> list[float]:
    """Every number in a JSON record, in order (NaN kept)."""
    if isinstance(record, dict):
        return [x for v in record.values() for x in _numbers(v)]
    if isinstance(record, list):
        return [x for v in record for x in _numbers(v)]
    return [float(record)] if isinstance(record, int | float) else []


def test_due_runs_are_analysed_in_one_call_per_device():
    """`due_by_device` hands each device its due runs' states, taken from its own shard."""
    from typing import NamedTuple

    class State(NamedTuple):  # the two things `due_by_device` reads of a StreamState
        epoch: jax.Array
        replay: jax.Array

    runs = State(np.arange(4, dtype=np.int32), np.arange(4 * 3, dtype=np.float32).reshape(4, 3))
    mesh = stream.runs_mesh(4)
    sharded = jax.device_put(jax.tree.map(jax.numpy.asarray, runs),
                             NamedSharding(mesh, P(executor.RUNS_AXIS)))
    devices = list(mesh.devices.flat)

    def grouped(states, due):
        return [(sorted(d.id for d in s.replay.devices()), np.asarray(s.replay).tolist(),
                 [i for i, _ in members])
                for s, members in run_lib.analysis.due_by_device(states,
                                                         [(i, f"run{i}") for i in due])]

    rows = runs.replay.tolist()
    # Every run due: one group per device, each its own shard (runs 0, 1 and 2, 3).
    assert grouped(sharded, range(4)) == [([devices[0].id], rows[:2], [0, 1]),
                                          ([devices[1].id], rows[2:], [2, 3])]
    # Run 3 stopped: device 1's group is run 2 alone, gathered from device 1's shard (its row 0).
    assert grouped(sharded, [0, 1, 2]) == [([devices[0].id], rows[:2], [0, 1]),
                                           ([devices[1].id], rows[2:3], [2])]
    # Replicated states (what trimming a padded stack leaves): the first device takes them all.
    replicated = jax.tree.map(lambda x: x[:3], sharded)
    assert grouped(replicated, [0, 2]) == [([devices[0].id], [rows[0], rows[2]], [0, 2])]
    # One device: one group, as the single-device path always had.
    assert grouped(jax.tree.map(jax.numpy.asarray, runs), [1, 2]) == [
        ([devices[0].id], rows[1:3], [1, 2])]


@pytest.mark.slow
def test_runs_split_across_devices_are_analysed_per_device_as_alone(tmp_path, monkeypatch):
    """Four runs on two devices (the device loop, as on GPUs): one `evaluate_runs` call per
    device and analysis, and every run's records as it writes them alone (its own seed too)."""
    import functools

    calls = []
    evaluate_runs = run_lib.analysis.evaluate_runs

    def spy(stream_, states, *keys, **options):
        calls.append((int(states.epoch.shape[0]), sorted(d.id for d in states.epoch.devices())))
        return evaluate_runs(stream_, states, *keys, **options)

    monkeypatch.setattr(run_lib.analysis, "evaluate_runs", spy)
    monkeypatch.setattr(run_lib, "run_stacked_epochs",
                        functools.partial(run_lib.run_stacked_epochs, host_loop=False))
    configs = [dataclasses.replace(small(), seed=s) for s in range(4)]
    run_lib.run_many(configs, [tmp_path / "many" / str(s) for s in range(4)], progress=False)
    run = stream.resolve(configs[0], 4, "cpu")
    analyses = len(run_lib.analysis_epochs(run.fill_epochs, run.epochs, run.eval.every))
    assert calls == [(2, [0]), (2, [1])] * analyses
    for seed in (0, 2):  # the first run of each device
        run_lib.run(configs[seed], tmp_path / "alone" / str(seed), progress=False)
        many = (tmp_path / "many" / str(seed) / "history.jsonl").read_text().splitlines()
        single = (tmp_path / "alone" / str(seed) / "history.jsonl").read_text().splitlines()
        assert len(many) == len(single) == 2 * analyses
        for a, b in zip(many, single, strict=True):
            a, b = json.loads(a), json.loads(b)
            assert a["run"] == b["run"] == seed
            np.testing.assert_allclose(_numbers(a), _numbers(b), rtol=1e-4, atol=1e-5)


# One process of `run_many` over two joined by `jax.distributed` (argv: coordinator, process
# id, out root, and `stop_after` or "-"): each opens and writes the runs it holds; prints each
# run's status and the epoch it resumed from.
_PROCESS = """
import json, sys
import jax
jax.distributed.initialize(sys.argv[1], 2, int(sys.argv[2]))
jax.config.update("jax_threefry_partitionable", False)  # this module's random bits
from jaml.stream import run as run_lib
from tests.stream.test_loop import tiny
stop_after = None if sys.argv[4] == "-" else int(sys.argv[4])
summaries = run_lib.run_many([tiny(seed=s) for s in range(3)],
                             [f"{sys.argv[3]}/{s}" for s in range(3)], progress=False,
                             stop_after=stop_after)
print(json.dumps([None if s is None else [s["status"], s["resumed_from"]] for s in summaries]))
"""


def _two_processes(out: Path, stop_after: int | None) -> list:
    """`_PROCESS` run by two processes of one CPU device each; what each printed."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "JAX_PLATFORMS": "cpu",
           "XLA_FLAGS": "--xla_force_host_platform_device_count=1"}
    procs = [subprocess.Popen([sys.executable, "-c", _PROCESS, f"127.0.0.1:{port}", str(i),
                               str(out), "-" if stop_after is None else str(stop_after)],
                              cwd=root, env=env, text=True, stdout=subprocess.PIPE)
             for i in range(2)]
    outs = [p.communicate()[0].strip().splitlines()[-1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0]
    return [json.loads(o) for o in outs]


@pytest.mark.slow  # four processes compiling the loop and the analysis, and this one
def test_two_processes_write_and_resume_the_run_directories_they_hold(tmp_path):
    """Three runs over two processes of one CPU device each (`run_many`, the host loop): the
    first holds runs 0 and 1, the second run 2; each writes only its own directories. Stopped
    after 3 epochs (between the analyses at 2 and 4) and resumed by two new processes, their
    records are those of the three runs trained through in one process."""
    assert _two_processes(tmp_path / "two", stop_after=3) == [
        [["interrupted", None]] * 2 + [None], [None, None, ["interrupted", None]]]
    assert _two_processes(tmp_path / "two", stop_after=None) == [
        [["finished", 3]] * 2 + [None], [None, None, ["finished", 3]]]
    run_lib.run_many([tiny(seed=s) for s in range(3)], [tmp_path / "one" / str(s)
                                                        for s in range(3)], progress=False)
    for seed in range(3):
        for name in ("metrics.jsonl", "history.jsonl"):
            two = (tmp_path / "two" / str(seed) / name).read_text().splitlines()
            one = (tmp_path / "one" / str(seed) / name).read_text().splitlines()
            assert len(two) == len(one) > 0, name
            for a, b in zip(two, one, strict=True):
                np.testing.assert_allclose(_numbers(json.loads(a)), _numbers(json.loads(b)),
                                           rtol=1e-4, atol=1e-5, err_msg=name)
