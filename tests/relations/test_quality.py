"""Guards of a fit: degenerate data refused or handled before training, `holds` calibrated to
its recall, a relation that cannot separate dropped, and the quality report's measures checked
against closed forms."""

import logging
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml import relations, sources
from jaml.relations import quality, relation_set
from jaml.relations.data import MIN_ROWS, padded_box, prepare
from jaml.relations.networks import Relation
from jaml.relations.relation_set import RelationSet


def _circle(n, z=0.3, seed=0):
    t = np.random.default_rng(seed).uniform(0, 2 * np.pi, n)
    return np.stack([np.cos(t), np.sin(t), np.full(n, z)], -1).astype(np.float32)


def test_nan_rows_are_refused_with_the_fix():
    rows = _circle(256)
    rows[[3, 7], 1] = np.nan
    with pytest.raises(ValueError, match=r"2 rows, first at row 3: drop them first"):
        relations.fit(rows, relations.Config(max_relations=1))


def test_too_few_rows_are_refused_before_training(tmp_path):
    """Rows or a file: the refusal names the data and its count once."""
    with pytest.raises(ValueError, match=f"^on_manifold data: {MIN_ROWS - 1} rows, at least "
                                         f"{MIN_ROWS} are needed"):
        relations.fit(_circle(MIN_ROWS - 1), relations.Config(max_relations=1))
    path = tmp_path / "few.npy"
    np.save(path, np.asarray(_circle(10)))
    with pytest.raises(ValueError, match=f"^{re.escape(str(path))}: 10 rows, at least"):
        relations.fit(sources.make(str(path)), relations.Config(max_relations=1))


def test_a_constant_column_pads_its_box_and_says_which_relation_it_is(caplog):
    rows = _circle(1000)
    with caplog.at_level(logging.WARNING, logger="jaml.relations.data"):
        low, high = padded_box(rows.min(0), rows.max(0), ("x", "y", "z"))
    assert "z is constant (0.3): it is the relation z = 0.3" in caplog.text
    np.testing.assert_allclose(high - low, [2.0, 2.0, 0.2], atol=1e-3)  # 10 % of the widest
    np.testing.assert_allclose((low + high)[2] / 2, 0.3, atol=1e-6)


def test_a_narrow_column_is_named_by_its_spread_not_its_mean(caplog):
    """A column ×1000 makes the others "nearly constant": the warning gives their spread
    against the widest column's and says to divide each by its spread."""
    rows = np.stack([1000 * np.cos(np.linspace(0, 6, 500)), np.sin(np.linspace(0, 6, 500))], 1)
    with caplog.at_level(logging.WARNING, logger="jaml.relations.data"):
        padded_box(rows.min(0), rows.max(0), ("x", "y"))
    assert "y spans 2, under 1% of the widest column's 2e+03" in caplog.text
    assert "divide each by its spread first" in caplog.text


def test_a_constant_columns_figure_box_is_padded_as_the_fits_box():
    """The zero-set figure's box: a constant column gets the side the fit pads it to (a zero
    side made matplotlib warn of a singular transform), the others their range × scale."""
    from jaml.relations.plots import _box

    low, high = _box(np.asarray(_circle(1000)), 1.2)
    np.testing.assert_allclose(high - low, [2.4, 2.4, 0.24], atol=1e-3)


def test_held_out_rows_never_train():
    rows = np.random.default_rng(1).normal(size=(5000, 3)).astype(np.float32)
    batches = prepare(rows, 256, 0.0, jax.random.key(0), 4)
    train = {tuple(r) for r in np.asarray(batches.rows)}
    held = {tuple(r) for r in np.asarray(batches.held_out)}
    assert len(held) == 500 and not train & held and len(train) + len(held) == 5000


def _random_set(seed=0):
    params = Relation(8, 2).init(jax.random.key(seed), jnp.zeros((1, 3)))
    return RelationSet.empty(3, 2, 1.5).append(params, 0.05, 1.0, 8)


def test_holds_by_distance_measures_the_distance_to_the_zero_set_to_first_order(tmp_path):
    """A point of g = 0 moved by ε along the unit gradient is ε from the zero set: `distances`
    reads ε (to first order, whatever g's slope there); `calibrated` sets both tolerances at
    the RECALL quantile of their measures; a checkpoint keeps the distance tolerance, one written
    before it holds by value, and by distance then needs a tolerance."""
    rs = _random_set()
    start = jax.random.normal(jax.random.key(4), (64, 3)) * 0.3
    on = relations.project(rs, start, steps=50)
    points = np.asarray(on.points)[np.asarray(on.converged)]
    assert len(points) >= 32
    g = rs.relation(0)
    normals = np.array(jax.vmap(jax.grad(lambda t: g(t[None])[0]))(jnp.asarray(points)))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    for eps in (1e-3, 1e-2):
        got = np.asarray(relations.distances(rs, points + eps * normals))[:, 0]
        np.testing.assert_allclose(got, eps, rtol=0.05)
    rows = jax.random.normal(jax.random.key(1), (4096, 3)) * 0.2
    fitted = quality.calibrated(rs, rows)
    d = np.asarray(relations.distances(rs, rows))[:, 0]
    assert fitted.distance_tolerance == pytest.approx((np.quantile(d, quality.RECALL),),
                                                      rel=1e-5)
    assert fitted.tolerance == pytest.approx(quality.calibrated_tolerance(rs, rows), rel=1e-6)
    assert float(np.mean(relations.holds(fitted, rows))) == pytest.approx(quality.RECALL,
                                                                          abs=1e-3)
    relations.save(fitted, tmp_path / "new")
    assert relations.load(tmp_path / "new").distance_tolerance == fitted.distance_tolerance
    relations.save(rs, tmp_path / "old")  # no distance tolerance: as written before it
    old = relations.load(tmp_path / "old")
    np.testing.assert_array_equal(relations.holds(old, rows),
                                  relations.holds(old, rows, by="value"))
    with pytest.raises(ValueError, match="no distance_tolerance"):
        relations.holds(old, rows, by="distance")


