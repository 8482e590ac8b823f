"""Plots from a JSON-lines history: files written, curves carry run means, bad input raises."""

import json
import math

import numpy as np
import pytest

from jaml import evaluation

NAMES = ("x", "theta", "vx", "vtheta")


def _history():
    rng = np.random.default_rng(0)
    history = []
    for learner, level in (("VAE", 0.6), ("PRED", 0.3)):
        for run in range(3):
            for step in (0, 100, 200):
                errors = {
                    "pi_curr": level * np.exp(-step / 200) + 0.02 * rng.normal(size=4),
                    "pi_rand": 1.2 * level + 0.02 * rng.normal(size=4),
                }
                history += evaluation.history_records(
                    step, learner, errors, NAMES, distortion=level + 0.01 * run, run=run
                )
    # JSON-lines round trip: the plots must work from what a run directory stores.
    return [json.loads(line) for line in "\n".join(json.dumps(r) for r in history).splitlines()]


def _png(path):
    with open(path, "rb") as fh:
        return fh.read(8) == b"\x89PNG\r\n\x1a\n"


def test_alignment_plot_shows_run_means(tmp_path):
    history = _history()
    fig = evaluation.plot_alignment(history, tmp_path / "alignment.png")
    assert _png(tmp_path / "alignment.png")
    axes = fig.axes
    assert len(axes) == 2 * len(NAMES)  # rows: pi_curr, pi_rand; columns: dimensions
    assert axes[0].get_title() == "x (pi_curr)"
    vae = axes[0].lines[0]
    assert vae.get_label() == "VAE"
    expected = [
        np.mean([r["errors"]["x"] for r in history
                 if (r["learner"], r["test_set"], r["step"]) == ("VAE", "pi_curr", step)])
        for step in (0, 100, 200)
    ]
    np.testing.assert_allclose(vae.get_xdata(), [0, 100, 200])
    np.testing.assert_allclose(vae.get_ydata(), expected)


def test_alignment_plot_groups_dimensions(tmp_path):
    groups = {"position": ["x", "theta"], "velocity": ["vx", "vtheta"]}
    fig = evaluation.plot_alignment(_history(), tmp_path / "grouped.png", groups=groups)
    assert len(fig.axes) == 2 * 2
    pred_velocity = fig.axes[1].lines[1]
    history = _history()
    at_0 = [np.mean([r["errors"]["vx"], r["errors"]["vtheta"]]) for r in history
            if (r["learner"], r["test_set"], r["step"]) == ("PRED", "pi_curr", 0)]
    assert pred_velocity.get_ydata()[0] == pytest.approx(np.mean(at_0))


def test_panels_in_other_units_carry_their_own_axis_label(tmp_path):
    """Fig. 2's layout: pendulum panels in training-std units, then a locomotion panel as a
    fraction of a constant predictor's error: the label changes where the units do."""
    groups = {"position": ["x", "theta"], "velocity": ["vx", "vtheta"], "panel": ["x", "vx"]}
    fig = evaluation.plot_alignment(_history(), tmp_path / "units.png", groups=groups,
                                    ylabels={"panel": "of the constant"})
    labels = [[ax.get_ylabel() for ax in fig.axes[row * 3:row * 3 + 3]] for row in (0, 1)]
    assert labels == [["test error (train std)", "", "of the constant"]] * 2


def test_the_legend_names_every_learner_even_one_absent_from_the_first_panel(tmp_path):
    """Fig. 2's layout: CartPole's panels first, with one learner, HalfCheetah's with two."""
    history = [{"step": 0, "learner": "VAE_rpl", "test_set": "pi_curr", "errors": {"a": 0.1}},
               {"step": 0, "learner": "VAE_v0", "test_set": "pi_curr", "errors": {"b": 0.2}}]
    fig = evaluation.plot_alignment(history, tmp_path / "legend.png")
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == ["VAE_rpl", "VAE_v0"]
    # drawn: its own (one analysis each, so a point with its error bar)
    assert [c.get_label() for c in fig.axes[0].containers] == ["VAE_rpl"]


