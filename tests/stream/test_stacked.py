"""Stacked runs: R seeds trained as one program must compute what each seed computes alone.

The reference is the host loop of one run (jitted `act` and `learn_step` per call, the CPU
path): the device loop (`fori_loop` over whole epochs, the GPU/TPU path) over R vmapped runs,
with the runs split across two devices (the two XLA:CPU devices of
tests/conftest.py), must reproduce every run's PPO and learner losses.
"""

import dataclasses
import json

import jax
import numpy as np
import pytest

from jaml import stream
from jaml.stream import executor
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


@pytest.mark.slow  # two compiles of the device loop; the one-device stacked tests stay default
def test_runs_split_across_two_devices_match_each_run_alone():
    s = stream.build(small())
    alone = []
    for seed in SEEDS:
        _, metrics = stream.run_epochs(s, s.init(jax.random.PRNGKey(seed)), EPOCHS)
        alone.append(metrics)
    # The CPU's host loop compiled its learner step once (with the learner's compiler options,
    # `executor._learner_jit`) and reused it for every step of every seed.
    assert executor._learner_jit(s, executor._learn_step_runs)._cache_size() == 1
    # Three runs on two devices: one device steps two runs, the other one run and a padding copy.
    assert jax.device_count() == 2, "tests/conftest.py asks XLA for two CPU devices"
    mesh = stream.runs_mesh(len(SEEDS))
    states = stream.stack_runs([s.init(jax.random.PRNGKey(seed)) for seed in SEEDS])
    # One epoch per call: the first call compiles each device's program, the second must reuse
    # them (the states it returns have the types it was given).
    states, first = stream.run_stacked_epochs(s, states, 1, mesh=mesh, host_loop=False)
    states, second = stream.run_stacked_epochs(s, states, EPOCHS - 1, mesh=mesh,
                                               host_loop=False)
    executables = [k for k in s.programs if k[0] is executor._block and len(k) == 3]
    assert sorted(device.id for _, device, _ in executables) == [0, 1], (
        "one program per device, reused")
    together = jax.tree.map(lambda a, b: np.concatenate([a, b]), first, second)
    assert mesh.size == 2 and states.epoch.tolist() == [EPOCHS] * len(SEEDS)
    assert [np.asarray(m["learner/training"]).tolist() for m in alone] == [[0, 1]] * 3
    for k in METRICS:
        # vmapped per-device programs fuse differently from the host loop: float rounding, which
        # the renderer can turn into a few flipped pixels of the epoch-2 frames (after a PPO
        # update), moving the learner's summed-pixel loss by up to ~1e-3 of itself; the seeds'
        # losses differ from each other by 0.5–1 %.
        rtol = 2e-3 if k.startswith("learner/") else 2e-5
        np.testing.assert_allclose(np.asarray(together[k]).T, [m[k] for m in alone],
                                   rtol=rtol, atol=1e-6, err_msg=k)


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

    from jax.sharding import NamedSharding
    from jax.sharding import PartitionSpec as P

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
                for s, members in executor.due_by_device(states,
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