def test_per_relation_distance_tolerances_against_the_closed_form():
    """Two independent relations whose distances on the rows are |N(0, σ_k)|: every relation
    holds on a RECALL share of rows where each column's share is √RECALL, so t_k = σ_k ·
    Φ⁻¹((1 + √RECALL) / 2). The fuzzy relation (σ 100× wider) keeps its width to itself; one
    tolerance for both (the largest distance's quantile) was the fuzzy one's for both."""
    from scipy.stats import norm

    sigma = np.array([0.001, 0.1])
    d = np.abs(np.random.default_rng(0).normal(size=(400_000, 2))) * sigma
    t = np.asarray(quality.joint_quantiles(d, quality.RECALL))
    np.testing.assert_allclose(t, sigma * norm.ppf((1 + np.sqrt(quality.RECALL)) / 2), rtol=0.02)
    assert np.mean(np.all(d < t, -1)) == pytest.approx(quality.RECALL, abs=1e-4)
    assert np.quantile(d.max(-1), quality.RECALL) > 50 * t[0]  # the one shared tolerance
    one = d[:, :1]
    assert quality.joint_quantiles(one, quality.RECALL) == pytest.approx(
        (np.quantile(one, quality.RECALL),), rel=1e-12)
    d[:3_000, 0] = np.inf  # 0.75 % of rows where g_1 is flat: still calibrated
    assert quality.joint_quantiles(d, quality.RECALL) is not None
    d[3_000:6_000, 1] = np.inf  # and 0.75 % others where g_2 is: 1.5 % of rows, not
    assert quality.joint_quantiles(d, quality.RECALL) is None


def test_holds_checks_each_relation_at_its_own_tolerance(tmp_path, monkeypatch):
    """`holds` by distance is every distance below its relation's tolerance (a plain numpy
    check); a number holds every relation to it; a checkpoint keeps the tuple, and one written
    with a single tolerance (before per-relation ones) holds every relation to that."""
    rs = _random_set().append(Relation(8, 2).init(jax.random.key(1), jnp.zeros((1, 3))),
                              0.05, 1.0, 8)
    rows = jax.random.normal(jax.random.key(2), (2048, 3)) * 0.2
    d = np.asarray(relations.distances(rs, rows))
    t = tuple(float(x) for x in np.quantile(d, [0.2, 0.9], axis=0).diagonal())
    tight = rs.replace(distance_tolerance=t)
    np.testing.assert_array_equal(relations.holds(tight, rows), np.all(d < np.asarray(t), -1))
    np.testing.assert_allclose(relation_set.holds_measure(tight, rows),
                               np.max(d / np.asarray(t), -1), rtol=1e-6)
    np.testing.assert_array_equal(relations.holds(tight, rows, tolerance=0.05),
                                  np.all(d < 0.05, -1))
    assert rs.replace(distance_tolerance=0.05).distance_tolerance == (0.05, 0.05)
    assert tight.select([1]).distance_tolerance == (t[1],)
    assert f"holds within {t[0]:.3g} / {t[1]:.3g}" in repr(tight)
    relations.save(tight, tmp_path / "new")
    assert relations.load(tmp_path / "new").distance_tolerance == pytest.approx(t)
    from jaml.relations import checkpoint

    describe = checkpoint._describe
    monkeypatch.setattr(checkpoint, "_describe",
                        lambda r: describe(r) | {"distance_tolerance": 0.05})
    relations.save(tight, tmp_path / "old")
    np.testing.assert_array_equal(relations.holds(relations.load(tmp_path / "old"), rows),
                                  np.all(d < 0.05, -1))


def test_holds_calibrated_on_rows_accepts_that_share_of_fresh_rows():
    """The tolerance is the RECALL quantile of max_k |g_k| / on-mean on calibration rows, so
    fresh rows of the same law pass at that rate (binomial spread: ±1 % at 8,192 rows)."""
    rs = _random_set()
    calib = jax.random.normal(jax.random.key(1), (8192, 3)) * 0.2
    fresh = jax.random.normal(jax.random.key(2), (8192, 3)) * 0.2
    tol = quality.calibrated_tolerance(rs, calib)
    ratio = np.abs(np.asarray(relations.evaluate(rs, calib)))[:, 0] / 0.05
    assert tol == pytest.approx(np.quantile(ratio, quality.RECALL), rel=1e-5)
    recall = float(np.mean(relations.holds(rs.replace(tolerance=tol), fresh)))
    assert abs(recall - quality.RECALL) < 0.01


def test_data_codimension_of_a_curve_a_surface_and_a_plane_in_r4():
    key = jax.random.key(3)
    circle = _circle(4000)
    u = np.random.default_rng(2).normal(size=(4000, 3))
    sphere = u / np.linalg.norm(u, axis=1, keepdims=True)
    s0v0 = np.random.default_rng(3).uniform(-1, 1, (4000, 2))
    block = np.concatenate([s0v0, s0v0 @ np.array([[1.0, 0.0], [1.0, 1.0]]) + 0.5], -1)
    assert quality.data_codimension(circle, key) == 2
    assert quality.data_codimension(sphere, key) == 1
    assert quality.data_codimension(block, key) == 2


def _band_rows(width: float, noise: bool = False, n: int = 16_384):
    """A surface in R⁴ over (a, b) ∈ [-1, 1]²: c = 0.3a + 0.2b exactly, and d = ab/2 either
    filling a band of ± `width` uniformly, or (noise) with both c and d scattered alike."""
    rng = np.random.default_rng(5)
    a, b = rng.uniform(-1, 1, (2, n))
    if noise:
        c, d = rng.normal(size=(2, n)) * width / np.sqrt(3)
        return np.stack([a, b, 0.3 * a + 0.2 * b + c, 0.5 * a * b + d], -1)
    return np.stack([a, b, 0.3 * a + 0.2 * b, 0.5 * a * b + width * rng.uniform(-1, 1, n)], -1)


def test_a_band_across_the_rows_is_told_from_an_exact_relation_and_from_noise():
    """The local PCA counts a thin band as a second direction off the rows (codimension 2);
    `band_directions` finds it scattered as a uniform band is (width/√3 over the box diagonal,
    less what each neighbourhood's quadratic fit absorbs), and the exact direction not at all.
    Noise of that size on both directions, and the clean ellipse, have no band."""
    key = jax.random.key(5)
    rows = _band_rows(0.02)
    assert quality.data_codimension(rows, key) == 2
    band = quality.band_directions(rows, 2, key)
    diag = np.linalg.norm(rows.max(0) - rows.min(0))
    assert band["bands"] == 1 and band["scatter"][0] < 1e-12
    # RMS of uniform ± 0.02, less the 6 parameters each 32-row neighbourhood's quadratic fits.
    expected = 0.02 / np.sqrt(3) * np.sqrt((32 - 6) / 32) / diag
    assert band["scatter"][1] == pytest.approx(expected, rel=0.1)
    noisy = _band_rows(0.02, noise=True)
    assert quality.data_codimension(noisy, key) == 2
    assert quality.band_directions(noisy, 2, key)["bands"] == 0
    assert quality.band_directions(_ellipse_rows()[0], 2, key)["bands"] == 0
    assert quality.band_directions(_band_rows(0.002), 2, key)["bands"] == 0  # under 0.1 %


