"""Fig. 9: the recipes' configs, the report (paired and Welch intervals, the stream check, the
primary comparison, the figure) and the driver's steps."""

import dataclasses
import gzip
import json
import math

import jax
import numpy as np
import pytest

import envs_mjx
from envs_mjx.config import configured
from jaml.configs.learners import default_config
from jaml.configs.stream import resolve
from jaml.evaluation import history_records
from jaml.experiments import fig9, fig9_report
from jaml.relations.transfer import LatentLayout

NAMES = ["texture_id", "object_id", "theta", "position", "velocity"]


def _write_run(path, seed, positions, distortions=(9.0, 1.0), irregularity=0.5):
    """A seed's history: analyses at 78, 678, 1078 with the given π_rand position errors."""
    path.mkdir(parents=True)
    records = []
    for step, pos, dist in zip((78, 678, 1078), positions, (9.0, *distortions), strict=False):
        errors = {"pi_rand": [0.1, 0.0, 0.2, pos, 0.4], "pi_curr": [0.5] * 5}
        for r in history_records(step, "PRED", errors, NAMES, dist, run=seed):
            if r["test_set"] == "pi_rand":
                r["irregularity"] = {"pi_rand": irregularity, "replay": irregularity + 1}
            records.append(r)
    (path / "history.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))


def _write_metrics(path, returns):
    (path / "metrics.jsonl").write_text("".join(
        json.dumps({"epoch": e + 1, "episode_return": r, "ppo/total_loss": 0.5}) + "\n"
        for e, r in enumerate(returns)))


def test_report_leads_with_the_primary_comparison_and_tables_paired_differences(tmp_path):
    """Three seeds per method; AML is PRED − (0.01, 0.02, 0.03) at both late analyses (after
    learner epoch 500 counts from the first analysis, 78): primary = −0.02 ± the hand half-width."""
    pred = {0: (0.3, 0.20, 0.18), 1: (0.3, 0.25, 0.22), 2: (0.3, 0.15, 0.12)}
    for seed, positions in pred.items():
        _write_run(tmp_path / "PRED" / f"seed_{seed}", seed, positions)
        _write_metrics(tmp_path / "PRED" / f"seed_{seed}", [1.0, 2.0])
        shift = 0.01 * (seed + 1)
        _write_run(tmp_path / "PRED+AML_trnsv" / f"seed_{seed}", seed,
                   (0.3, positions[1] - shift, positions[2] - shift))
        _write_metrics(tmp_path / "PRED+AML_trnsv" / f"seed_{seed}",
                       [1.0, 2.0] if seed < 2 else [1.0, 2.5])
    text = fig9_report.report(tmp_path, list(fig9.METHODS))
    half = 2.9199856 * 0.01 / math.sqrt(3)
    assert text.splitlines()[0].startswith("**Primary comparison** (PRED+AML_trnsv − PRED")
    assert f"**-0.0200 [{-0.02 - half:+.4f}, {-0.02 + half:+.4f}]**" in text.splitlines()[0]
    assert "- PRED+AML_trnsv vs PRED: 2 seeds identical; differ: seed_2 from epoch 2" in text
    row = next(line for line in text.splitlines() if line.startswith("| 1078 |"))
    assert f"Δ **-0.0200 [{-0.02 - half:+.4f}, {-0.02 + half:+.4f}]**" in row
    assert "irreg_std, π_rand" in text and "VAE_rpl" not in text
    assert (tmp_path / "fig9.md").read_text() == text
    assert (tmp_path / "fig9.png").stat().st_size > 0


def test_runs_without_metrics_say_so_in_one_line_not_in_empty_tables(tmp_path):
    """Records without metrics.jsonl (runs kept before it was): no stream check naming every
    seed, no losses table of dashes; one line says what is missing."""
    for method in ("PRED", "PRED+AML_trnsv"):
        for seed in range(2):
            _write_run(tmp_path / method / f"seed_{seed}", seed, (0.3, 0.2, 0.1))
    text = fig9_report.report(tmp_path, list(fig9.METHODS))
    assert "Streams and learner losses: not in these runs' records (no metrics.jsonl)." in text
    assert "no metrics:" not in text and "**Learner losses**" not in text
    _write_metrics(tmp_path / "PRED" / "seed_0", [1.0, 2.0])  # one run kept them: both parts
    text = fig9_report.report(tmp_path, list(fig9.METHODS))
    assert "- PRED+AML_trnsv vs PRED: 0 seeds identical; no metrics: seed_0, seed_1" in text
    assert "**Learner losses**" in text


def test_the_bounds_line_reads_the_constants_and_the_runs_floors(tmp_path):
    """The ceiling: each run's constant prediction at its last analysis; the floor: the true
    state's errors from summary.json, where a run recorded them."""
    for seed in range(2):
        run = tmp_path / "PRED" / f"seed_{seed}"
        _write_run(run, seed, (0.3, 0.2, 0.1))
        records = [json.loads(line) for line in (run / "history.jsonl").read_text().splitlines()]
        for r in records:  # the constant: position 0.5 + seed / 10 at the last analysis only
            last = r["step"] == 1078
            r["baseline"] = dict(zip(NAMES, [1.0, 1.0, 1.0, 0.5 + seed / 10 if last else 9.0,
                                             0.8], strict=True))
        (run / "history.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    (tmp_path / "PRED" / "seed_1" / "summary.json").write_text(json.dumps(
        {"references": {"true_state": {"pi_rand": [0.0, 0.0, 0.0, 0.03, 0.07]}}}))
    line = fig9_report.bounds(tmp_path, fig9_report.collect(tmp_path, ["PRED"]))
    assert ("a constant prediction's errors position 0.5500 and velocity 0.8000 (2 runs, each "
            "at its last analysis) (the ceiling); the true state's as the latent position 0.0300 "
            "and velocity 0.0700 (1 run, each at its last call's first analysis)") in line
    (tmp_path / "PRED" / "seed_1" / "summary.json").unlink()
    assert "not recorded by these runs (the floor)" in fig9_report.report(tmp_path, ["PRED"])


