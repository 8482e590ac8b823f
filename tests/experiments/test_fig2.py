"""The Fig. 2 report: per-seed histories → mean ± 90 % confidence half-width per dimension."""

import dataclasses
import json
import math

import numpy as np
import pytest

from jaml import stream
from jaml.evaluation import history_records, plots
from jaml.experiments import _runs, fig2

NAMES = ["theta", "theta_dot", "x", "x_dot"]

PAPER_SIZES = _runs.Sizes().overrides()


def _write_run(path, learner, seed, errors_at_end, finished=True, learner_overrides=None,
               baseline=None, errors_at_15=None):
    """Analyses at epochs 10 (errors 0.9), 15 where `errors_at_15` is given and, when finished,
    20 of the 20 scheduled; with a constant predictor's errors `baseline` (one list, every
    analysis), as stream.run records."""
    path.mkdir(parents=True)
    config = {k: 1 for k in _runs.SIZES} | {"epochs": 20, "seed": seed,
                                          "learner_overrides": learner_overrides or {}}
    (path / "config.json").write_text(json.dumps(config))
    records = history_records(10, learner, {"pi_rand": [0.9] * 4}, NAMES, run=seed)
    if errors_at_15 is not None:
        records += history_records(15, learner, {"pi_rand": errors_at_15}, NAMES, run=seed)
    if finished:
        records += history_records(20, learner, {"pi_rand": errors_at_end}, NAMES, run=seed)
    if baseline is not None:
        records = [r | {"baseline": dict(zip(NAMES, baseline, strict=True))} for r in records]
    (path / "history.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))


def test_report_averages_seeds_with_a_t_interval(tmp_path):
    seeds = {0: [0.1, 0.5, 0.2, 0.7], 1: [0.2, 0.6, 0.2, 0.9], 2: [0.3, 0.4, 0.2, 0.8]}
    for seed, errors in seeds.items():
        _write_run(tmp_path / "CartPole" / "PRED" / f"seed_{seed}", "PRED", seed, errors)
    _write_run(tmp_path / "CartPole" / "VAE_rpl" / "seed_0", "VAE_rpl", 0, [0.4, 0.8, 0.1, 1.0])

    text = fig2.report(tmp_path, ["CartPole", "InvertedPendulum"], ["PRED", "VAE_rpl", "DSA"])

    errors_table = text[:text.index("fraction of a constant")]  # the raw table, not the next
    rows = {line.split(" | ")[0].strip("| "): line.split(" | ")
            for line in errors_table.splitlines() if line.startswith("| PRED") or
            line.startswith("| VAE_rpl")}
    theta = np.array([0.1, 0.2, 0.3])
    half = 2.9199856 * theta.std(ddof=1) / math.sqrt(3)  # t(0.95, 2 dof) · s / √n
    assert rows["PRED"][2] == f"{theta.mean():.3f} ± {half:.3f}"
    assert rows["PRED"][4] == "0.200 ± 0.000"  # x: the same in every seed
    velocity = [np.mean([e[1], e[3]]) for e in seeds.values()]  # per seed, then over seeds
    assert rows["PRED"][7].startswith(f"{np.mean(velocity):.3f} ± ")
    assert rows["PRED"][-2:] == ["20", "3 |"]  # the last analysed epoch, seeds counted
    assert rows["VAE_rpl"][2] == "0.400" and rows["VAE_rpl"][-1] == "1 |"  # one seed: no ±
    assert "## InvertedPendulum" not in text  # no runs, no section (a status row only)
    assert (tmp_path / "fig2.md").read_text() == text
    assert (tmp_path / "CartPole_alignment.png").stat().st_size > 0
    assert (tmp_path / "fig2.png").stat().st_size > 0


def test_each_domain_table_ends_with_its_ceiling_and_floor(tmp_path):
    """The constant predictor's errors (each cell's last epoch) and the true state's (each
    run's summary.json references) close the table, over every run that recorded them."""
    for variant, seed, baseline, floor in (("PRED", 0, [1.0, 2.0, 1.0, 2.0], [0.02] * 4),
                                           ("PRED", 1, [1.2, 2.2, 1.0, 2.0], [0.04] * 4),
                                           ("VAE_rpl", 0, [1.4, 2.4, 1.0, 2.0], None)):
        run = tmp_path / "CartPole" / variant / f"seed_{seed}"
        _write_run(run, variant, seed, [0.3] * 4, baseline=baseline)
        if floor is not None:
            (run / "summary.json").write_text(json.dumps(
                {"references": {"epoch": 10, "true_state": {"pi_rand": floor}}}))
    text = fig2.report(tmp_path, ["CartPole"], ["PRED", "VAE_rpl"])
    rows = {line.split(" | ")[0]: line.split(" | ") for line in text.splitlines()
            if line.startswith("| *")}
    theta = np.array([1.0, 1.2, 1.4])
    half = 2.9199856 * theta.std(ddof=1) / math.sqrt(3)
    assert rows["| *constant*"][1:3] == ["pi_rand", f"{theta.mean():.3f} ± {half:.3f}"]
    assert rows["| *constant*"][-2:] == ["—", "3 |"]
    assert rows["| *true state*"][2].startswith("0.030 ± ") and rows["| *true state*"][-1] == "2 |"
    assert fig2.bounds_note({"constant", "true state"}) in text
    # Without either record, no row and no note.
    (tmp_path / "CartPole" / "VAE_rpl").rename(tmp_path / "VAE_rpl")
    for seed in (0, 1):
        (tmp_path / "CartPole" / "PRED" / f"seed_{seed}" / "summary.json").unlink()
        _strip_baseline(tmp_path / "CartPole" / "PRED" / f"seed_{seed}" / "history.jsonl")
    assert "(the ceiling)" not in fig2.report(tmp_path, ["CartPole"], ["PRED", "VAE_rpl"])


def _strip_baseline(path):
    records = [json.loads(line) for line in path.read_text().splitlines()]
    path.write_text("".join(json.dumps({k: v for k, v in r.items() if k != "baseline"}) + "\n"
                            for r in records))


def test_a_smoke_scale_report_says_its_numbers_do_not_rank_encoders(tmp_path):
    """fig2.md of `--scale smoke` runs opens with the smoke caveat; other sizes' have none."""
    from jaml.configs.stream import SCALES, SMOKE_CAVEAT

    run = tmp_path / "CartPole" / "VAE_rpl" / "seed_0"
    _write_run(run, "VAE_rpl", 0, [0.4, 0.8, 0.1, 1.0])
    assert SMOKE_CAVEAT not in fig2.report(tmp_path, ["CartPole"], ["VAE_rpl"])
    smoke = {f.name: SCALES["smoke"][f.metadata["path"]]
             for f in dataclasses.fields(_runs.Sizes)}
    config = json.loads((run / "config.json").read_text()) | smoke
    (run / "config.json").write_text(json.dumps(config))
    text = fig2.report(tmp_path, ["CartPole"], ["VAE_rpl"])
    assert text.splitlines()[2] == f"Note: {SMOKE_CAVEAT}."
    assert _runs.scale_of(_runs.settings(config)) == "smoke"


def test_report_shows_each_cells_progress_and_reads_a_cell_at_its_seeds_common_epoch(tmp_path):
    for seed in range(6):
        _write_run(tmp_path / "CartPole" / "PRED" / f"seed_{seed}", "PRED", seed, [0.1] * 4)
    for seed in range(3):  # an unfinished call: seed 2 stopped after its first analysis
        _write_run(tmp_path / "CartPole" / "VAE_rpl" / f"seed_{seed}", "VAE_rpl", seed,
                   [0.2] * 4, finished=seed < 2)

    text = fig2.report(tmp_path, ["CartPole", "Ant"], ["PRED", "VAE_rpl", "DSA"])

    assert "1 of 6 complete" in text
    assert "| CartPole | 6 × 20 ✓ | 3 × 10 of 20 | — |" in text
    assert "| Ant | — | — | — |" in text
    vae = next(line for line in text.splitlines() if line.startswith("| VAE_rpl"))
    # Every seed read at epoch 10 (errors 0.9), not seeds 0 and 1 at 20 (0.2) mixed in.
    assert vae.split(" | ")[2] == "0.900 ± 0.000" and vae.endswith("| 10 | 3 |")
    # A seed stopped by a non-finite loss is named beside its cell, not counted nor read.
    _write_run(tmp_path / "CartPole" / "DSA" / "seed_0", "DSA", 0, [0.3] * 4)
    _write_run(tmp_path / "CartPole" / "DSA" / "seed_1", "DSA", 1, [0.3] * 4, finished=False)
    (tmp_path / "CartPole" / "DSA" / "seed_1" / "summary.json").write_text(
        json.dumps({"status": "nonfinite", "error": "learner loss became non-finite at epoch 12"}))
    dsa = fig2.report(tmp_path, ["CartPole"], ["DSA"])
    assert "| CartPole | 1 × 20 (+1 stopped: non-finite loss) |" in dsa


def test_a_cells_extra_learner_options_are_shown_and_seeds_that_differ_are_refused(tmp_path):
    for seed in range(6):  # β-VAE_5's own β is not an extra; bfloat16 is
        _write_run(tmp_path / "CartPole" / "beta-VAE_5" / f"seed_{seed}", "beta-VAE", seed,
                   [0.1] * 4, learner_overrides={"beta": 5.0, "compute_dtype": "bfloat16"})
    text = fig2.report(tmp_path, ["CartPole"], ["beta-VAE_5"])
    assert "| CartPole | 6 × 20 ✓ (compute_dtype=bfloat16) |" in text

    _write_run(tmp_path / "CartPole" / "PRED" / "seed_0", "PRED", 0, [0.1] * 4)
    _write_run(tmp_path / "CartPole" / "PRED" / "seed_1", "PRED", 1, [0.1] * 4,
               learner_overrides={"compute_dtype": "bfloat16"})
    with pytest.raises(ValueError, match="seed_0 and seed_1 differ in learner_overrides"):
        fig2.report(tmp_path, ["CartPole"], ["PRED"])


def test_a_cells_extra_options_read_from_records_of_the_config_tree(tmp_path):
    """Records written since the config is a tree (#45) give the same settings and extras."""
    for seed in range(2):
        config = fig2.config_for("CartPole", "beta-VAE_5", seed, PAPER_SIZES, fig2.SCHEDULE,
                                 {"compute_dtype": "bfloat16"})
        path = tmp_path / "CartPole" / "beta-VAE_5" / f"seed_{seed}"
        _write_run(path, "beta-VAE", seed, [0.1] * 4)
        (path / "config.json").write_text(json.dumps(stream.resolve(config, 4, "cpu").to_dict()))
    flat = _runs.cell_config(tmp_path / "CartPole" / "beta-VAE_5")
    # What differs from the learner's defaults (β-VAE's own β is 5).
    assert flat["learner_overrides"] == {"compute_dtype": "bfloat16"}
    assert (flat["eval_every"], flat["replay_slots"], flat["env_overrides"]) == (100, 4992, {})
    text = fig2.report(tmp_path, ["CartPole"], ["beta-VAE_5"])
    assert "| CartPole | 2 × 20 of 1000 (compute_dtype=bfloat16) |" in text


def test_figure_panels_average_the_groups_of_each_domain(tmp_path):
    """Pendulums: position and velocity panels; locomotion: one panel, the mean of its groups'
    means (contacts weigh as much as the many position dims)."""
    _write_run(tmp_path / "CartPole" / "PRED" / "seed_0", "PRED", 0, [0.1, 0.5, 0.3, 0.7])
    records = [r for r in fig2.figure_records(
        {"CartPole": fig2.grid_histories(tmp_path, "CartPole", ["PRED"])})
               if r["step"] == 20]
    assert records[0]["errors"] == {"CartPole position": 0.2, "CartPole velocity": 0.6}
    assert records[0]["learner"] == "PRED"
    assert "baseline" not in records[0]  # recorded without one: no constant curve to draw
    assert fig2.panels("Ant").keys() == {"Ant (pos, vel, contacts)"}
    assert len(fig2.panels("Ant")["Ant (pos, vel, contacts)"]) == 3


def test_figure_panels_carry_the_constant_predictors_level_on_their_own_scale(tmp_path):
    """fig2.png's dashed curve: a pendulum panel's constant predictor in training-std units
    (the mean of its dims' baselines), drawn in the panel whose legend names it."""
    _write_run(tmp_path / "CartPole" / "PRED" / "seed_0", "PRED", 0, [0.1, 0.5, 0.3, 0.7],
               baseline=[0.8, 1.0, 0.6, 1.2])
    records = fig2.figure_records(
        {"CartPole": fig2.grid_histories(tmp_path, "CartPole", ["PRED"])})
    assert records[0]["baseline"] == pytest.approx({"CartPole position": 0.7,
                                                    "CartPole velocity": 1.1})
    fig = plots.alignment_figure(records)
    dashed = [line for line in fig.axes[0].get_lines() if line.get_linestyle() == "--"]
    assert len(dashed) == 1 and dashed[0].get_label() == plots.CONSTANT
    assert dashed[0].get_ydata() == pytest.approx([0.7, 0.7])  # epochs 10 and 20


def _locomotion_cell(out, variant, with_baselines=True):
    """A one-seed HalfCheetah cell analysed at epochs 10 and 20; its groups' raw errors and a
    constant predictor's are position 0.5 / 1.0, velocity 0.6 / 1.2, contacts 0.3 / 1.2."""
    groups = fig2.ld_groups("HalfCheetah")
    raw = {"position": (0.5, 1.0), "velocity": (0.6, 1.2), "contact": (0.3, 1.2)}
    errors = {d: raw[g][0] for g, dims in groups.items() for d in dims}
    baseline = {d: raw[g][1] for g, dims in groups.items() for d in dims}
    run = out / "HalfCheetah" / variant / "seed_0"
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({k: 1 for k in _runs.SIZES}
                                                | {"seed": 0, "epochs": 20}))
    names = list(errors)
    lines = [r | ({"baseline": baseline} if with_baselines else {})
             for step in (10, 20) for r in history_records(
                 step, variant, {"pi_rand": [errors[n] for n in names]}, names, run=0)]
    (run / "history.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    return lines


def test_locomotion_figures_read_fractions_of_the_constant_predictor(tmp_path):
    """Each run's raw errors are in its own replay's units, so the locomotion panel (and the
    per-group figure) read every group as a fraction of the run's constant predictor's error,
    the report's scale; a cell recorded without baselines is left out, not drawn raw."""
    lines = _locomotion_cell(tmp_path, "PRED")
    _locomotion_cell(tmp_path, "VAE_rpl", with_baselines=False)
    records = fig2.figure_records(
        {"HalfCheetah": fig2.grid_histories(tmp_path, "HalfCheetah", ["PRED", "VAE_rpl"])})
    assert [(r["learner"], r["step"]) for r in records] == [("PRED", 10), ("PRED", 20)]
    value = records[0]["errors"]["HalfCheetah (pos, vel, contacts)"]
    assert value == pytest.approx(np.mean([0.5, 0.5, 0.25]))  # raw would be 0.467
    assert records[0]["baseline"] == {"HalfCheetah (pos, vel, contacts)": 1.0}  # its own scale
    by_group = fig2.group_records("HalfCheetah", {"PRED": [lines], "VAE_rpl": [[
        {k: v for k, v in r.items() if k != "baseline"} for r in lines]]})
    assert [(r["learner"], r["step"]) for r in by_group] == [("PRED", 10), ("PRED", 20)]
    assert by_group[0]["errors"] == pytest.approx(
        {"position": 0.5, "velocity": 0.5, "contact": 0.25})
    assert by_group[0]["baseline"] == {"position": 1.0, "velocity": 1.0, "contact": 1.0}
    assert fig2.panel_ylabels(["CartPole", "HalfCheetah"]) == {
        "HalfCheetah (pos, vel, contacts)": fig2.OF_CONSTANT}


def test_the_report_draws_locomotion_on_the_constants_scale_and_names_what_it_leaves_out(
        tmp_path, monkeypatch):
    """report(): the per-group HalfCheetah figure and fig2.png's HalfCheetah panel carry the
    fractions' axis label; the cell without baselines is named, and a stale per-group figure
    of a grid where no cell can be drawn is removed."""
    _write_run(tmp_path / "CartPole" / "PRED" / "seed_0", "PRED", 0, [0.1] * 4)
    _locomotion_cell(tmp_path, "PRED")
    _locomotion_cell(tmp_path, "VAE_rpl", with_baselines=False)
    drawn = {}
    real = plots.plot_alignment

    def plot_alignment(records, path, groups=None, ylabels=None):
        drawn[path.name] = ({r["learner"] for r in records}, ylabels)
        return real(records, path, groups=groups, ylabels=ylabels)

    monkeypatch.setattr(plots, "plot_alignment", plot_alignment)
    text = fig2.report(tmp_path, ["CartPole", "HalfCheetah"], ["PRED", "VAE_rpl"])
    assert drawn["HalfCheetah_alignment.png"] == (
        {"PRED"}, dict.fromkeys(fig2.ld_groups("HalfCheetah"), fig2.OF_CONSTANT))
    assert drawn["fig2.png"][1] == {"HalfCheetah (pos, vel, contacts)": fig2.OF_CONSTANT}
    assert drawn["CartPole_alignment.png"][1] is None  # training-std units
    assert "Not in the HalfCheetah figures (records without a constant predictor's errors): " \
           "VAE_rpl." in text
    fig2.report(tmp_path, ["HalfCheetah"], ["VAE_rpl"])  # no cell with baselines
    assert not (tmp_path / "HalfCheetah_alignment.png").exists()
    assert not (tmp_path / "fig2.png").exists()


def test_grid_configs_follow_the_paper_per_family():
    cart = fig2.config_for("CartPole", "beta-VAE_20", 3, PAPER_SIZES, fig2.SCHEDULE)
    ant = fig2.config_for("Ant", "PRED", 0, PAPER_SIZES, fig2.SCHEDULE)
    assert (cart.learner, cart.learner_config.beta, cart.seed) == ("beta-VAE", 20.0, 3)
    assert (cart.epochs, cart.learner_steps) == (1000, 10)
    assert stream.resolve(cart, 4, "cpu").replay.slots == 4992
    assert (ant.epochs, ant.learner_steps, ant.rollout_len) == (300, 50, 64)
    assert cart.frames_per_batch == ant.frames_per_batch == 1024


def test_groups_come_from_the_domains_metadata_not_the_names():
    """vx/vy/vz are velocities and the foot flags contacts (a name rule counted both as
    position); the incline's scene parameters and the planar cheetah's constants are in no
    group."""
    cheetah = fig2.ld_groups("HalfCheetah")
    assert {"vx", "vz", "bthigh_vel"} <= set(cheetah["velocity"])
    assert {"z_rel", "pitch", "bthigh_pos"} <= set(cheetah["position"])
    grouped = {n for names in cheetah.values() for n in names}
    assert not grouped & {"vy", "roll", "sin_to_target", "cos_to_target"}
    ant = fig2.ld_groups("Ant")
    assert "vy" in ant["velocity"] and "roll" in ant["position"]  # the Ant moves in 3-D
    assert len(cheetah["contact"]) == 6 and all(n.endswith("_contact") for n in cheetah["contact"])
    assert fig2.ld_groups("CartPole") == {"position": ["theta", "x"],
                                          "velocity": ["theta_dot", "x_dot"]}
    assert fig2.ld_groups("MeshOnIncline") == {"position": ["position"],
                                               "velocity": ["velocity"]}


def test_compare_two_grids_cell_by_cell_with_welch_intervals(tmp_path):
    """Group means of grid A minus grid B at their last common analysis; the interval is Welch's,
    computed here from its closed form (Welch–Satterthwaite degrees of freedom)."""
    from scipy import stats

    a_theta, b_theta = [0.1, 0.2, 0.3], [0.5, 0.6, 0.8, 0.7]
    for seed, t in enumerate(a_theta):
        _write_run(tmp_path / "a" / "CartPole" / "PRED" / f"seed_{seed}", "PRED", seed,
                   [t, 0.5, 0.1, 0.5])
    for seed, t in enumerate(b_theta):
        _write_run(tmp_path / "b" / "CartPole" / "PRED" / f"seed_{seed}", "PRED", seed,
                   [t, 0.5, 0.1, 0.5])
    _write_run(tmp_path / "a" / "CartPole" / "DSA" / "seed_0", "DSA", 0, [0.1] * 4)  # only in A

    text = fig2.compare(tmp_path / "a", tmp_path / "b", ["CartPole"], ["PRED", "DSA"])

    rows = [line.split(" | ") for line in text.splitlines() if line.startswith("| CartPole")]
    assert len(rows) == 2  # PRED's position and velocity on π_rand; DSA is in one grid only
    position = next(r for r in rows if r[2] == "position")
    a, b = (np.array(a_theta) + 0.1) / 2, (np.array(b_theta) + 0.1) / 2  # mean(theta, x)
    va, vb = a.var(ddof=1) / 3, b.var(ddof=1) / 4
    dof = (va + vb) ** 2 / (va**2 / 2 + vb**2 / 3)
    half = stats.t.ppf(0.95, dof) * math.sqrt(va + vb)
    diff = a.mean() - b.mean()
    assert position[3] == "20" and position[4] == f"{a.mean():.3f}"
    assert position[6] == f"{diff:+.3f} [{diff - half:+.3f}, {diff + half:+.3f}]"
    assert position[7] == "1 of 2"  # resolved at epoch 20, not at epoch 10 (all 0.9)
    assert position[8] == position[6] + " |"  # the later half (after epoch 10) is epoch 20
    velocity = next(r for r in rows if r[2] == "velocity")
    assert velocity[6] == "+0.000 [+0.000, +0.000]" and velocity[7] == "0 of 2"


def test_compare_averages_each_seed_over_the_later_half_before_the_interval(tmp_path):
    """The later half's interval: each seed's mean over the analyses after half the last epoch
    (15 and 20 of 20, not 10), then Welch's interval over those means, from its closed form."""
    from scipy import stats

    a = {15: [0.1, 0.3, 0.2], 20: [0.3, 0.2, 0.4]}
    b = {15: [0.4, 0.5, 0.3, 0.6], 20: [0.2, 0.6, 0.5, 0.4]}
    for grid, theta in (("a", a), ("b", b)):
        for seed, (t15, t20) in enumerate(zip(theta[15], theta[20], strict=True)):
            _write_run(tmp_path / grid / "CartPole" / "PRED" / f"seed_{seed}", "PRED", seed,
                       [t20, 0.5, t20, 0.5], errors_at_15=[t15, 0.5, t15, 0.5])

    text = fig2.compare(tmp_path / "a", tmp_path / "b", ["CartPole"], ["PRED"])

    row = next(line.split(" | ") for line in text.splitlines() if "| position |" in line)
    ma, mb = (np.add(a[15], a[20]) / 2), (np.add(b[15], b[20]) / 2)  # θ and x move together
    va, vb = ma.var(ddof=1) / 3, mb.var(ddof=1) / 4
    dof = (va + vb) ** 2 / (va**2 / 2 + vb**2 / 3)
    half = stats.t.ppf(0.95, dof) * math.sqrt(va + vb)
    diff = ma.mean() - mb.mean()
    assert row[7] == "1 of 3"  # epoch 15 resolves; 10 (0.9 on both sides) and 20 do not
    assert row[8] == f"{diff:+.3f} [{diff - half:+.3f}, {diff + half:+.3f}] |"


def test_report_only_compares_with_each_grid_given(tmp_path, capsys):
    for grid in "abc":
        _write_run(tmp_path / grid / "CartPole" / "PRED" / "seed_0", "PRED", 0, [0.1] * 4)
    argv = ["--out", str(tmp_path / "a"), "--envs", "CartPole", "--variants", "PRED",
            "--report-only", "--compare-with", str(tmp_path / "b"),
            "--compare-with", str(tmp_path / "c")]
    assert fig2.main(argv) == 0
    table = (tmp_path / "a" / "compare.md").read_text()
    assert "## a − b, cell by cell" in table and "## a − c, cell by cell" in table

    bad = [*argv[:6], "--report-only", "--compare-with", str(tmp_path / "nowhere")]
    assert fig2.main(bad) != 0
    assert "nowhere: no such grid directory" in capsys.readouterr().err


def test_group_means_as_fractions_of_the_constant_predictors_error(tmp_path):
    """Two runs whose regressors' units differ (their constants score 0.8 and 0.4 on position):
    the report and --compare-with put them on one scale; runs without baselines show "—"."""
    _write_run(tmp_path / "a" / "CartPole" / "VAE_v0" / "seed_0", "VAE_v0", 0,
               [0.2, 1.0, 0.2, 1.0], baseline=[0.8, 1.0, 0.8, 1.0])
    _write_run(tmp_path / "b" / "CartPole" / "VAE_v0" / "seed_0", "VAE_v0", 0,
               [0.1, 0.5, 0.1, 0.5], baseline=[0.4, 0.5, 0.4, 0.5])
    _write_run(tmp_path / "a" / "CartPole" / "PRED" / "seed_0", "PRED", 0, [0.1] * 4)

    record = {"errors": dict(zip(NAMES, [0.2, 1.0, 0.3, 1.0], strict=True)),
              "baseline": dict(zip(NAMES, [0.8, 1.0, 0.2, 1.0], strict=True))}
    assert fig2.group_value(record, ["theta", "x"]) == pytest.approx(0.25)  # raw mean
    assert fig2.group_value(record, ["theta", "x"], relative=True) == pytest.approx(0.5)
    assert fig2.group_value({"errors": record["errors"]}, ["x"], relative=True) is None

    text = fig2.report(tmp_path / "a", ["CartPole"], ["VAE_v0", "PRED"])
    table = text[text.index("fraction of a constant"):]
    assert "| VAE_v0 | pi_rand | 0.250 | 1.000 | 20 | 1 |" in table
    assert "| PRED | pi_rand | — | — | 20 | 1 |" in table

    raw = fig2.compare(tmp_path / "a", tmp_path / "b", ["CartPole"], ["VAE_v0"])
    fraction = fig2.compare(tmp_path / "a", tmp_path / "b", ["CartPole"], ["VAE_v0"],
                            relative=True)
    assert "| CartPole · VAE_v0 | pi_rand | position | 20 | 0.200 | 0.100 |" in raw
    assert "| CartPole · VAE_v0 | pi_rand | position | 20 | 0.250 | 0.250 |" in fraction
    assert "fraction of each run's constant" in fraction.splitlines()[0]
    _write_run(tmp_path / "b" / "CartPole" / "PRED" / "seed_0", "PRED", 0, [0.1] * 4)
    fraction = fig2.compare(tmp_path / "a", tmp_path / "b", ["CartPole"], ["VAE_v0", "PRED"],
                            relative=True)
    assert "not compared (runs recorded without baselines): CartPole · PRED." in fraction


def test_a_report_beside_a_run_still_writing_reads_whole_records_and_leaves_no_temporaries(
        tmp_path):
    """Several processes may train cells of one grid, each rewriting the report at its end: a
    record being appended (no newline yet) is not read, and the report and figures are replaced
    whole (written under a temporary name of the process's own, then renamed)."""
    run = tmp_path / "CartPole" / "PRED" / "seed_0"
    _write_run(run, "PRED", 0, [0.1, 0.5, 0.2, 0.7])
    whole = (run / "history.jsonl").read_text()
    torn = json.dumps(history_records(30, "PRED", {"pi_rand": [0.3] * 4}, NAMES, run=0)[0])
    (run / "history.jsonl").write_text(whole + torn[:len(torn) // 2])
    assert fig2._runs.read_jsonl(run / "history.jsonl") == [
        json.loads(line) for line in whole.splitlines()]
    text = fig2.report(tmp_path, ["CartPole"], ["PRED"])
    assert "| PRED | pi_rand | 0.100 |" in text  # epoch 20's record, the torn one skipped
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "CartPole", "CartPole_alignment.png", "fig2.md", "fig2.png"]


