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
    frames, wall, cpu = pybullet_envs.run_block(scene, actions)
    assert frames == 6 and wall > 0 and cpu > 0
    # The reference's observation: float CHW in [0, 1], from a call that computed the mask.
    obs = scene.frame()
    assert obs.shape == (3, 64, 64) and obs.dtype == np.float64
    assert obs.min() >= 0.0 and obs.max() <= 1.0
    scene.lean, scene.flags = True, scene.pb.ER_NO_SEGMENTATION_MASK
    frame = scene.frame()
    assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8
    np.testing.assert_allclose(obs, frame.transpose(2, 0, 1) / 255.0)
    # The camera sees the robot (and for the walkers the floor): not a blank white frame.
    assert (frame < 250).any(-1).mean() > 0.01


def test_rearrange_frame_shows_the_tray_and_the_four_coloured_objects():
    scene = pybullet_envs.RearrangeGeom(seed=1, lean=True)
    scene.reset()
    for a in np.random.default_rng(0).uniform(-1, 1, (3, 2)):
        scene.step(a)
    frame = scene.frame().astype(int)
    r, g, b = frame[..., 0], frame[..., 1], frame[..., 2]
    # The top-down camera sees the tray's wood texture almost everywhere (no white background,
    # no black floor showing through it) ...
    wood = (r > 120) & (r > b + 30)
    assert wood.mean() > 0.4
    assert ((frame > 250).all(-1)).mean() < 0.01
    # ... and version 0's objects in their colours: blue cylinder, magenta cube, red sphere,
    # yellow sphere1, each covering some pixels; the objects stay inside the workspace.
    colours = {"blue": (b > 150) & (r < 80) & (g < 80), "magenta": (r > 150) & (b > 150) & (g < 80),
               "red": (r > 150) & (g < 60) & (b < 60), "yellow": (r > 150) & (g > 150) & (b < 60)}
    for name, mask in colours.items():
        assert mask.sum() >= 4, name
    assert scene._in_workspace()


def test_franka_scene_is_torque_driven_with_gravity_compensation_and_seen_by_the_camera():
    scene = pybullet_envs.SCENES["RearrangeGeom:arm=franka"](seed=0, lean=True)
    p = scene.p
    assert scene.action_size == 7 and len(scene.joints) == 7
    assert all(p.getJointInfo(scene.arm, j)[2] == p.JOINT_REVOLUTE for j in scene.joints)
    # The base at (-0.7, 0, 0): joint 1's frame is 0.333 m above it.
    link1 = p.getLinkState(scene.arm, scene.joints[0], computeForwardKinematics=True)[4]
    assert link1 == pytest.approx((-0.7, 0, 0.333), abs=1e-6)
    # jaml's Franka constants (envs_mjx/domains/rearrange.py, assets/rearrange_franka.xml).
    from envs_mjx.domains import rearrange
    assert pybullet_envs.FRANKA_TORQUE == rearrange.FRANKA_TORQUE
    assert pybullet_envs.FRANKA_REST == rearrange.FRANKA_REST
    scene.reset()

    def pose(q):
        for j, qj in zip(scene.joints, q, strict=True):
            p.resetJointState(scene.arm, j, qj, 0)

    def moved(q):
        return np.array([s[0] for s in p.getJointStates(scene.arm, scene.joints)]) - q

    free = (0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8)  # the hand 0.5 m up, clear of everything
    pose(free)
    scene.step(np.zeros(7))  # 4 Bullet steps: compensation holds the arm ...
    held = np.abs(moved(free)).max()
    pose(free)
    for _ in range(4):  # ... which sags without it
        p.setJointMotorControlArray(scene.arm, scene.joints, p.TORQUE_CONTROL, forces=[0.0] * 7)
        p.stepSimulation()
    assert held < 0.1 * np.abs(moved(free)).max()
    pose(free)
    scene.step(np.full(7, 0.5))  # a torque action moves every joint
    assert (np.abs(moved(free)) > 1e-3).all()
    # The 64x64 frame: the hand reaching into the tray changes it (the camera sees the arm).
    frame_free = scene.frame()
    assert frame_free.shape == (64, 64, 3) and frame_free.dtype == np.uint8
    pose((0.0, 0.6, 0.0, -1.6, 0.0, 2.2, 0.8))  # the hand at ~(0, 0, 0.28)
    frame_reach = scene.frame()
    assert (np.abs(frame_reach.astype(int) - frame_free).max(-1) > 30).sum() > 100