def test_the_stream_check_reads_committed_gzip_metrics(tmp_path):
    """A committed record keeps metrics.jsonl as metrics.jsonl.gz: the same verdict either way,
    a run with neither is named as missing."""
    for method, returns in (("PRED", [1.0, 2.0, 3.0]), ("PRED+AML_trnsv", [1.0, 2.0, 3.5])):
        (tmp_path / method / "seed_0").mkdir(parents=True)
        _write_metrics(tmp_path / method / "seed_0", returns)
    (tmp_path / "PRED+AML_trnsv" / "seed_1").mkdir()
    plain = fig9_report.stream_check(tmp_path, ["PRED", "PRED+AML_trnsv"])
    assert plain == ["- PRED+AML_trnsv vs PRED: 0 seeds identical; differ: seed_0 from epoch 3; "
                     "no metrics: seed_1"]
    for method in ("PRED", "PRED+AML_trnsv"):
        path = tmp_path / method / "seed_0" / "metrics.jsonl"
        path.with_name("metrics.jsonl.gz").write_bytes(gzip.compress(path.read_bytes()))
        path.unlink()
    assert fig9_report.stream_check(tmp_path, ["PRED", "PRED+AML_trnsv"]) == plain


def test_learner_losses_are_averaged_between_analyses_then_over_seeds(tmp_path):
    """Analyses at 78, 678, 1078: blocks 79–678 and 679–1078; epoch 78 (the fill) is left out,
    a metric a method never logs is a dash, one a block lacks is a dash in that block."""
    for seed in (0, 1):
        for method in ("PRED", "PRED+AML_trnsv"):
            path = tmp_path / method / f"seed_{seed}"
            _write_run(path, seed, (0.3, 0.2, 0.1))
            rows = []
            for epoch in (78, 100, 600, 700, 1078):
                row = {"epoch": epoch, "learner/nll": epoch / 100 + seed, "learner/kl": 2.0,
                       "learner/penalty": 0.0}
                if method != "PRED":
                    row["learner/penalty"] = 1.0
                    if epoch > 678:
                        row["learner/ok_fraction"] = 0.25 * (seed + 1)
                rows.append(row)
            (path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    runs = fig9_report.collect(tmp_path, ["PRED", "PRED+AML_trnsv"])
    lines = fig9_report.losses_table(tmp_path, runs)
    # NLL: block 1 epochs 100, 600 → seed means 3.5, 4.5 → 4.0; block 2: 700, 1078 → 8.89, 9.89
    assert "| PRED | 4.0 → 9.4 | 2.0 → 2.0 | 0.0 → 0.0 | — |" in lines
    assert "| PRED+AML_trnsv | 4.0 → 9.4 | 2.0 → 2.0 | 1.0 → 1.0 | — → 37.5% |" in lines
    assert lines[-1] == "Blocks: epochs 79–678, 679–1078."


def test_the_penalty_is_contrasted_with_its_controls_seed_by_seed(tmp_path):
    """AML − ok_rows at the last common analysis: the control is AML + (0.01, 0.02, 0.03)."""
    for seed in range(3):
        aml = (0.3, 0.2, 0.1 + 0.01 * seed)
        _write_run(tmp_path / "PRED+AML_trnsv" / f"seed_{seed}", seed, aml)
        _write_run(tmp_path / "PRED+ok_rows" / f"seed_{seed}", seed,
                   (0.3, 0.2, aml[2] + 0.01 * (seed + 1)))
    text = fig9_report.report(tmp_path, ["PRED+AML_trnsv", "PRED+ok_rows"])
    half = 2.9199856 * 0.01 / math.sqrt(3)
    row = next(line for line in text.splitlines()
               if line.startswith("| PRED+AML_trnsv − PRED+ok_rows |"))
    assert "**Penalty against its controls** at epoch 1078" in text
    assert row.split(" | ")[1] == f"**-0.0200 [{-0.02 - half:+.4f}, {-0.02 + half:+.4f}]**"


def test_every_method_is_averaged_after_learner_epoch_500_and_the_beta_control_is_contrasted(
        tmp_path):
    """The late table averages the analyses at 678 and 1078 (after 78 + 500): β is PRED −
    (0.01, 0.02, 0.03) at 678 and − (0.03, 0.04, 0.05) at 1078 → −0.03 ± the hand half-width;
    the random-row control − β is a row of the contrasts at 1078 (control = β + 0.01 · seed)."""
    for seed in range(3):
        pred = (0.3, 0.2 + 0.01 * seed, 0.1)
        d = 0.01 * (seed + 1)
        beta = (0.3, pred[1] - d, pred[2] - d - 0.02)
        _write_run(tmp_path / "PRED" / f"seed_{seed}", seed, pred)
        _write_run(tmp_path / "PRED+beta_1of11" / f"seed_{seed}", seed, beta)
        _write_run(tmp_path / "PRED+random_rows_5pct" / f"seed_{seed}", seed,
                   (0.3, beta[1], beta[2] + 0.01 * seed))
    text = fig9_report.report(
        tmp_path, ["PRED", "PRED+random_rows_5pct", "PRED+beta_1of11"])
    half = 2.9199856 * 0.01 / math.sqrt(3)
    late = next(line for line in text.splitlines() if line.startswith("| PRED+beta_1of11 |"))
    assert late.split(" | ")[1] == f"**-0.0300 [{-0.03 - half:+.4f}, {-0.03 + half:+.4f}]**"
    row = next(line for line in text.splitlines()
               if line.startswith("| PRED+random_rows_5pct − PRED+beta_1of11 |"))
    assert row.split(" | ")[1] == f"+0.0100 [{0.01 - half:+.4f}, {0.01 + half:+.4f}]"


def test_the_figure_draws_each_methods_seed_mean_and_90_percent_band(tmp_path):
    """Per panel and step: the mean over seeds and mean ± t(0.95, n−1)·s/√n, by hand."""
    ends = [(0.10, 1.0), (0.12, 1.2), (0.17, 1.9)]
    for seed, (pos, dist) in enumerate(ends):
        _write_run(tmp_path / "PRED" / f"seed_{seed}", seed, (0.3, pos), (dist,))
    fig = fig9_report.plot(fig9_report.collect(tmp_path, ["PRED"]), tmp_path / "fig9.png")
    t = 2.9199856  # t(0.95, 2 dof)
    for ax, first, at_end in ((fig.axes[0], 0.3, [e[0] for e in ends]),
                              (fig.axes[1], 9.0, [e[1] for e in ends])):
        line, = ax.lines
        np.testing.assert_allclose(line.get_xdata(), [78, 678])
        np.testing.assert_allclose(line.get_ydata(), [first, np.mean(at_end)], rtol=1e-6)
        half = t * np.std(at_end, ddof=1) / math.sqrt(3)
        band = ax.collections[0].get_paths()[0].vertices
        last = band[np.isclose(band[:, 0], 678), 1]
        np.testing.assert_allclose([last.min(), last.max()],
                                   [np.mean(at_end) - half, np.mean(at_end) + half], rtol=1e-5)


def test_the_layout_reads_every_relation_coordinate_from_the_incline_pred():
    """The experiment's layout against the source's own coordinate names and the latent and
    action sizes of the PRED the experiment builds (`penalty_for`'s): θ in the static part, s
    and v in each step's dynamic part, the action of the first step."""
    from jaml import sources
    from jaml.stream import build

    names = tuple(sources.make(fig9.SOURCE).dim_names)
    assert sorted(names) == sorted(("theta", "s0", "v0", "a0", "s1", "v1"))
    stream = build(fig9._config("PRED", 0, fig9.RECIPES["reference"]))
    assert stream.learner.config.static_per_step
    config = stream.learner.config
    plan = LatentLayout.place(config.penalty_slots, **fig9.COORDINATES).gather(
        names, config.penalty_dim, stream.env.action_size)
    expected = {"theta": ("z", 2, 0), "s0": ("z", 3, 0), "v0": ("z", 4, 0), "a0": ("a", 0, 0),
                "s1": ("z", 3, 1), "v1": ("z", 4, 1)}
    assert [p[:3] for p in plan] == [expected[n] for n in names]


def _reset_draws(env, resets=3):
    """The episode fields three resets draw, as NumPy: `env.reset` is `_reset_from` of
    `_sample_reset`'s draw, and only the draw sets mass and friction (envs_mjx/domains/incline.py),
    so the draw is jitted alone: three eager resets compiled the settle physics op by op (~60 s
    of the default suite on two cores)."""
    keys = jax.random.split(jax.random.key(0), resets)
    info = jax.jit(jax.vmap(lambda k: env._sample_reset(k)[2]))(keys)
    return {k: np.asarray(info[k], np.float64) for k in ("mass", "friction")}


def test_fixed_dynamics_fix_the_targets_mass_and_friction_at_every_reset():
    """`--dynamics fixed` reaches the target's envs and the source's rows: every reset draws
    the one mass and friction; an unknown name is refused."""
    ours = fig9.RECIPES["ours"]
    config = fig9._config("PRED", 0, ours, "fixed")
    assert config.env == fig9.TARGET and config.env_config == configured(
        fig9.TARGET, **fig9._dynamics("fixed"))
    env = envs_mjx.load(fig9.TARGET, dataclasses.replace(config.env_config, pixels="off"))
    draws = _reset_draws(env)
    assert set(np.round(draws["mass"], 6)) == {0.2}  # float32
    assert set(np.round(draws["friction"], 6)) == {0.3}
    from jaml import sources  # the relations' rows: the source's env, as `learn_relations` makes it

    draws = _reset_draws(sources.make(fig9.SOURCE, **fig9._dynamics("fixed")).env)
    assert set(np.round(draws["mass"], 6)) == {0.2}
    assert set(np.round(draws["friction"], 6)) == {0.3}
    # "drawn": the domains' own
    assert fig9._config("PRED", 0, ours).env_config == envs_mjx.default_config(fig9.TARGET)
    with pytest.raises(ValueError, match=r"dynamics must be one of \['drawn', 'fixed'\]"):
        fig9._config("PRED", 0, ours, "frozen")


def test_the_beta_control_weighs_the_kl_as_the_random_row_controls_loss_does_in_expectation():
    """PRED+beta_1of11: β = 1/11 over the recipe's PRED, which the other methods keep at 1."""
    reference = fig9.RECIPES["reference"]
    ld = 5

    def learner(method):
        return resolve(fig9._config("PRED", 0, reference, method=method), ld,
                       "cpu").learner_config

    control, pred = learner("PRED+beta_1of11"), learner("PRED")
    assert control.beta == pytest.approx(1 / 11) and pred.beta == 1.0
    assert dataclasses.replace(control, beta=1.0) == pred  # nothing else differs


def test_a_method_without_relations_neither_fits_them_nor_runs_the_pilot(tmp_path, monkeypatch):
    # A `--methods PRED` process beside the pilot once ran the pilot itself, into the pilot's
    # own run directory. The reference recipe has one weight: no pilot.
    calls = []
    monkeypatch.setattr(fig9, "learn_relations", lambda *a, **k: calls.append("relations"))
    monkeypatch.setattr(fig9, "choose_weight",
                        lambda *a, **k: calls.append("pilot") or fig9.Penalty(1000.0))
    monkeypatch.setattr(fig9, "run_method",
                        lambda out, method, seeds, penalty, recipe, **k: calls.append(
                            (method, penalty, recipe.name)))
    ours = fig9.Penalty(100.0)
    assert fig9.Args(out=tmp_path, recipe="ours", methods=("PRED", "VAE_rpl")).train() is True
    assert calls == [("PRED", ours, "ours"), ("VAE_rpl", ours, "ours")]
    calls.clear()
    fig9.Args(out=tmp_path, recipe="ours", methods=("PRED", "PRED+AML_trnsv")).train()
    assert calls[:2] == ["relations", "pilot"] and [c[0] for c in calls[2:]] == [
        "PRED", "PRED+AML_trnsv"]
    calls.clear()
    assert fig9.Args(out=tmp_path, recipe="ours", methods=("PRED",), pilot_only=True).train() \
        is False
    assert calls == ["relations", "pilot"]
    calls.clear()
    fig9.Args(out=tmp_path, methods=("PRED+AML_trnsv",)).train()
    assert calls == ["relations", ("PRED+AML_trnsv", fig9.Penalty(2000.0, "hinge", 10.0),
                                   "reference")]


def test_the_reference_recipe_and_its_controls():
    """The released code's settings (docs/reference/fig9.md §2–3) reach the configs; the controls
    impose no penalty but keep the ok-row term, with the relations' rows or random ones."""
    ref = fig9.RECIPES["reference"]
    pred = fig9._config("PRED", 0, ref)
    assert pred.learner_config == default_config(
        "PRED", ld_dim=None, hist=1, pred=1, static_dim=3, latent_dim=2, mu_nl=False,
        logvar_limit=20.0, current_action="observed", kl_form="reference",
        conv_filters=(32, 64, 64, 128), deconv_filters=(128, 64, 64, 32), static_per_step=True,
        compute_dtype="float32", activation_dtype="float32")  # the reference's, on any device
    assert (resolve(pred, 5, "gpu").replay.slots, pred.frames_per_batch // 2,
            pred.learner_steps) == (4992, 512, 10)
    assert (pred.eval.train, pred.eval.rand, pred.eval.regressor_iterations) == (
        10_000, 10_048, 10_000)
    assert not hasattr(fig9._config("VAE_rpl", 0, ref).learner_config, "static_per_step")
    penalty = fig9.Penalty(2000.0, "hinge", 10.0)
    assert fig9.method_penalty("PRED+AML_syz", penalty) == penalty
    assert fig9.method_penalty("PRED+ok_rows", penalty) == fig9.Penalty(0.0, "hinge", 10.0)
    assert fig9.method_penalty("PRED+random_rows", penalty) == fig9.Penalty(
        0.0, "hinge", 10.0, "random")
    assert fig9.method_penalty("PRED+random_rows_5pct", penalty) == fig9.Penalty(
        0.0, "hinge", 10.0, "random", 0.05)


def test_a_methods_penalty_enters_its_runs_configs(tmp_path, monkeypatch):
    """A method with relations trains configs whose `penalty` names the set's checkpoint under
    OUT, the relations the recipe imposes (the reference's: all; "ours": the converged ones)
    and fig9's coordinates; a method without relations, none. No penalty.json is written."""
    trained = {}
    monkeypatch.setattr(fig9._runs, "train_seeds",
                        lambda method, configs, dirs, **k: trained.update({method: configs}))
    summary = tmp_path / "relations" / "trnsv" / "summary.json"
    summary.parent.mkdir(parents=True)
    summary.write_text(json.dumps({"relations": [{"index": 1, "status": "capped"},
                                                 {"index": 2, "status": "done"}]}))
    penalty = fig9.Penalty(2000.0, "hinge", 10.0)
    for method in ("PRED+random_rows", "PRED"):
        fig9.run_method(tmp_path, method, [0, 1], penalty, fig9.RECIPES["ours"])
    assert [c.seed for c in trained["PRED+random_rows"]] == [0, 1]
    assert {c.penalty for c in trained["PRED+random_rows"]} == {fig9.Penalty(
        0.0, "hinge", 10.0, "random", relations=str(summary.parent / "checkpoint"), used=(1,),
        static=("theta",), dynamic=("s", "v"))}
    assert {c.penalty for c in trained["PRED"]} == {None}
    assert not list(tmp_path.rglob("penalty.json"))



@pytest.mark.slow  # compile-bound on a CPU: relations and PRED alone took 26 min on 2 cores
def test_the_driver_runs_end_to_end_at_smoke_scale(tmp_path, monkeypatch):
    """`jaml fig9 --scale smoke` on two seeds: relations (only the set the methods use), PRED and
    PRED+AML_trnsv trained on one stream per seed, then the report. The target is Geom-on-incline
    here: MeshOnIncline's MJX program compiles for tens of minutes on a CPU, and the driver's
    path does not depend on which incline it trains on."""
    monkeypatch.setattr(fig9, "TARGET", "GeomOnIncline")
    out = tmp_path / "fig9"
    assert fig9.main(["--out", str(out), "--scale", "smoke", "--methods", "PRED",
                      "PRED+AML_trnsv", "--seeds", "0", "1"]) == 0
    assert sorted(p.name for p in (out / "relations").iterdir()) == ["trnsv"]
    summary = json.loads((out / "relations" / "trnsv" / "summary.json").read_text())
    assert summary["num_relations"] == 2
    penalty = json.loads((out / "PRED+AML_trnsv" / "seed_1" / "config.json").read_text())[
        "penalty"]
    assert penalty["weight"] == 2000.0 and penalty["used"] == [0, 1]
    text = (out / "fig9.md").read_text()
    assert "- PRED+AML_trnsv vs PRED: 2 seeds identical" in text
    assert text.startswith("Primary comparison: no analysis after learner epoch 500")
    config = json.loads((out / "PRED" / "seed_0" / "config.json").read_text())
    assert "GeomOnIncline" in json.dumps(config)