def test_a_fit_takes_a_band_off_the_codimension_and_says_so(caplog):
    """Rows with one exact relation and a band: the fit's codimension is 1, and its log and
    report say that the local PCA's 2 lost a band direction (what the relations then are is
    measured on the MJX incline's rows, docs/results/aml_quality.md)."""
    with caplog.at_level(logging.INFO, logger="jaml.relations"):
        rs = relations.fit(_band_rows(0.02), relations.Config(max_relations=1, max_steps=500))
    ind = rs.quality["independence"]
    assert ind["data_codimension"] == 1
    assert ind["data_codimension_from"] == "by local PCA, less 1 band direction"
    assert any("a band, not a relation; fitting codimension 1 (Config.codimension=2 fits a "
               "relation there)" in r.getMessage() for r in caplog.records)


def _ellipse_rows():
    """20,000 rows of the ellipse (√2 cos t, 2 sin t − 1, sin t − 1), t uniform, and their box."""
    t = np.random.default_rng(4).uniform(0, 2 * np.pi, 20_000)
    curve = np.stack([np.sqrt(2) * np.cos(t), 2 * np.sin(t) - 1, np.sin(t) - 1], -1)
    return curve, curve.min(0), curve.max(0)


def _ellipse_relations(tau):
    """Its two exact relations: the plane y = 2z + 1 and the hyperboloid x² + y² − 2z² = 1."""
    x, y, z = (tau[..., i] for i in range(3))
    return jnp.stack([y - 2 * z - 1, x**2 + y**2 - 2 * z**2 - 1], -1)


def test_the_true_ellipse_relations_land_every_box_point_and_a_spurious_pair_does_not():
    """The landing measure against closed forms: plane ∩ hyperboloid is the ellipse; plane ∩
    (hyperboloid · another plane) adds a line across it, which catches projected points."""
    curve, low, high = _ellipse_rows()

    def spurious(tau):
        g = _ellipse_relations(tau)
        return jnp.stack([g[..., 0], g[..., 1] * tau[..., 0]], -1)  # also x = 0 in the plane

    within = quality.landing_distance(curve, curve[:1024], low, high)
    good, _, _ = quality.landing(_ellipse_relations, jax.random.key(5), low, high, curve,
                                 within, tolerance=1e-4)
    bad, _, _ = quality.landing(spurious, jax.random.key(5), low, high, curve, within,
                                tolerance=1e-4)
    assert good["landed"] >= 0.97 and good["spurious"] <= 0.01, good
    assert bad["spurious"] >= 0.1 and bad["landed"] <= good["landed"] - 0.1, bad


def test_a_third_relation_cutting_the_ellipse_to_two_points_lands_all_and_reaches_little():
    """Coverage against closed forms: plane ∩ hyperboloid is the whole ellipse, so its landed
    points reach about what as many of the data's own rows do; adding x = 0 leaves two points
    of it, (0, 1, 0) and (0, -3, -2), where every box point still lands: the landing share
    misses the cut, the coverage and the report's warning do not."""
    curve, low, high = _ellipse_rows()

    def cut(tau):
        return jnp.concatenate([_ellipse_relations(tau), tau[..., :1]], -1)

    within = quality.landing_distance(curve, curve[:1024], low, high)
    whole, _, _ = quality.landing(_ellipse_relations, jax.random.key(5), low, high, curve,
                                  within, tolerance=1e-4)
    points, _, _ = quality.landing(cut, jax.random.key(5), low, high, curve, within,
                                   tolerance=1e-4)
    assert whole["coverage"] >= 0.9 * whole["coverage_of_rows"] >= 0.85, whole
    assert points["landed"] >= 0.9, points  # every converged point is on the curve
    # The rows the two points reach: t within `within` / |d curve / dt| of each (the speed is
    # √2 where cos t = 0), t uniform over 2π.
    expected = 2 * (2 * within / np.sqrt(2)) / (2 * np.pi)
    assert abs(points["coverage"] - expected) < 0.02, (points, expected)
    report = {"relations": [{"index": j, "status": "done", "ratio": 100.0} for j in (1, 2, 3)],
              "independence": {"median_abs_cos": np.eye(3).tolist()}, "landing": points}
    assert [w for w in quality._warnings(report) if "smaller than the data" in w] == [
        f"the landed points reach {100 * points['coverage']:.0f}% of the data's rows, where as "
        f"many of its own rows reach {100 * points['coverage_of_rows']:.0f}%: the zero set is "
        "smaller than the data (a relation vanishes on part of it, or two near-coincident "
        "relations cut it)"]
    report["landing"] = whole
    assert not [w for w in quality._warnings(report) if "smaller than the data" in w]


def test_a_zero_set_going_on_past_the_samples_edge_is_not_spurious_and_a_parallel_one_is():
    """Rows of the plane z = 0 drawn only for x ≤ 0.5, a box reaching x = 1; g = z (z − 0.3)
    vanishes on the whole plane and on the plane z = 0.3 too. Box points move along z only
    (g's gradient), to the nearer root: z = 0 for z < 0.15 (half the box's z range), x as
    drawn. So a quarter land on the rows, a quarter on the plane past their edge (extends),
    half on z = 0.3 (spurious), whatever the sample's spacing."""
    rows = np.random.default_rng(6).uniform((0, 0, 0), (0.5, 1, 0), (4000, 3))
    low, high = np.array([0.0, 0.0, -0.2]), np.array([1.0, 1.0, 0.5])
    land, points, _ = quality.landing(lambda t: (t[..., 2] * (t[..., 2] - 0.3))[..., None],
                                      jax.random.key(7), low, high, rows, 0.03, tolerance=1e-4)
    assert land["converged"] == 1.0
    for share, expected in (("landed", 0.25), ("extends", 0.25), ("spurious", 0.5)):
        assert abs(land[share] - expected) < 0.07, (share, land)
    np.testing.assert_allclose(points[:, 2], 0.3, atol=1e-3)  # the spurious points returned


def test_uniform_noise_has_no_relation_and_the_capped_one_is_dropped(caplog):
    """Rows filling their box have nothing that vanishes on them and nowhere else: g_1 caps
    without separating (from each of its 2 initialisations, 300 steps each, then a refinement
    round of 60: its zero set, a surface through the box, is off the rows' 2-D tangent space
    given by codimension 1; then its other start again with the gradient push capped, then
    both at a smaller step: 5 trainings of 360 steps) and is dropped, not returned as a
    relation."""
    rows = np.random.default_rng(5).uniform(-1, 1, (4096, 3)).astype(np.float32)
    cfg = relations.Config(max_relations=2, max_steps=300, chunk_steps=100, stop_patience=20,
                           batch_size=256, eval_batches=2, codimension=1, premine_attempts=2)
    with caplog.at_level(logging.WARNING, logger="jaml.relations"):
        rs = relations.fit(rows, cfg)
    assert rs.num_relations == 0
    assert "relation 1 is not a relation (capped; 1800 steps in all its trainings" in caplog.text