def test_one_env_is_always_set_against_one_pybullet_process():
    pairs = envs_throughput.side_by_side_pairs
    assert pairs([1], 2) == [(1, 1)]
    assert pairs([1, 64, 256], 2) == [(256, 2), (1, 1)]
    assert pairs([256], 1) == [(256, 1)]


def test_env_specs_pick_the_peer_scene_or_say_why_not(capsys):
    key = pybullet_envs.scene_key
    assert key("RearrangeGeom") == key("RearrangeGeom:physics=c") == "RearrangeGeom"
    assert key("RearrangeGeom:arm=reacher,max_contacts=null") == "RearrangeGeom"
    assert key("RearrangeGeom:arm=franka") == "RearrangeGeom:arm=franka"
    assert key("RearrangeGeom:physics=c,arm=franka") == "RearrangeGeom:arm=franka"
    assert set(pybullet_envs.SCENE_NOTES) == set(pybullet_envs.SCENES)
    for spec in ("RearrangeGeom:version=3", "RearrangeGeom:arm=ur5", "RearrangeYCB:arm=franka"):
        with pytest.raises(ValueError, match="PyBullet"):
            key(spec)
    # envs_throughput skips the side-by-side rows with the reason, not another scene.
    assert envs_throughput._has_peer("RearrangeGeom:arm=franka,physics=c")
    assert not envs_throughput._has_peer("RearrangeGeom:version=3")
    assert "cannot honour" in capsys.readouterr().out


def test_alternated_blocks_give_a_row_with_the_measured_ratio_and_the_quoted_anchor_apart():
    # Two real PyBullet workers against a stand-in for jaml's compiled rollout (the real one
    # compiles for ~15 s on two cores; the slow test below runs it).
    fn = jax.jit(lambda x: jnp.cumsum(x) * 2.0)
    x = jnp.ones(4096)
    fn(x).block_until_ready()
    with pybullet_envs.PeerPool("CartPole", processes=2, episodes=2, steps=3) as pool:
        t = envs_throughput.alternate(lambda: fn(x), pool, rounds=3)
    jaml_t, pb_t = t["jaml_s"], t["pybullet_s"]
    assert pool.frames_per_block == 12 and len(jaml_t) == len(pb_t) == 3
    assert len(t["jaml_cpu_s"]) == len(t["pybullet_cpu_s"]) == 3
    row = envs_throughput.side_by_side_row("CartPole", 4, 3, 12, jaml_t, 12, pb_t,
                                           compile_s=0.0, setup_s=pool.setup_s, processes=2,
                                           jaml_cpu=t["jaml_cpu_s"],
                                           pybullet_cpu=t["pybullet_cpu_s"])
    assert row["case"] == "CartPole/pixels_vs_pybullet/b4"
    assert row["jaml_frames_per_s"] == pytest.approx(12 / np.median(jaml_t))
    assert row["pybullet_frames_per_s"] == pytest.approx(12 / np.median(pb_t))
    assert row["pybullet_frames_per_s"] > 0
    assert row["ratio_jaml_over_pybullet"] == pytest.approx(
        row["jaml_frames_per_s"] / row["pybullet_frames_per_s"])
    per_round = [(12 / j) / (12 / p) for j, p in zip(jaml_t, pb_t, strict=True)]
    assert (row["ratio_min"], row["ratio_max"]) == pytest.approx((min(per_round), max(per_round)))
    assert row["pybullet_frames_per_cpu_s"] == pytest.approx(12 / np.median(t["pybullet_cpu_s"]))
    # The quoted anchor has its own labelled columns; nothing measured is derived from it.
    assert row["quoted_pybullet_1core_frames_per_s"] == 698.0
    assert "perf_anchors" in row["quoted_source"]
    assert envs_throughput.side_by_side_row(
        "Ant", 4, 3, 12, jaml_t, 12, pb_t, compile_s=0.0, setup_s=0.0, processes=2
    )["quoted_pybullet_1core_frames_per_s"] == ""


