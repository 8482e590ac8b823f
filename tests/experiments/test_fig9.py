"""The Fig. 9 report and its pieces: per-seed histories → final means, Welch intervals, figure."""

import json
import math

import jax
import numpy as np
import pytest
from scipy import stats

import envs_mjx
from jaml.evaluation import history_records
from jaml.experiments import fig9
from jaml.relations.transfer import LatentLayout

NAMES = ["texture_id", "object_id", "theta", "position", "velocity"]


def _write_run(path, method, seed, position_at_end, distortion_at_end):
    path.mkdir(parents=True)
    records = []
    for step, pos, dist in ((100, 0.3, 9.0), (200, position_at_end, distortion_at_end)):
        errors = {"pi_rand": [0.1, 0.0, 0.2, pos, 0.4], "pi_curr": [0.5] * 5}
        records += history_records(step, "PRED", errors, NAMES, dist, run=seed)
    (path / "history.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))


def test_welch_interval_matches_a_hand_computation():
    a, b = [1.0, 2.0, 3.0], [2.0, 4.0, 6.0, 8.0]
    diff, low, high = fig9.welch_interval(a, b)
    va, vb = np.var(a, ddof=1) / 3, np.var(b, ddof=1) / 4  # 1/3, 20/12
    dof = (va + vb) ** 2 / (va**2 / 2 + vb**2 / 3)
    assert dof == pytest.approx(4.0755, abs=1e-4)  # (1/3 + 5/3)² / ((1/3)²/2 + (5/3)²/3)
    half = stats.t.ppf(0.95, dof) * math.sqrt(va + vb)
    assert diff == -3.0
    assert (low, high) == pytest.approx((-3.0 - half, -3.0 + half), abs=2e-3)


def test_report_tables_final_means_and_differences_from_pred(tmp_path):
    for seed, (pos, dist) in enumerate([(0.10, 1.0), (0.12, 1.2), (0.14, 1.4)]):
        _write_run(tmp_path / "PRED+AML_trnsv" / f"seed_{seed}", "PRED+AML_trnsv", seed, pos, dist)
    for seed, (pos, dist) in enumerate([(0.20, 2.0), (0.22, 2.2), (0.24, 2.4)]):
        _write_run(tmp_path / "PRED" / f"seed_{seed}", "PRED", seed, pos, dist)

    text = fig9.report(tmp_path, list(fig9.METHODS))

    table = [line.split(" | ") for line in text.splitlines() if line.startswith("| PRED")]
    rows = {cells[0].strip("| "): cells for cells in table if len(cells) == 6}
    half = 2.9199856 * 0.02 / math.sqrt(3)  # t(0.95, 2 dof) · s / √n, s = 0.02
    assert rows["PRED+AML_trnsv"][1:4] == ["3", "200", f"0.1200 ± {half:.4f}"]
    assert rows["PRED"][3] == f"0.2200 ± {half:.4f}"
    assert rows["PRED"][5].startswith("2.2000 ± ")
    diff_row = next(line for line in text.splitlines()
                    if line.startswith("| PRED+AML_trnsv | -") or
                    line.startswith("| PRED+AML_trnsv | +"))
    assert diff_row.split(" | ")[1].startswith("-0.1000 [")
    assert "VAE_rpl" not in text and "PRED+AML_syz" not in text  # no runs, no rows
    assert (tmp_path / "fig9.md").read_text() == text
    assert (tmp_path / "fig9.png").stat().st_size > 0


def test_the_figure_draws_each_methods_seed_mean_and_90_percent_band(tmp_path):
    """Per panel and step: the mean over seeds and mean ± t(0.95, n−1)·s/√n, by hand."""
    ends = [(0.10, 1.0), (0.12, 1.2), (0.17, 1.9)]
    for seed, (pos, dist) in enumerate(ends):
        _write_run(tmp_path / "PRED" / f"seed_{seed}", "PRED", seed, pos, dist)
    fig = fig9.plot(fig9.collect(tmp_path, ["PRED"]), tmp_path / "fig9.png")
    t = 2.9199856  # t(0.95, 2 dof)
    for ax, at_100, at_200 in ((fig.axes[0], 0.3, [e[0] for e in ends]),
                               (fig.axes[1], 9.0, [e[1] for e in ends])):
        line, = ax.lines
        np.testing.assert_allclose(line.get_xdata(), [100, 200])
        np.testing.assert_allclose(line.get_ydata(), [at_100, np.mean(at_200)], rtol=1e-6)
        half = t * np.std(at_200, ddof=1) / math.sqrt(3)
        band = ax.collections[0].get_paths()[0].vertices
        at_end = band[np.isclose(band[:, 0], 200), 1]
        np.testing.assert_allclose([at_end.min(), at_end.max()],
                                   [np.mean(at_200) - half, np.mean(at_200) + half], rtol=1e-5)


def test_the_layout_reads_every_relation_coordinate_from_the_incline_pred():
    """The experiment's layout against the source's own coordinate names and the latent and
    action sizes of the PRED the experiment builds (`penalty_for`'s): θ in the static part, s
    and v in each step's dynamic part, the action of the first step."""
    from jaml import sources
    from jaml.stream.loop import build

    names = tuple(sources.make(fig9.SOURCE).dim_names)
    assert sorted(names) == sorted(("theta", "s0", "v0", "a0", "s1", "v1"))
    stream = build(fig9._config("PRED", 0))
    plan = LatentLayout(**fig9.LAYOUT).gather(names, stream.learner.config.penalty_dim,
                                              stream.env.action_size)
    expected = {"theta": ("z", 2, 0), "s0": ("z", 3, 0), "v0": ("z", 4, 0), "a0": ("a", 0, 0),
                "s1": ("z", 3, 1), "v1": ("z", 4, 1)}
    assert [p[:3] for p in plan] == [expected[n] for n in names]


def test_fixed_dynamics_fix_the_targets_mass_and_friction_at_every_reset():
    """`--dynamics fixed` reaches the target's envs and the source's rows: every reset draws
    the one mass and friction; an unknown name is refused."""
    config = fig9._config("PRED", 0, "fixed")
    assert config.env == fig9.TARGET and config.env_overrides == fig9._dynamics("fixed")
    env = envs_mjx.make(fig9.TARGET, **config.env_overrides, pixels="off")
    infos = [env.reset(jax.random.key(k)).info for k in range(3)]
    assert {round(float(i["mass"]), 6) for i in infos} == {0.2}  # float32
    assert {round(float(i["friction"]), 6) for i in infos} == {0.3}
    from jaml import sources  # the relations' rows: the source's env, as `learn_relations` makes it

    source_env = sources.make(fig9.SOURCE, **fig9._dynamics("fixed")).env
    infos = [source_env.reset(jax.random.key(k)).info for k in range(3)]
    assert {round(float(i["mass"]), 6) for i in infos} == {0.2}
    assert {round(float(i["friction"]), 6) for i in infos} == {0.3}
    assert fig9._config("PRED", 0).env_overrides == {}  # "drawn": the domains' own ranges
    with pytest.raises(ValueError, match=r"dynamics must be one of \['drawn', 'fixed'\]"):
        fig9._config("PRED", 0, "frozen")


def test_a_method_without_relations_neither_fits_them_nor_runs_the_pilot(tmp_path, monkeypatch):
    # A `--methods PRED` process beside the pilot once ran the pilot itself, into the pilot's
    # own run directory.
    calls = []
    monkeypatch.setattr(fig9, "learn_relations", lambda *a, **k: calls.append("relations"))
    monkeypatch.setattr(fig9, "choose_weight", lambda *a, **k: calls.append("pilot"))
    monkeypatch.setattr(fig9, "run_method",
                        lambda out, method, seeds, penalty, **k: calls.append((method, penalty)))
    monkeypatch.setattr(fig9, "SCALE", dict(fig9.SCALE))  # `train` writes the flags into it
    assert fig9.Args(out=tmp_path, methods=("PRED", "VAE_rpl")).train() is True
    assert calls == [("PRED", fig9.Penalty()), ("VAE_rpl", fig9.Penalty())]
    calls.clear()
    fig9.Args(out=tmp_path, methods=("PRED", "PRED+AML_trnsv")).train()
    assert calls[:2] == ["relations", "pilot"] and [c[0] for c in calls[2:]] == [
        "PRED", "PRED+AML_trnsv"]
    calls.clear()
    assert fig9.Args(out=tmp_path, methods=("PRED",), pilot_only=True).train() is False
    assert calls == ["relations", "pilot"]
