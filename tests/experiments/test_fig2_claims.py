"""The paper's Fig. 2 findings measured from a grid's records (`fig2_claims`), against Welch
intervals and fractions computed here by hand from the same numbers."""

import json

import numpy as np
import pytest
from scipy import stats

from jaml.evaluation import history_records
from jaml.experiments import fig2, fig2_claims

CARTPOLE = ["theta", "theta_dot", "x", "x_dot"]  # position: theta, x; velocity: the dots


def _cell(out, env, variant, per_seed, names, baseline=None, epochs=20):
    """A cell whose seed s has errors per_seed[s] (one list over `names`) on both test sets at
    epoch `epochs`, and 0.9 everywhere at epoch 10; `baseline`, a constant predictor's errors."""
    for seed, errors in enumerate(per_seed):
        path = out / env / variant / f"seed_{seed}"
        path.mkdir(parents=True)
        (path / "config.json").write_text(json.dumps({"epochs": epochs, "seed": seed}))
        records = history_records(10, variant, {t: [0.9] * len(names) for t in fig2_claims.BOTH},
                                  names, run=seed)
        records += history_records(epochs, variant, {t: errors for t in fig2_claims.BOTH},
                                   names, run=seed)
        if baseline is not None:
            records = [r | {"baseline": dict(zip(names, baseline, strict=True))} for r in records]
        (path / "history.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))


def _row(table: list[str], comparison: str) -> list[str]:
    line = next(line for line in table if f"| {comparison} |" in line)
    return [c.strip() for c in line.strip("|").split("|")]


def _welch(a, b) -> str:
    ci = stats.ttest_ind(a, b, equal_var=False).confidence_interval(0.90)
    return f"{np.mean(a) - np.mean(b):+.3f} [{ci.low:+.3f}, {ci.high:+.3f}]"


def test_each_finding_is_a_welch_interval_marked_by_the_side_of_zero_the_paper_puts_it(tmp_path):
    rng = np.random.default_rng(0)
    theta_v0 = [1.2, 1.4, 1.1]  # VAE_v0 worse on π_rand position: the paper's side
    theta_rpl = [0.2, 0.3, 0.25]
    _cell(tmp_path, "CartPole", "VAE_v0", [[t, 1.0, t, 1.0] for t in theta_v0], CARTPOLE)
    vel_rpl = [1.0, 1.05, 0.95]
    _cell(tmp_path, "CartPole", "VAE_rpl",
          [[t, v, t, v] for t, v in zip(theta_rpl, vel_rpl, strict=True)], CARTPOLE)
    # SVAE's velocity worse than VAE_rpl's (against the paper); DSA's noisy around it.
    _cell(tmp_path, "CartPole", "SVAE", [[0.3, v, 0.3, v] for v in (1.5, 1.6, 1.7)], CARTPOLE)
    _cell(tmp_path, "CartPole", "DSA",
          [[0.3, v, 0.3, v] for v in 1.0 + rng.normal(0, 0.5, 3)], CARTPOLE)

    table = fig2_claims.claims_table(tmp_path, ["CartPole", "HalfCheetah"], list(fig2.VARIANTS))

    assert table[0] == "## The paper's findings, measured"
    assert "| CartPole |" in table[4] and "HalfCheetah" not in table[4]  # only domains with runs
    v0 = _row(table, f"VAE_v0 − VAE_rpl, pi_rand, {fig2_claims.PLOTTED}")
    # Three seeds, short of a full cell's six: said beside the entry.
    assert v0[2] == _welch(theta_v0, theta_rpl) + " ✓ (VAE_v0 3 seeds, VAE_rpl 3 seeds)"
    svae = _row(table, "SVAE − VAE_rpl, pi_rand, velocity")
    assert svae[2].startswith(_welch([1.5, 1.6, 1.7], vel_rpl) + " ✗ (")
    assert " ~ (" in _row(table, "DSA − VAE_rpl, pi_curr, velocity")[2]
    assert _row(table, "PRED − VAE_rpl, pi_rand, velocity")[2] == "—"  # no PRED cell
    assert _row(table, "PRED − VAE_rpl, pi_curr, panel")[2] == "—"  # a locomotion finding
    assert fig2_claims.claims_table(tmp_path, ["Ant"], list(fig2.VARIANTS)) == []


def test_locomotion_is_read_as_fractions_of_the_constant_and_pred_placed_among_the_cells(
        tmp_path):
    groups = fig2.ld_groups("HalfCheetah")
    names = [n for dims in groups.values() for n in dims]
    baseline = [2.0] * len(names)
    panel = {"PRED": [0.5, 0.6, 0.7], "VAE_rpl": [0.9, 1.0, 1.1], "DSA": [0.3, 0.3, 0.4]}
    for variant, values in panel.items():  # every group at the same error: the panel's value
        _cell(tmp_path, "HalfCheetah", variant, [[2.0 * v] * len(names) for v in values], names,
              baseline=baseline)

    table = fig2_claims.claims_table(tmp_path, ["HalfCheetah"], list(fig2.VARIANTS))

    pred = _row(table, "PRED − VAE_rpl, pi_curr, panel")
    assert pred[2].startswith(_welch(panel["PRED"], panel["VAE_rpl"]) + " ✓")
    place = _row(table, "PRED's place by mean; PRED − the cell next to it")
    assert place[2].startswith("2 of 3 ✓; PRED − DSA " + _welch(panel["PRED"], panel["DSA"]))
    assert _row(table, "PRED − SVAE, pi_rand, velocity")[2] == "—"  # a pendulum finding


def test_a_comparison_is_read_where_both_cells_seeds_are(tmp_path):
    """A cell stopped at epoch 10 is compared at 10, and the entry says so."""
    _cell(tmp_path, "CartPole", "VAE_v0", [[1.0] * 4, [1.1] * 4], CARTPOLE)
    _cell(tmp_path, "CartPole", "VAE_rpl", [[0.2] * 4, [0.3] * 4], CARTPOLE)
    for seed in range(2):  # VAE_rpl's history cut after its first analysis
        path = tmp_path / "CartPole" / "VAE_rpl" / f"seed_{seed}" / "history.jsonl"
        lines = path.read_text().splitlines(keepends=True)
        path.write_text("".join(lines[:2]))

    table = fig2_claims.claims_table(tmp_path, ["CartPole"], ["VAE_v0", "VAE_rpl"])

    entry = _row(table, f"VAE_v0 − VAE_rpl, pi_rand, {fig2_claims.PLOTTED}")[2]
    assert entry.startswith("+0.000 ")  # both at 0.9 at epoch 10
    assert "epoch 10" in entry


@pytest.mark.parametrize("variants", [["VAE_v0"], ["PRED"]])
def test_no_pair_no_entry(tmp_path, variants):
    for v in variants:
        _cell(tmp_path, "CartPole", v, [[0.5] * 4, [0.6] * 4], CARTPOLE)
    table = fig2_claims.claims_table(tmp_path, ["CartPole"], variants)
    assert all(row.endswith("| — |") for row in table[6:-1])