def test_only_a_relation_known_to_have_missed_its_stopping_rule_is_warned_of():
    """"restored" (a checkpoint's relation whose end its record does not hold) is no warning;
    "capped" is."""
    report = {"relations": [{"index": 1, "status": "restored", "ratio": 160.0},
                            {"index": 2, "status": "capped", "ratio": 3.0}],
              "independence": {"median_abs_cos": [[1.0, 0.0], [0.0, 1.0]]},
              "landing": {"converged": 1.0, "spurious": 0.0, "within": 0.05}}
    assert quality._warnings(report) == [
        "g2 capped: it did not meet the stopping rule (held-out off/on 3.0)"]


@pytest.mark.parametrize("index, codim_from, hinted", [
    (2, "by local PCA", True), (2, "given", False), (1, "by local PCA", False),
    (3, "by local PCA", False)])
def test_a_capped_relation_the_local_pca_asked_for_names_the_codimension_to_give(
        index, codim_from, hinted):
    """A relation at or below the estimated codimension that caps may stand for a thin band
    of the rows, not a relation (the MJX incline with mass and friction drawn): its warning
    names `Config.codimension` one lower. Not where the codimension was given, not for g1 (the
    codimension cannot be 0) and not beyond the codimension."""
    report = {"relations": [{"index": index, "status": "capped", "ratio": 3.6}],
              "independence": {"median_abs_cos": [[1.0]], "data_codimension": 2,
                               "data_codimension_from": codim_from},
              "landing": {"converged": 1.0, "spurious": 0.0, "within": 0.05}}
    capped = f"g{index} capped: it did not meet the stopping rule (held-out off/on 3.6)"
    hint = ("; the data's codimension 2 is the local PCA's estimate: if the rows only keep "
            "near a surface there (a band, not a relation), set Config.codimension=1")
    assert quality._warnings(report) == [capped + (hint if hinted else "")]


@pytest.mark.parametrize("converged, warned", [(0.68, True), (0.95, False)])
def test_box_points_that_reach_no_zero_are_warned_of(converged, warned):
    """Points `project` leaves unconverged are neither on the data nor spurious: more than a
    tenth of them is a warning of its own (seed 2 of the noisy ellipse: 32 %, no other)."""
    report = {"relations": [{"index": 1, "status": "done", "ratio": 160.0}],
              "independence": {"median_abs_cos": [[1.0]]},
              "landing": {"converged": converged, "spurious": 0.0, "within": 0.05}}
    found = [w for w in quality._warnings(report) if "reach no zero" in w]
    assert found == ([f"{100 * (1 - converged):.0f}% of projected box points reach no zero of "
                      "the relations: `project` leaves them where the relations cannot all "
                      "vanish (a relation level but not zero away from the data), with "
                      "converged False"] if warned else [])


@pytest.mark.parametrize("attempts", [1, 3])
def test_a_codimension_one_relation_landing_away_from_the_data_is_tried_from_another_start(
        monkeypatch, attempts):
    """The circle's one relation (no earlier zero set to pre-mine) is trained again from
    another initialisation while its zero set has parts away from the data, up to
    `premine_attempts` trainings, and the one landing most is kept; with one attempt, the
    last resorts train it again (the landing measured by the fit is stood in for: the first
    training's lands half away, the next one's all on)."""
    from jaml.relations import training

    trainings, lands = [], iter([0.5, 0.0, 0.0])
    real_fit_relation, real_refine = training._fit_relation, training._refine

    def counting(*args, **kwargs):
        trainings.append(kwargs.get("phase", "relation"))
        return real_fit_relation(*args, **kwargs)

    def landing(*args, **kwargs):
        fitted, land, rounds, spent = real_refine(*args, **kwargs)
        spurious = next(lands)
        return (fitted._replace(off_mean=100 * fitted.on_mean),
                {**land, "spurious": spurious, "landed": 1 - spurious}, rounds, spent)

    monkeypatch.setattr(training, "_fit_relation", counting)
    monkeypatch.setattr(training, "_refine", landing)
    rs = relations.fit(sources.make("circle"), relations.Config(
        max_relations=1, max_steps=40, chunk_steps=20, batch_size=64, stop_patience=1,
        eval_batches=2, refine_rounds=0, premine_attempts=attempts))
    assert trainings == ["relation"] * 2  # with one attempt, the second is a last resort's
    assert rs.num_relations == 1


@pytest.mark.parametrize("away, ratio, codim, kept", [
    (0.04, 2.7, 2, True),  # the round halves the share landing away: it may separate less
    (0.20, 2.7, 2, False),  # it does not halve it: not below the stopping rule's ratio
    (0.20, 6.0, 2, True),  # it separates at the bar: kept for landing more
    (0.04, 1.5, 2, False),  # not below what keeps a relation
    (0.04, 2.7, 1, False),  # beyond the codimension a relation must separate fully
])
def test_a_refining_round_that_halves_the_share_landing_away_may_separate_less(
        monkeypatch, away, ratio, codim, kept):
    """g_2 (off/on 5.5, 26 % of projected box points landing away) refined one round: the
    round is kept where more points land on the data and g_2 separates down to the stopping
    rule's ratio, or, for the relation completing the codimension, down to the ratio that keeps
    a relation where the round at least halves the share landing away (the round's landing and
    off/on stood in for)."""
    from types import SimpleNamespace

    from jaml.relations import training
    from jaml.relations.loop import CAPPED as CAPPED_STATUS

    lands = iter([{"landed": 0.74, "spurious": 0.26}, {"landed": 1 - away, "spurious": away}])
    state = SimpleNamespace(step=jnp.asarray(10), status=jnp.asarray(CAPPED_STATUS), params={})
    monkeypatch.setattr(training, "mine", lambda *args, **kwargs: (None, next(lands)))
    monkeypatch.setattr(training, "_fit_relation", lambda *args, **kwargs: state)
    monkeypatch.setattr(training, "_grow", lambda *args, **kwargs: ("refined", 1.0, ratio))
    start = training._Fitted(state, "start", 1.0, 5.5, CAPPED_STATUS)
    fitted, land, rounds, _ = training._refine(
        relations.Config(refine_rounds=1), None, SimpleNamespace(num_relations=1), None, 8,
        start, 0.05, codim, None, *jax.random.split(jax.random.key(0), 3))
    assert (fitted.grown, rounds) == (("refined", 1) if kept else ("start", 0))
    assert land["spurious"] == (away if kept else 0.26)


PLAIN, CAPPED, SLOWER = (None, 1e-3), (0.1, 1e-3), (None, 3e-4)  # (gradient cap, step size)