def test_a_panel_spanning_more_than_a_decade_is_log_scaled(tmp_path):
    """One learner 40x worse than another (a forgetting VAE_v0 against PRED): that panel is
    drawn on a log axis, the others stay linear from 0."""
    history = _history()
    for r in history:
        if r["learner"] == "VAE" and r["test_set"] == "pi_rand":
            r["errors"]["x"] = 12.0
    fig = evaluation.plot_alignment(history, tmp_path / "log.png")
    by_title = {ax.get_title(): ax for ax in fig.axes}
    assert by_title["x (pi_rand) (log)"].get_yscale() == "log"
    assert by_title["x (pi_curr)"].get_yscale() == "linear"
    assert by_title["x (pi_curr)"].get_ylim()[0] == 0.0
    assert by_title["theta (pi_rand)"].get_yscale() == "linear"


def test_distortion_plot_band_is_a_90_percent_interval(tmp_path):
    fig = evaluation.plot_distortion(_history(), tmp_path / "distortion.png")
    assert _png(tmp_path / "distortion.png")
    ax = fig.axes[0]
    labels = [line.get_label() for line in ax.lines]
    assert labels == ["VAE (pi_curr)", "VAE (pi_rand)", "PRED (pi_curr)", "PRED (pi_rand)"]
    runs = np.array([0.6, 0.61, 0.62])
    np.testing.assert_allclose(ax.lines[0].get_ydata(), runs.mean())
    band = ax.collections[0].get_paths()[0].vertices[:, 1]
    half = 2.9199856 * runs.std(ddof=1) / math.sqrt(3)  # Student t, 2 dof, 95th percentile
    assert band.max() == pytest.approx(runs.mean() + half, rel=1e-6)
    assert band.min() == pytest.approx(runs.mean() - half, rel=1e-6)


def test_bad_histories_raise(tmp_path):
    with pytest.raises(ValueError, match="empty"):
        evaluation.plot_alignment([], tmp_path / "a.png")
    with pytest.raises(ValueError, match="lacks"):
        evaluation.plot_alignment([{"step": 0, "errors": {"x": 1.0}}], tmp_path / "a.png")
    no_distortion = evaluation.history_records(0, "VAE", {"pi_rand": [0.1] * 4}, NAMES)
    with pytest.raises(ValueError, match="distortion"):
        evaluation.plot_distortion(no_distortion, tmp_path / "d.png")
    with pytest.raises(ValueError, match="names"):
        evaluation.history_records(0, "VAE", {"pi_rand": [0.1] * 3}, NAMES)


def test_the_constant_predictor_is_drawn_dashed_where_records_carry_it(tmp_path):
    history = [{"step": s, "learner": "PRED", "test_set": "pi_rand", "run": run,
                "errors": {"x": 0.5 / s, "v": 0.9}, "baseline": {"x": 1.0 + run, "v": 2.0}}
               for s in (1, 2) for run in (0, 1)]
    fig = evaluation.plot_alignment(history, tmp_path / "a.png")
    x_panel, v_panel = fig.axes[:2]
    (dashed,) = [ln for ln in x_panel.get_lines() if ln.get_label() == "constant predictor"]
    assert dashed.get_linestyle() == "--"
    np.testing.assert_allclose(dashed.get_xdata(), [1, 2])
    np.testing.assert_allclose(dashed.get_ydata(), [1.5, 1.5])  # the runs' mean
    assert [t.get_text() for t in x_panel.get_legend().get_texts()] == ["PRED",
                                                                        "constant predictor"]
    assert any(ln.get_label() == "constant predictor" for ln in v_panel.get_lines())
    plain = evaluation.plot_alignment([{k: v for k, v in r.items() if k != "baseline"}
                                       for r in history], tmp_path / "b.png")
    assert not [ln for ln in plain.axes[0].get_lines() if ln.get_label() == "constant predictor"]


def test_the_true_state_floor_is_a_dotted_line_at_its_mean_over_the_panels_names(tmp_path):
    """`floor` (a run's true-state reference row) is drawn in each test set's panels at the
    mean over the panel's names, in the legend, and not on a set it has no row for; a floor
    near 0 leaves the panel's axis linear."""
    history = [{"step": s, "learner": "PRED", "test_set": t, "run": 0,
                "errors": {"x": 0.5, "v": 0.9}, "baseline": {"x": 1.0, "v": 2.0}}
               for s in (1, 2) for t in ("pi_rand", "pi_curr")]
    floor = {"pi_rand": {"x": 0.001, "v": 0.3}}
    fig = evaluation.plot_alignment(history, tmp_path / "a.png",
                                    groups={"x": ["x"], "both": ["x", "v"]}, floor=floor)
    (x_line,) = [ln for ln in fig.axes[0].get_lines() if ln.get_label() == "true state"]
    (both_line,) = [ln for ln in fig.axes[1].get_lines() if ln.get_label() == "true state"]
    assert x_line.get_linestyle() == ":" and list(x_line.get_ydata()) == [0.001, 0.001]
    assert both_line.get_ydata()[0] == pytest.approx(0.1505)
    assert not [ln for ax in fig.axes[2:] for ln in ax.get_lines()
                if ln.get_label() == "true state"]  # pi_curr: no row
    assert fig.axes[0].get_yscale() == "linear"
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == [
        "PRED", "constant predictor", "true state"]


