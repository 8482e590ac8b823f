"""The Fig. 2 report: per-seed histories → mean ± 90 % confidence half-width per dimension."""

import json
import math

import numpy as np

from jaml.evaluation import history_records
from jaml.experiments import fig2

NAMES = ["theta", "theta_dot", "x", "x_dot"]


def _write_run(path, learner, seed, errors_at_end):
    path.mkdir(parents=True)
    config = {k: 1 for k in fig2.SCALE}
    (path / "config.json").write_text(json.dumps(config))
    records = history_records(10, learner, {"pi_rand": [0.9] * 4}, NAMES, run=seed)
    records += history_records(20, learner, {"pi_rand": errors_at_end}, NAMES, run=seed)
    (path / "history.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))


def test_report_averages_seeds_with_a_t_interval(tmp_path):
    seeds = {0: [0.1, 0.5, 0.2, 0.7], 1: [0.2, 0.6, 0.2, 0.9], 2: [0.3, 0.4, 0.2, 0.8]}
    for seed, errors in seeds.items():
        _write_run(tmp_path / "CartPole" / "PRED" / f"seed_{seed}", "PRED", seed, errors)
    _write_run(tmp_path / "CartPole" / "VAE_rpl" / "seed_0", "VAE_rpl", 0, [0.4, 0.8, 0.1, 1.0])

    text = fig2.report(tmp_path, ["CartPole", "InvertedPendulum"], ["PRED", "VAE_rpl", "DSA"])

    rows = {line.split(" | ")[0].strip("| "): line.split(" | ")
            for line in text.splitlines() if line.startswith("| PRED") or
            line.startswith("| VAE_rpl")}
    theta = np.array([0.1, 0.2, 0.3])
    half = 2.9199856 * theta.std(ddof=1) / math.sqrt(3)  # t(0.95, 2 dof) · s / √n
    assert rows["PRED"][2] == f"{theta.mean():.3f} ± {half:.3f}"
    assert rows["PRED"][4] == "0.200 ± 0.000"  # x: the same in every seed
    velocity = [np.mean([e[1], e[3]]) for e in seeds.values()]  # per seed, then over seeds
    assert rows["PRED"][7].startswith(f"{np.mean(velocity):.3f} ± ")
    assert rows["PRED"][-2:] == ["20", "3 |"]  # the last analysed epoch, seeds counted
    assert rows["VAE_rpl"][2] == "0.400" and rows["VAE_rpl"][-1] == "1 |"  # one seed: no ±
    assert "InvertedPendulum" not in text  # no runs, no section
    assert (tmp_path / "fig2.md").read_text() == text
    assert (tmp_path / "CartPole_alignment.png").stat().st_size > 0


def test_groups_come_from_the_domains_metadata_not_the_names():
    """vx/vy/vz are velocities and the foot flags contacts (a name rule counted both as
    position); the incline's scene parameters are in no group."""
    cheetah = fig2.ld_groups("HalfCheetah")
    assert {"vx", "vy", "vz", "bthigh_vel"} <= set(cheetah["velocity"])
    assert {"z_rel", "roll", "bthigh_pos"} <= set(cheetah["position"])
    assert len(cheetah["contact"]) == 6 and all(n.endswith("_contact") for n in cheetah["contact"])
    assert fig2.ld_groups("CartPole") == {"position": ["theta", "x"],
                                          "velocity": ["theta_dot", "x_dot"]}
    assert fig2.ld_groups("MeshOnIncline") == {"position": ["position"],
                                               "velocity": ["velocity"]}