@pytest.mark.parametrize("ratios, kept", [
    ((3.0, 10.0), 10.0),  # the second start separates: kept, nothing more
    ((3.0, 2.5, 2.0, 12.0), 12.0),  # none of the starts does, the first capped one does
    ((3.0, 2.5, 4.0, 1.0, 1.0, 1.0, 1.0, 1.0), 4.0),  # nothing does: the one separating most
    ((3.0, 2.5, 2.0, 1.0, 1.0, 1.0, 1.0, 1.0), 3.0),  # the first separates most: kept
    ((8.0,), 8.0),  # the first separates: no other start
])
def test_a_relation_below_the_codimension_capped_without_separating_gets_other_starts(
        monkeypatch, ratios, kept):
    """The ellipse's g_1 (codimension 2: nothing refined or landed yet) that ends capped
    separating less than the bar trains again from other initialisations (up to
    `premine_attempts` trainings), then as the last resorts train (−log‖∇g‖ capped from the
    second start on, then every start at a smaller step), until one separates; the one
    separating most is kept (the recorded off/on of each training stood in for; every
    training ends capped)."""
    from jaml.relations import training
    from jaml.relations.loop import CAPPED as CAPPED_STATUS

    given, trainings = iter(ratios), []
    real_grow, real_fit_relation = training._grow, training._fit_relation

    def capped(cfg, *args, **kwargs):
        trainings.append((cfg.gradient_cap, cfg.learning_rate))
        state = real_fit_relation(cfg, *args, **kwargs)
        return state.replace(status=jnp.asarray(CAPPED_STATUS))

    def separating(*args, **kwargs):
        grown, on_mean, _ = real_grow(*args, **kwargs)
        return grown, on_mean, next(given) * on_mean

    monkeypatch.setattr(training, "_fit_relation", capped)
    monkeypatch.setattr(training, "_grow", separating)
    summaries = []
    relations.fit(sources.make("ellipse"), relations.Config(
        max_relations=1, codimension=2, max_steps=40, chunk_steps=20, batch_size=64,
        stop_patience=1, eval_batches=2, premine_attempts=3),
        on_relation=lambda _, summary: summaries.append(summary))
    assert next(given, None) is None
    assert trainings == [PLAIN, PLAIN, PLAIN, CAPPED, CAPPED, SLOWER, SLOWER, SLOWER][
        :len(ratios)]
    assert summaries[0].ratio == pytest.approx(kept, rel=1e-5)




@pytest.mark.parametrize("ratios, trainings, kept", [
    ((1.5, 1.5, 100.0), [PLAIN, PLAIN, CAPPED], 1),  # the capped start separates: kept
    ((1.5, 100.0), [PLAIN, PLAIN], 1),  # the second start separates: nothing more
    ((1.5, 1.5, 1.5, 100.0), [PLAIN, PLAIN, CAPPED, SLOWER], 1),  # the slower first start does
    ((1.5,) * 5, [PLAIN, PLAIN, CAPPED, SLOWER, SLOWER], 0),  # none does: dropped, as before
])
def test_when_no_start_separates_the_starts_train_again_capped_then_at_a_smaller_step(
        monkeypatch, ratios, trainings, kept):
    """A relation that would be dropped (no start reaches off/on 2) gets its other starts
    again with −log‖∇g‖ pushing only up to ‖∇g‖ = RETRY_GRADIENT_CAP, then every start, the
    first one's parameters included, at RETRY_STEP_FACTOR of the step size; a fit where a start
    separates trains as it did (the recorded ratios stand in for the trainings')."""
    from jaml.relations import training

    seen, starts, given = [], [], iter(ratios)
    real_fit_relation, real_refine = training._fit_relation, training._refine

    def counting(cfg, batches, rs, params, *args, **kwargs):
        seen.append((cfg.gradient_cap, cfg.learning_rate))
        starts.append(np.concatenate([np.ravel(x) for x in jax.tree.leaves(params)]))
        return real_fit_relation(cfg, batches, rs, params, *args, **kwargs)

    def landing(*args, **kwargs):  # each training lands a little more than the one before
        fitted, land, rounds, spent = real_refine(*args, **kwargs)
        spurious = 0.05 - 0.01 * len(seen)
        return (fitted._replace(off_mean=next(given) * fitted.on_mean),
                {**land, "spurious": spurious, "landed": 1 - spurious, "extends": 0.0}, rounds,
                spent)

    monkeypatch.setattr(training, "_fit_relation", counting)
    monkeypatch.setattr(training, "_refine", landing)
    rs = relations.fit(sources.make("circle"), relations.Config(
        max_relations=1, max_steps=40, chunk_steps=20, batch_size=64, stop_patience=1,
        eval_batches=2, refine_rounds=0, premine_attempts=2))
    assert [(cap, pytest.approx(rate)) for cap, rate in seen] == trainings
    assert rs.num_relations == kept
    slower = starts[3:]  # the slower resort's starts are the plain ones, in order
    for again, plain in zip(slower, starts[: len(slower)], strict=True):
        np.testing.assert_array_equal(again, plain)
    assert (training.RETRY_GRADIENT_CAP, training.RETRY_STEP_FACTOR) == (0.1, 0.3)


def test_when_every_start_lands_away_from_the_data_the_starts_train_again_capped(monkeypatch):
    """Starts that separate (off/on 100) but land 30 % of projected box points away from the
    data send the relation to the last resorts too: the other start again with −log‖∇g‖
    capped, kept since it lands on the data (off/on 50 marks it), and nothing after it (the
    recorded shares stand in for the trainings')."""
    from jaml.relations import training

    seen, summaries = [], []
    real_fit_relation, real_refine = training._fit_relation, training._refine

    def counting(cfg, *args, **kwargs):
        seen.append((cfg.gradient_cap, cfg.learning_rate))
        return real_fit_relation(cfg, *args, **kwargs)

    def landing(*args, **kwargs):
        fitted, land, rounds, spent = real_refine(*args, **kwargs)
        ratio, spurious = (50.0, 0.0) if seen[-1] == CAPPED else (100.0, 0.3)
        return (fitted._replace(off_mean=ratio * fitted.on_mean),
                {**land, "spurious": spurious, "landed": 1 - spurious, "extends": 0.0}, rounds,
                spent)

    monkeypatch.setattr(training, "_fit_relation", counting)
    monkeypatch.setattr(training, "_refine", landing)
    relations.fit(sources.make("circle"), relations.Config(
        max_relations=1, max_steps=40, chunk_steps=20, batch_size=64, stop_patience=1,
        eval_batches=2, refine_rounds=0, premine_attempts=2),
        on_relation=lambda _, summary: summaries.append(summary))
    assert [(cap, pytest.approx(rate)) for cap, rate in seen] == [PLAIN, PLAIN, CAPPED]
    assert summaries[0].ratio == pytest.approx(50.0, rel=1e-5)