def test_a_runs_floor_is_its_references_true_state_by_name():
    from jaml.stream.rundir import _floor

    refs = {"epoch": 4, "true_state": {"pi_rand": [0.1, 0.2], "validation": [0.3, 0.4]},
            "constant": {"pi_rand": [1.0, 1.0]}}
    assert _floor(refs, ["x", "v"]) == {"pi_rand": {"x": 0.1, "v": 0.2},
                                        "validation": {"x": 0.3, "v": 0.4}}
    assert _floor(None, ["x", "v"]) is None
    with pytest.raises(ValueError):
        _floor(refs, ["x"])


def test_an_infinite_distortion_is_drawn_trimmed_with_its_count_or_said_in_words(tmp_path):
    """Steps 1 and 3 finite (solid), step 2 +inf with a trimmed figure (a dashed point whose
    label gives the pairs left out); a history that is +inf throughout and carries no trimmed
    figure draws no curve and says so."""
    records = []
    for step, exact, trimmed, left in ((1, 0.5, 0.5, 0), (2, math.inf, 0.7, 3), (3, 0.4, 0.4, 0)):
        records += [r | {"distortion_trimmed": trimmed, "distortion_left_out": left}
                    for r in evaluation.history_records(step, "VAE", {"pi_rand": [0.1] * 4},
                                                        NAMES, exact)]
    ax = evaluation.plot_distortion(records, tmp_path / "d.png").axes[0]
    solid, dashed = ax.lines
    np.testing.assert_array_equal(solid.get_xdata(), [1, 3])
    np.testing.assert_allclose(solid.get_ydata(), [0.5, 0.4])
    assert dashed.get_linestyle() == "--" and list(dashed.get_xdata()) == [2]
    assert dashed.get_ydata()[0] == pytest.approx(0.7)
    assert dashed.get_label() == "VAE: +inf, trimmed (3 collapsed pairs left out)"
    infinite = evaluation.history_records(1, "VAE", {"pi_rand": [0.1] * 4}, NAMES, math.inf)
    ax = evaluation.plot_distortion(infinite, tmp_path / "e.png").axes[0]
    assert not ax.lines and "+inf at every analysis" in ax.texts[0].get_text()
    assert _png(tmp_path / "e.png")


def test_a_lone_analysis_is_drawn_as_a_point_with_its_interval(tmp_path):
    """A line and a band of one point draw nothing: a history of one analysis (a run stopped
    early) shows each curve as a marker with an error bar spanning the runs' 90 % interval."""
    history = [r for r in _history() if r["step"] == 100]
    fig = evaluation.plot_alignment(history, tmp_path / "a.png")
    ax = fig.axes[0]  # x (pi_curr)
    vae = next(c for c in ax.containers if c.get_label() == "VAE")
    point, _, (bar,) = vae
    assert point.get_marker() == "o"
    np.testing.assert_allclose(point.get_xdata(), [100])
    runs = np.array([r["errors"]["x"] for r in history
                     if (r["learner"], r["test_set"]) == ("VAE", "pi_curr")])
    half = 2.9199856 * runs.std(ddof=1) / math.sqrt(3)  # Student t, 2 dof, 95th percentile
    np.testing.assert_allclose(bar.get_segments()[0][:, 1],
                               [runs.mean() - half, runs.mean() + half], rtol=1e-6)
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["VAE", "PRED"]
    fig = evaluation.plot_distortion(history, tmp_path / "d.png")
    assert {c.get_label() for c in fig.axes[0].containers} == {
        "VAE (pi_curr)", "VAE (pi_rand)", "PRED (pi_curr)", "PRED (pi_rand)"}