def test_fresh_processes_give_the_median_process_with_every_process_beside_it(monkeypatch):
    """`--fresh-processes 3`: three child processes, each its own side-by-side row; the row is
    the middle ratio's, the extremes span them all, one of them slow (as one in eight was)."""
    children = [{"ratio_jaml_over_pybullet": r, "jaml_frames_per_s": j, "ratio_min": lo,
                 "ratio_max": hi, "rounds": 7, "case": "CartPole/pixels_vs_pybullet/b256"}
                for r, j, lo, hi in ((2.5, 23_000.0, 2.2, 2.6), (1.07, 9_900.0, 1.0, 1.1),
                                     (2.52, 23_100.0, 2.4, 2.7))]
    calls = []

    def run(cmd, **kwargs):
        calls.append(json.loads(cmd[cmd.index("--side-by-side-child") + 1]))
        return type("Done", (), {"returncode": 0,
                                 "stdout": "warp missing\n" + json.dumps(children[len(calls) - 1])})

    monkeypatch.setattr(harness.subprocess, "run", run)
    row = envs_throughput.bench_vs_pybullet_in_processes("CartPole", 256, 10, 7, 2, 3)
    assert calls == [["CartPole", 256, 10, 7, 2]] * 3
    assert row["ratio_jaml_over_pybullet"] == 2.5 and row["jaml_frames_per_s"] == 23_000.0
    assert row["ratio_by_process"] == [2.5, 1.07, 2.52]
    assert row["jaml_frames_per_s_by_process"] == [23_000, 9_900, 23_100]
    assert (row["ratio_min"], row["ratio_max"], row["rounds"]) == (1.0, 2.7, 21)
    assert row["fresh_processes"] == 3
    monkeypatch.setattr(harness.subprocess, "run", lambda cmd, **kw: type(
        "Failed", (), {"returncode": 1, "stdout": "", "stderr": "Traceback\nValueError: no"}))
    with pytest.raises(RuntimeError, match=r"\(CartPole, batch 256\): its process exited with "
                                            r"status 1: ValueError: no"):
        envs_throughput.bench_vs_pybullet_in_processes("CartPole", 256, 10, 7, 2, 3)


@pytest.mark.slow
def test_envs_throughput_records_a_side_by_side_row_for_cartpole(tmp_path, monkeypatch):
    env = {"device": "cpu:cpu", "device_count": 1, "cpu": "x", "cpu_cores": 2, "python": "3",
           "versions": {"jax": "0"}, "commit": "abc1234", "date": "2026-01-01T00:00:00+00:00"}
    monkeypatch.setattr(harness, "RESULTS_JSONL", tmp_path / "results.jsonl")
    monkeypatch.setattr(harness, "RESULTS_MD", tmp_path / "RESULTS.md")
    monkeypatch.setattr(harness, "environment", lambda: dict(env))
    row, single, gym = envs_throughput.main(["--envs", "CartPole", "--parts", "pybullet",
                                             "--pixel-batches", "1", "2", "--rounds", "2",
                                             "--processes", "2", "--single-env-steps", "7",
                                             "--gym"])
    assert row["case"] == "CartPole/pixels_vs_pybullet/b2" and row["steps"] == 10
    # One env against one process, over longer blocks than the batched pair's.
    assert single["case"] == "CartPole/pixels_vs_pybullet/b1" and single["steps"] == 7
    # The same one env stepped through the Gymnasium interface, one call per step.
    assert gym["case"] == "CartPole/gym_vs_pybullet/b1" and gym["steps"] == 7
    assert gym["jaml_frames_per_s"] > 0 and gym["rounds"] == 2
    assert row["jaml_frames_per_s"] > 0 and row["pybullet_frames_per_s"] > 0
    assert row["ratio_jaml_over_pybullet"] == pytest.approx(
        row["jaml_frames_per_s"] / row["pybullet_frames_per_s"])
    recorded, _, _ = [json.loads(line)
                   for line in (tmp_path / "results.jsonl").read_text().splitlines()]
    assert recorded["benchmark"] == "envs_vs_pybullet"
    assert recorded["ratio_jaml_over_pybullet"] == row["ratio_jaml_over_pybullet"]
    assert "quoted_pybullet_1core_frames_per_s" in (tmp_path / "RESULTS.md").read_text()