def _landing_by_g1(monkeypatch, first, again):
    """Every training separates (off/on 100), and every g_2 training lands `first` of the
    projected box points away under the fit's first g_1 and `again` under the one trained again
    (the fit's landing stood in for; no last resorts, for fewer compiles). Returns the
    `below_attempt` of each loop the fit runs (a paused loop's continuation: 0)."""
    from jaml.relations import training

    loops = []
    real_loop, real_refine, real_grow = training._fit_loop, training._refine, training._grow

    def separating(*args, **kwargs):
        grown, on_mean, _ = real_grow(*args, **kwargs)
        return grown, on_mean, 100 * on_mean

    def loop(*args, below_attempt=0, **kwargs):
        loops.append(below_attempt)
        return real_loop(*args, below_attempt=below_attempt, **kwargs)

    def landing(*args, **kwargs):
        fitted, land, rounds, spent = real_refine(*args, **kwargs)
        away = first if loops[-1] == 0 else again
        return (fitted._replace(off_mean=100 * fitted.on_mean),
                {**land, "spurious": away, "landed": 1 - away, "extends": 0.0}, rounds, spent)

    monkeypatch.setattr(training, "_fit_loop", loop)
    monkeypatch.setattr(training, "_refine", landing)
    monkeypatch.setattr(training, "_grow", separating)
    monkeypatch.setattr(training, "RETRY_GRADIENT_CAP", None)
    monkeypatch.setattr(training, "RETRY_STEP_FACTOR", None)
    return loops


_G1_AGAIN_CONFIG = relations.Config(
    max_relations=2, codimension=2, max_steps=40, chunk_steps=20, batch_size=64,
    stop_patience=1, eval_batches=2, refine_rounds=0, premine_attempts=2)


@pytest.mark.parametrize("first, again, attempts, kept", [
    (0.3, 0.0, 2, "again"),  # every g_2 start leaves 30 % away; under the other g_1 none: kept
    (0.3, 0.5, 2, "first"),  # under the other g_1 half land away: the first relations stay
    (0.05, 0.0, 2, None),  # the first lands (at most a tenth away): nothing trained again
    (0.3, 0.0, 1, None),  # one attempt (the legacy configs): nothing trained again
])
def test_where_every_start_of_the_codimension_th_relation_lands_away_g1_trains_again(
        monkeypatch, first, again, attempts, kept):
    """The ellipse (codimension 2): where every start of g_2 leaves more than a tenth of the
    projected box points away from the data, the fit runs again with g_1 from another start,
    keeping the relations under which more land on the data; the kept ones reach on_relation
    again. Trained again, g_1 and g_2 run the loops compiled for them the first time (the fit
    keeps its compiled loops): two programs, whatever ran."""
    from jaml.relations import training

    loops, seen, ran = _landing_by_g1(monkeypatch, first, again), [], []
    real_run = training.run_until_done

    def running(chunk, *args, **kwargs):
        ran.append(chunk)
        return real_run(chunk, *args, **kwargs)

    monkeypatch.setattr(training, "run_until_done", running)
    rs = relations.fit(sources.make("ellipse"), _G1_AGAIN_CONFIG.replace(
        premine_attempts=attempts), on_relation=lambda rs, summary: seen.append(
            (summary.index, rs.params[0], summary.landing)))
    assert loops == ([0] if kept is None else [0, 1, 0])
    assert len(set(map(id, ran))) == 2
    assert [index for index, _, _ in seen] == ([1, 2, 1, 2] if kept == "again" else [1, 2])
    g1_first, g1_kept = seen[0][1], seen[-1][1]
    assert seen[-1][2]["spurious"] == (again if kept == "again" else first)
    if kept == "again":  # g_1 from another start, and the fit returns it
        assert not all(np.array_equal(a, b) for a, b in zip(
            jax.tree.leaves(g1_first), jax.tree.leaves(g1_kept), strict=True))
    for a, b in zip(jax.tree.leaves(rs.params[0]), jax.tree.leaves(g1_kept), strict=True):
        np.testing.assert_array_equal(a, b)


def test_relations_beyond_the_codimension_train_once_on_the_relations_kept(monkeypatch):
    """With a third relation asked, a fit whose g_2 lands away on every start pauses there:
    g_1 and g_2 train again, and g_3 trains once, on the kept ones (not first on the set that
    is dropped)."""
    loops, seen = _landing_by_g1(monkeypatch, 0.3, 0.05), []
    rs = relations.fit(sources.make("ellipse"), _G1_AGAIN_CONFIG.replace(max_relations=3),
                       on_relation=lambda rs, summary: seen.append((summary.index, rs.params)))
    assert loops == [0, 1, 0]
    assert [index for index, _ in seen] == [1, 2, 1, 2, 3]
    assert rs.num_relations == 3
    for a, b in zip(jax.tree.leaves(rs.params[:2]), jax.tree.leaves(seen[3][1]), strict=True):
        np.testing.assert_array_equal(a, b)  # g_3 grows the set trained again


def test_a_run_directory_keeps_the_relations_trained_again_once(monkeypatch, tmp_path):
    """`relations.run` with g_1 trained again and kept: summary.json lists relations 1 and 2
    once, the kept ones (their landing), and the checkpoint holds them."""
    from jaml.relations import run as run_module

    loops = _landing_by_g1(monkeypatch, 0.3, 0.0)
    summary = run_module.run("ellipse", _G1_AGAIN_CONFIG, tmp_path / "run", progress=False)
    assert loops == [0, 1, 0]
    assert [r["index"] for r in summary["relations"]] == [1, 2]
    assert summary["relations"][1]["landing"]["spurious"] == 0.0
    saved = relations.load(tmp_path / "run" / "checkpoint")
    np.testing.assert_allclose(saved.on_means, [r["on_mean"] for r in summary["relations"]],
                               rtol=1e-6)


