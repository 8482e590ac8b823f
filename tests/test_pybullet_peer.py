"""The PyBullet peer (benchmarks/peers/pybullet_envs.py) and the side-by-side row it feeds."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("pybullet", reason="pybullet (the dev extra) is not installed")

from benchmarks import envs_throughput, harness
from benchmarks.peers import pybullet_envs


@pytest.mark.parametrize("name", sorted(pybullet_envs.SCENES))
def test_each_scene_steps_and_frames_its_robot(name):
    scene = pybullet_envs.SCENES[name](seed=0)
    actions = np.random.default_rng(0).uniform(-1, 1, (2, 3, scene.action_size))
    assert pybullet_envs.run_block(scene, actions) == 6
    frame = scene.frame()
    assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8
    # The camera sees the robot (and for the walkers the floor): not a blank white frame.
    assert (frame < 250).any(-1).mean() > 0.01


def test_alternated_blocks_give_a_row_with_the_measured_ratio_and_the_quoted_anchor_apart():
    # Two real PyBullet workers against a stand-in for jaml's compiled rollout (the real one
    # compiles for ~15 s on two cores; the slow test below runs it).
    fn = jax.jit(lambda x: jnp.cumsum(x) * 2.0)
    x = jnp.ones(4096)
    fn(x).block_until_ready()
    with pybullet_envs.PeerPool("CartPole", processes=2, episodes=2, steps=3) as pool:
        jaml_t, pb_t = envs_throughput.alternate(lambda: fn(x), pool, rounds=3)
    assert pool.frames_per_block == 12 and len(jaml_t) == len(pb_t) == 3
    row = envs_throughput.side_by_side_row("CartPole", 4, 3, 12, jaml_t, 12, pb_t,
                                           compile_s=0.0, setup_s=pool.setup_s, processes=2)
    assert row["case"] == "CartPole/pixels_vs_pybullet/b4"
    assert row["jaml_frames_per_s"] == pytest.approx(12 / np.median(jaml_t))
    assert row["pybullet_frames_per_s"] == pytest.approx(12 / np.median(pb_t))
    assert row["pybullet_frames_per_s"] > 0
    assert row["ratio_jaml_over_pybullet"] == pytest.approx(
        row["jaml_frames_per_s"] / row["pybullet_frames_per_s"])
    per_round = [(12 / j) / (12 / p) for j, p in zip(jaml_t, pb_t, strict=True)]
    assert (row["ratio_min"], row["ratio_max"]) == pytest.approx((min(per_round), max(per_round)))
    # The quoted anchor has its own labelled columns; nothing measured is derived from it.
    assert row["quoted_pybullet_1core_frames_per_s"] == 698.0
    assert "perf_anchors" in row["quoted_source"]
    assert envs_throughput.side_by_side_row(
        "Ant", 4, 3, 12, jaml_t, 12, pb_t, compile_s=0.0, setup_s=0.0, processes=2
    )["quoted_pybullet_1core_frames_per_s"] == ""


@pytest.mark.slow
def test_envs_throughput_records_a_side_by_side_row_for_cartpole(tmp_path, monkeypatch):
    env = {"device": "cpu:cpu", "device_count": 1, "cpu": "x", "cpu_cores": 2, "python": "3",
           "versions": {"jax": "0"}, "commit": "abc1234", "date": "2026-01-01T00:00:00+00:00"}
    monkeypatch.setattr(harness, "RESULTS_JSONL", tmp_path / "results.jsonl")
    monkeypatch.setattr(harness, "RESULTS_MD", tmp_path / "RESULTS.md")
    monkeypatch.setattr(harness, "environment", lambda: dict(env))
    (row,) = envs_throughput.main(["--envs", "CartPole", "--parts", "pybullet",
                                   "--pixel-batches", "2", "--rounds", "2", "--processes", "2"])
    assert row["case"] == "CartPole/pixels_vs_pybullet/b2"
    assert row["jaml_frames_per_s"] > 0 and row["pybullet_frames_per_s"] > 0
    assert row["ratio_jaml_over_pybullet"] == pytest.approx(
        row["jaml_frames_per_s"] / row["pybullet_frames_per_s"])
    (recorded,) = [json.loads(line)
                   for line in (tmp_path / "results.jsonl").read_text().splitlines()]
    assert recorded["benchmark"] == "envs_vs_pybullet"
    assert recorded["ratio_jaml_over_pybullet"] == row["ratio_jaml_over_pybullet"]
    assert "quoted_pybullet_1core_frames_per_s" in (tmp_path / "RESULTS.md").read_text()