@pytest.mark.slow  # the benchmark's plumbing, on two compiles
def test_envs_throughput_records_the_compiler_options_pair(tmp_path, monkeypatch):
    """`--parts options`: one row per env, both programs timed in the same rounds, the ratio the
    two medians', which one jaml uses, recorded under its own benchmark name."""
    env = {"device": "cpu:cpu", "device_count": 1, "cpu": "x", "cpu_cores": 2, "python": "3",
           "versions": {"jax": "0"}, "commit": "abc1234", "date": "2026-01-01T00:00:00+00:00"}
    monkeypatch.setattr(harness, "RESULTS_JSONL", tmp_path / "results.jsonl")
    monkeypatch.setattr(harness, "RESULTS_MD", tmp_path / "RESULTS.md")
    monkeypatch.setattr(harness, "environment", lambda: dict(env))
    (row,) = envs_throughput.main(["--envs", "CartPole", "--parts", "options", "--quick",
                                   "--rounds", "3", "--options-batch", "2"])
    assert row["case"] == "CartPole/compiler_options/b2" and row["rounds"] == 3
    assert json.loads(row["options"]) == {"xla_cpu_use_fusion_emitters": False}
    assert row["jaml_uses"] == "xla_default"  # the cart-pole's tree is 2 bodies deep
    # batch x steps x the env's substeps per step, over each side's median block.
    assert row["ratio_older_over_default"] == pytest.approx(
        row["older_substeps_per_s"] / row["default_substeps_per_s"])
    (recorded,) = [json.loads(line)
                   for line in (tmp_path / "results.jsonl").read_text().splitlines()]
    assert recorded["benchmark"] == "env_compiler_options"
    assert recorded["ratio_older_over_default"] == row["ratio_older_over_default"]


def test_the_render_part_times_the_frames_env_step_draws():
    """`--parts render` times the env's own pixels function: on reset states it returns exactly
    the frames the states carry (drawn by reset through the same function)."""
    env = envs_throughput.make_env("CartPole", pixels="required")
    states = envs_throughput._reset(env, 2)
    frames = envs_throughput._render_fn(env)(states.pipeline_state, states.info)
    assert frames.shape == (2, 64, 64, 3) and frames.dtype == np.uint8
    np.testing.assert_array_equal(np.asarray(frames), np.asarray(states.pixels))
    assert len(np.unique(np.asarray(frames))) > 2  # a drawn scene, not a blank frame


@pytest.mark.slow  # the peer's frame count, on a compiled rollout
def test_the_physics_part_counts_frames_as_actions_not_substeps():
    """A physics row's frames/s is batch × actions over the time, its substeps/s that times the
    env's substeps per action (4 on HalfCheetah, 8 on the Rearrange scenes): converting one
    into the other by hand with the wrong count halved a GPU split's physics share once."""
    r = envs_throughput.bench_env_physics("HalfCheetah", 2, 3, 2)
    assert r["substeps_per_frame"] == envs_throughput.make_env("HalfCheetah").n_frames == 4
    assert r["frames_per_s"] == pytest.approx(2 * 3 / r["median_s"])
    assert r["substeps_per_s"] == pytest.approx(r["frames_per_s"] * 4)