@pytest.mark.parametrize("trainings, kept", [
    (((2.2, 0.58), (2.25, 0.0), (2.6, 0.55)), 2.25),  # the clean pre-mined start stays
    (((2.2, 0.58), (2.25, 0.5), (2.6, 0.1)), 2.6),  # the plain training lands more: it replaces
    (((1.5, 0.0), (1.6, 0.0), (2.6, 0.05)), 2.6),  # the pre-mined one would be dropped
    (((2.2, 0.58), (2.25, 0.0), None), 2.25),  # without mined rows the loss turns non-finite
])
def test_training_again_without_mined_rows_replaces_a_pre_mined_relation_only_if_better(
        monkeypatch, trainings, kept):
    """The ellipse's g_2 (pre-mined, 2 starts) separates less than the bar, so it trains once
    more without mined rows; that training is kept only where more projected box points land
    on the data, or where the pre-mined one separates too little to be kept at all, and never
    where its loss turned non-finite (the recorded (off/on, spurious share) pairs stand in for
    the trainings', None for a non-finite one; g_1 separates)."""
    from jaml.relations import training
    from jaml.relations.loop import NONFINITE

    given = iter([t for t in trainings if t is not None])
    real_refine, real_grow, real_fit_relation = (training._refine, training._grow,
                                                 training._fit_relation)

    def plain(*args, **kwargs):  # the training without mined rows is the one given no pool
        state = real_fit_relation(*args, **kwargs)
        if "pool" not in kwargs and trainings[-1] is None:
            return state.replace(status=jnp.asarray(NONFINITE))
        return state

    def separating(*args, **kwargs):  # g_1 (not refined) separates
        grown, on_mean, _ = real_grow(*args, **kwargs)
        return grown, on_mean, 100 * on_mean

    def landing(*args, **kwargs):
        fitted, land, rounds, spent = real_refine(*args, **kwargs)
        ratio, spurious = next(given)
        return (fitted._replace(off_mean=ratio * fitted.on_mean),
                {**land, "spurious": spurious, "landed": 1 - spurious, "extends": 0.0},
                rounds, spent)

    monkeypatch.setattr(training, "_grow", separating)
    monkeypatch.setattr(training, "_refine", landing)
    monkeypatch.setattr(training, "_fit_relation", plain)
    summaries = []
    relations.fit(sources.make("ellipse"), relations.Config(
        max_relations=2, codimension=2, max_steps=40, chunk_steps=20, batch_size=64,
        stop_patience=1, eval_batches=2, refine_rounds=0, premine_steps=40,
        premine_attempts=2), on_relation=lambda _, summary: summaries.append(summary))
    assert next(given, None) is None  # every finite training refined
    assert len(summaries) == 2
    assert summaries[1].ratio == pytest.approx(kept, rel=1e-5)


def test_a_start_reaching_half_the_noise_floor_is_not_tried_again(monkeypatch):
    """Where the rows' scatter lets an exact relation separate only 4× (below the stopping bar
    of 5), a start at off/on 3 (over half of it) that lands cleanly is kept without another
    start (on clean rows it is tried again: the test of the last resorts above)."""
    from jaml.relations import training

    seen = []
    real_fit_relation, real_refine, real_floor = (training._fit_relation, training._refine,
                                                  training._noise_floor)

    def counting(*args, **kwargs):
        seen.append(1)
        return real_fit_relation(*args, **kwargs)

    def separating(*args, **kwargs):  # off/on 3, no projected point on a spurious zero
        fitted, land, rounds, spent = real_refine(*args, **kwargs)
        return (fitted._replace(off_mean=3.0 * fitted.on_mean),
                {**land, "spurious": 0.0, "landed": 1.0}, rounds, spent)

    monkeypatch.setattr(training, "_fit_relation", counting)
    monkeypatch.setattr(training, "_refine", separating)
    monkeypatch.setattr(training, "_noise_floor",
                        lambda *args: real_floor(*args) | {"separation": 4.0})
    rs = relations.fit(sources.make("circle"), relations.Config(
        max_relations=1, max_steps=40, chunk_steps=20, batch_size=64, stop_patience=1,
        eval_batches=2, refine_rounds=0, premine_attempts=2))
    assert len(seen) == 1
    assert rs.num_relations == 1
    assert training.RETRY_FLOOR_SHARE == 0.5


def test_the_fit_takes_its_noise_floor_from_the_rows_with_its_training_noise():
    """`Config.noise_scale` adds uniform noise (±noise_scale/2 of the box's width per axis) to
    the rows training sees; the floor is theirs: on clean unit-sphere rows at noise 0.05 its
    scatter is that of ‖x + ε‖ − 1 (the top fifth's mean, by sampling the same noise), where
    the clean rows alone scatter by rounding only."""
    from jaml.relations import training

    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(4000, 3))
    sphere = (sphere / np.linalg.norm(sphere, axis=1, keepdims=True)).astype(np.float32)
    cfg = relations.Config(noise_scale=0.05)
    batches = prepare(sphere, 256, cfg.noise_scale, jax.random.key(0), 2)
    floor = training._noise_floor(cfg, batches, 1, jax.random.key(1))
    width = np.asarray(batches.high - batches.low)
    diag = np.linalg.norm(width)
    noisy = sphere + (rng.uniform(size=sphere.shape) - 0.5) * width * cfg.noise_scale
    radial = np.sort(np.abs(np.linalg.norm(noisy, axis=1) - 1))[::-1]
    np.testing.assert_allclose(floor["across"] * diag, radial[: len(radial) // 5].mean(),
                               rtol=0.15)
    clean = training._noise_floor(relations.Config(), prepare(sphere, 256, 0.0,
                                                              jax.random.key(0), 2),
                                  1, jax.random.key(1))
    assert clean["separation"] > 1e3 > 10 * floor["separation"]


def test_the_noise_floor_matches_the_closed_form_on_a_noisy_sphere():
    """Unit sphere rows with Gaussian noise σ: the offset across the sphere is σ·|z| (the
    tangent part is fitted away), so the largest fifth averages 1.755σ (E[|z| : |z| > 1.2816]);
    a box row's distance to the manifold is |‖x‖ − 1|. Exact rows scatter by rounding only."""
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(4000, 3))
    sphere /= np.linalg.norm(sphere, axis=1, keepdims=True)
    noisy = sphere + 0.03 * rng.normal(size=sphere.shape)
    low, high = noisy.min(0), noisy.max(0)
    diag = np.linalg.norm(high - low)
    floor = quality.separation_floor(noisy, 1, jax.random.key(1), low, high)
    np.testing.assert_allclose(floor["across"] * diag, 1.755 * 0.03, rtol=0.15)
    box = rng.uniform(low, high, (100_000, 3))
    exact = np.abs(np.linalg.norm(box, axis=1) - 1).mean() / (1.755 * 0.03)
    np.testing.assert_allclose(floor["separation"], exact, rtol=0.2)
    assert floor["separation"] < 5  # below the paper's stopping bar
    assert quality.separation_floor(sphere, 1, jax.random.key(1), low, high)["separation"] > 1e3


def test_a_capped_relation_on_noisy_rows_is_said_to_be_out_of_reach():
    """Where an exact relation's separation is below the stopping bar, the capped warning says
    so and a line gives the rows' scatter; on exact rows neither."""
    report = {"relations": [{"index": 1, "status": "capped", "ratio": 2.4}],
              "independence": {"median_abs_cos": [[1.0]]},
              "landing": {"converged": 1.0, "spurious": 0.0, "within": 0.05},
              "noise": {"across": 0.0224, "separation": 2.4, "separation_ratio": 5.0}}
    assert quality._warnings(report) == [
        "g1 capped: it did not meet the stopping rule (held-out off/on 2.4; out of reach on "
        "these rows, see noise)"]
    report["noise"]["separation"] = 1e4
    assert quality._warnings(report) == [
        "g1 capped: it did not meet the stopping rule (held-out off/on 2.4)"]
    rows = jnp.asarray(_circle(400))
    low, high = np.asarray(rows.min(0)) - 0.1, np.asarray(rows.max(0)) + 0.1
    noise = {"across": 0.0224, "separation": 2.4, "separation_ratio": 5.0}
    lines = quality.assess(_random_set(), jax.random.key(3), rows[:200], rows[200:], low, high,
                           ("capped",), 2, "given", noise)["lines"]
    assert ("noise: the rows scatter 2.2% of the box diagonal across their manifold; an exact "
            "relation separates them only 2.4x, below the stopping bar (5), so a capped relation "
            "is expected") in lines


def test_sparse_rows_are_warned_of_and_a_given_codimension_is_named_so():
    """The landing distance grows with the sample's spacing: past a tenth of the box diagonal
    the report says its shares are loose; the data's codimension is labelled by its source."""
    report = {"relations": [{"index": 1, "status": "done", "ratio": 9.0}],
              "independence": {"median_abs_cos": [[1.0]]},
              "landing": {"converged": 1.0, "spurious": 0.0, "within": 0.74,
                          "box_diagonal": 3.6}}
    assert quality._warnings(report) == [
        "the rows are sparse for their box: a point counts as on the data within 0.74 of a row, "
        "21% of the box diagonal, so the landing shares are loose (more rows tighten them)"]
    report["landing"]["within"] = 0.05
    assert quality._warnings(report) == []
    rows = jnp.asarray(_circle(400))
    low, high = np.asarray(rows.min(0)) - 0.1, np.asarray(rows.max(0)) + 0.1
    line = quality.assess(_random_set(), jax.random.key(3), rows[:200], rows[200:], low, high,
                          ("done",), 2, "given")["lines"][1]
    assert "; the data's, given: 2)" in line


def test_holds_accepting_box_rows_far_from_the_data_is_warned_of():
    """Of the box rows farther than the landing distance from the data, the share `holds`
    accepts: all of them at a tolerance that accepts every row (warned), none at tolerance 0;
    the warning's rule at a tenth."""
    rows = jnp.asarray(_circle(400))
    low, high = np.asarray(rows.min(0)) - 0.1, np.asarray(rows.max(0)) + 0.1
    for tolerance, share in ((1e9, 1.0), (0.0, 0.0)):
        report = quality.assess(_random_set().replace(tolerance=tolerance), jax.random.key(3),
                                rows[:200], rows[200:], low, high, ("done",), 2, "given")
        assert report["holds"]["far_acceptance"] == share
        assert any(w.startswith("holds accepts 100% of box rows farther than")
                   for w in report["warnings"]) == (share == 1.0)
    report = {"relations": [], "independence": {"median_abs_cos": [[1.0]]},
              "landing": {"converged": 1.0, "spurious": 0.0, "within": 0.05,
                          "box_diagonal": 3.6},
              "holds": {"far_acceptance": 0.3}}
    assert quality._warnings(report) == [
        "holds accepts 30% of box rows farther than 0.05 from the data: the relations stay "
        "near zero there (a lower `tolerance` rejects more of them, at some recall)"]
    report["holds"]["distance_tolerance"] = 0.02  # a fit's: holds by distance
    assert quality._warnings(report)[-1].endswith(
        "(a lower `distance_tolerance` rejects more of them, at some recall)")
    report["holds"]["far_acceptance"] = 0.1
    assert quality._warnings(report) == []


def test_a_local_pca_codimension_of_0_is_fitted_as_1(monkeypatch, caplog):
    """Noisy or few rows fill their neighbourhoods and the local PCA reads codimension 0, which
    made every relation one "beyond the codimension" (dropped below off/on 5, not 2)."""
    monkeypatch.setattr(quality, "data_codimension", lambda rows, key: 0)
    with caplog.at_level(logging.INFO, logger="jaml.relations"):
        rs = relations.fit(sources.make("circle"), relations.Config(
            max_relations=1, max_steps=40, chunk_steps=20, batch_size=64, stop_patience=1,
            eval_batches=2, refine_rounds=0, premine_attempts=1, separation_ratio=1e-3))
    assert "finds no codimension" in caplog.text and "the data's codimension: 1" in caplog.text
    assert "the data's, by local PCA 0, taken as 1: 1)" in rs.quality.to_dict()["lines"][1]


def test_on_noisy_rows_the_tangent_space_takes_the_datas_dimension_not_the_noise():
    """Rows of the plane z = 0 with noise in z of 0.4 × a neighbourhood's in-plane spread: by
    the singular-value bar alone z counts as a tangent direction and a point 0.3 off the plane
    reads as on it; with the data's dimension (2) it reads 0.3 off."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(8)
    rows = np.concatenate([rng.uniform(0, 1, (4000, 2)), rng.normal(0, 0.01, (4000, 1))], 1)
    tree = cKDTree(rows)
    point = np.array([[0.5, 0.5, 0.3]])
    _, nearest = tree.query(point)
    assert quality.tangent_offsets(point, tree, nearest)[0] < 0.05  # the noise passed the bar
    np.testing.assert_allclose(quality.tangent_offsets(point, tree, nearest, dim=2), 0.3,
                               atol=0.02)


def test_a_relation_a_fresh_syzygy_explains_is_warned_of_and_its_share_reported():
    """A syzygy-trained relation's unexplained share is on its line; below 1/separation_ratio
    (a fresh f writes it as Σ_j f_j g_j, a copy) the report warns."""
    report = {"relations": [{"index": 1, "status": "done", "ratio": 90.0},
                            {"index": 2, "status": "done", "ratio": 80.0, "unexplained": 0.1}],
              "independence": {"median_abs_cos": [[1.0, 0.2], [0.2, 1.0]]},
              "landing": {"converged": 1.0, "spurious": 0.0, "within": 0.05}}
    assert quality._warnings(report) == [
        "g2 is a restricted syzygy of the earlier relations: a fresh syzygy network explains all "
        "but 10% of it (not new; 20% would be)"]
    report["relations"][1]["unexplained"] = 0.3
    assert quality._warnings(report) == []
    rows = jnp.asarray(_circle(400))
    low, high = np.asarray(rows.min(0)) - 0.1, np.asarray(rows.max(0)) + 0.1
    two = _random_set().append(_random_set(1).params[0], 0.05, 1.0, 8)
    report = quality.assess(two, jax.random.key(3), rows[:200], rows[200:], low, high,
                            ("done", "done"), 2, "given", unexplained=(None, 0.1))
    assert "unexplained" not in report["relations"][0]
    assert "g2 done off/on" in report["lines"][0]
    assert ", 10% unexplained by a syzygy" in report["lines"][0]
    assert any("g2 is a restricted syzygy" in line for line in report["lines"])
