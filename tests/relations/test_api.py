"""The functional API: validation before training, determinism, checkpoints, non-finite losses."""

import logging
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml import relations, sources
from jaml.relations import loop

# Plumbing, not quality: no mining, and capped relations kept (a real fit drops them).
TINY = relations.Config(  # one start a relation: these capped fits are not about retries
    max_relations=2, max_steps=60, chunk_steps=30, batch_size=64, eval_batches=2, stop_patience=1,
    mined_weight=0.0, stop_when_complete=False, premine_attempts=1,
)


@pytest.fixture(scope="module")
def tiny_set():
    rows = sources.make("ellipse").sample(jax.random.key(0), 512)
    return relations.fit(rows, TINY), rows


def test_fit_returns_the_declared_structure(tiny_set):
    rs, rows = tiny_set
    assert rs.num_relations == 2 and rs.widths == (4, 8) and rs.dim == 3
    assert rs.on_means.shape == (2,) and rs.off_means.shape == (2,)
    assert relations.evaluate(rs, rows[:5]).shape == (5, 2)
    assert relations.evaluate(rs, rows.reshape(4, 128, 3)).shape == (4, 128, 2)
    assert relations.penalty(rs, rows[:5]).shape == (5,)
    assert relations.holds(rs, rows[:5]).dtype == jnp.bool_
    np.testing.assert_allclose(
        relations.penalty(rs, rows[:5]),
        jnp.abs(relations.evaluate(rs, rows[:5])).sum(-1),
        rtol=1e-6,
    )


def test_evaluate_is_one_program_with_the_networks_own_values(tiny_set):
    """`evaluate` runs every relation in one compiled program, kept for a set of the same
    shapes whatever its tolerance or report, with each network's own values (its Flax module
    applied op by op) to float32 rounding; raw gives them before the output tanh. Bit for bit
    on some CPUs; on others XLA orders the one program's sums differently (4 ulp seen)."""
    from jaml.relations import relation_set

    rs, rows = tiny_set
    tau = rows[:7]
    own = jnp.stack([rs.relation(k)(tau) for k in range(rs.num_relations)], axis=-1)
    raw = jnp.stack([rs.relation(k, raw=True)(tau) for k in range(rs.num_relations)], axis=-1)
    before = relation_set._evaluate._cache_size()
    np.testing.assert_array_max_ulp(relations.evaluate(rs, tau), own, maxulp=16)
    np.testing.assert_array_max_ulp(relation_set.evaluate_raw(rs, tau), raw, maxulp=16)
    assert relation_set._evaluate._cache_size() == before + 2  # g and raw: one program each
    relations.evaluate(rs.replace(tolerance=rs.tolerance * 2, quality=None), rows[7:14])
    assert relation_set._evaluate._cache_size() == before + 2


def test_penalty_is_differentiable_in_tau(tiny_set):
    rs, rows = tiny_set
    grad = jax.grad(lambda t: relations.penalty(rs, t).sum())(rows[:8])
    assert grad.shape == (8, 3) and bool(jnp.all(jnp.isfinite(grad)))
    assert float(jnp.abs(grad).sum()) > 0


def test_same_seed_same_parameters_different_seed_differs(tiny_set, caplog):
    """A later fit of the same shapes compiles nothing, whatever its seed: the seed, the data
    and the parameters are arguments of the programs the first fit compiled."""
    rs, rows = tiny_set
    with jax.log_compiles(), caplog.at_level(logging.WARNING, logger="jax"):
        again = relations.fit(rows, TINY)
        other = relations.fit(rows, TINY.replace(seed=1))
    assert "Compiling" not in caplog.text
    for a, b in zip(jax.tree.leaves(rs.params), jax.tree.leaves(again.params), strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.allclose(jax.tree.leaves(other.params)[0], jax.tree.leaves(rs.params)[0])


def test_samplers_and_sources_are_accepted():
    """The fixture's source and shapes (the fits' programs compiled once in this module)."""
    src = sources.make("ellipse")
    rs = relations.fit(src, TINY.replace(max_relations=1))
    assert rs.dim_names == src.dim_names == ("x", "y", "z")
    rs = relations.fit(lambda key: src.sample(key, 32), TINY.replace(max_relations=1))
    assert rs.num_relations == 1 and rs.dim == 3 and rs.dim_names == ()


def test_checkpoint_round_trip(tiny_set, tmp_path, caplog):
    rs, rows = tiny_set
    relations.save(rs, tmp_path / "rs")
    with caplog.at_level("INFO", logger="jaml.relations"):
        loaded = relations.load(tmp_path / "rs")
    on, off = np.asarray(rs.on_means).tolist(), np.asarray(rs.off_means).tolist()
    assert (f"loaded 2 relations (0 syzygies) from {tmp_path / 'rs'}; mean |g| on / off the "
            f"data: g1 {on[0]:.4g} / {off[0]:.4g}, g2 {on[1]:.4g} / {off[1]:.4g}"
            ) in caplog.text and "\n[" not in caplog.text  # one line, no numpy arrays
    np.testing.assert_array_equal(relations.evaluate(loaded, rows), relations.evaluate(rs, rows))
    np.testing.assert_array_equal(loaded.on_means, rs.on_means)
    assert (loaded.widths, loaded.depth, loaded.tolerance) == (rs.widths, rs.depth, rs.tolerance)
    # Overwriting an existing checkpoint replaces it whole.
    relations.save(relations.fit(rows, TINY.replace(max_relations=1)), tmp_path / "rs")
    assert relations.load(tmp_path / "rs").num_relations == 1


def test_training_continues_from_a_loaded_set(tiny_set):
    rs, rows = tiny_set
    first = relations.RelationSet.empty(3, 3, 1.5).append(
        rs.params[0], rs.on_means[0], rs.off_means[0], 4
    )
    grown = relations.fit(rows, TINY, start=first)
    assert grown.num_relations == 2
    np.testing.assert_array_equal(
        jax.tree.leaves(grown.params[0])[0], jax.tree.leaves(rs.params[0])[0]
    )
    # g2 here is traced and compiled after g1 exists; in `tiny_set` its loop was compiled ahead,
    # while g1 trained, with a stand-in for g1: the same program, so the same parameters.
    for a, b in zip(jax.tree.leaves(grown.params[1]), jax.tree.leaves(rs.params[1]), strict=True):
        np.testing.assert_array_equal(a, b)


def test_rows_in_other_units_train_in_units_near_one_and_the_set_takes_theirs(tiny_set,
                                                                               tmp_path):
    """Rows 2^10 and 2^12 times the ellipse's (both beyond `units.BAND`) train on the same bits:
    g at τ·2^10 of one set is g at τ·2^12 of the other, and their lengths (box, `holds`'
    distance tolerances, the report's landing distance) are 4× apart. Rows far from the origin
    train centred: the centre is kept on the set and in its checkpoint, and a fit continued from
    it goes on in the same units (on rows centred elsewhere it is refused)."""
    _, rows = tiny_set
    cfg = TINY.replace(max_relations=1)
    small, big = relations.fit(rows * 2**10, cfg), relations.fit(rows * 2**12, cfg)
    tau = rows[:64]
    np.testing.assert_array_equal(relations.evaluate(small, tau * 2**10),
                                  relations.evaluate(big, tau * 2**12))
    assert small.centre == big.centre == () and big.low == tuple(4 * x for x in small.low)
    np.testing.assert_array_equal(big.distance_tolerance,
                                  [4 * t for t in small.distance_tolerance])
    assert big.quality["landing"]["within"] == 4 * small.quality["landing"]["within"]
    assert f"within {big.quality['landing']['within']:.3g})" in str(big)

    far = relations.fit(rows + 1000, cfg)
    box_centre = (np.asarray(rows).min(0) + np.asarray(rows).max(0)) / 2 + 1000
    np.testing.assert_allclose(far.centre, box_centre, rtol=1e-6)
    assert "centred at (" in str(far)
    g = relations.evaluate(far, tau + 1000)
    assert bool(jnp.all(jnp.isfinite(g))) and relations.holds(far, tau + 1000).mean() > 0.5
    relations.save(far, tmp_path / "far")
    loaded = relations.load(tmp_path / "far")
    assert loaded.centre == far.centre
    np.testing.assert_array_equal(relations.evaluate(loaded, tau + 1000), g)
    grown = relations.fit(rows + 1000, TINY, start=loaded)
    assert grown.num_relations == 2 and grown.centre == far.centre
    np.testing.assert_array_equal(relations.evaluate(grown, tau + 1000)[:, 0], g[:, 0])
    with pytest.raises(ValueError, match="centred at"):
        relations.fit(rows + 2000, TINY, start=loaded)


def test_units_keep_rows_near_unit_scale_and_move_the_rest():
    """`units.choose` by hand: a box's widest half-side within [2^-1.5, 2^1.5] keeps its scale,
    one beyond it is divided by the nearest power of two; a column whose centre lies more than 3
    half-sides out is centred. The analytic sources keep their units but the 45° block, whose
    next velocity is centred (the incline presets' boxes, half-side 1 and centres within 0.5 of
    it, are not sampled here)."""
    from jaml.relations import units

    assert units.choose([-1, -2], [1, 2]).identity
    assert units.choose([-0.36, 0], [0.36, 0.1]).identity
    assert units.choose([-1000, -1], [1000, 1]) == units.Units((), 1024.0)
    assert units.choose([-0.3, 0], [0.3, 0.1]) == units.Units((), 0.25)
    assert units.choose([1.5, -1], [4.5, 1]) == units.Units((), 1.0)  # 3 = 2 half-sides
    assert units.choose([7.5, -1], [9.5, 1]) == units.Units((8.5, 0.0), 1.0)  # 8.5 half-sides
    assert units.choose([999, 999], [1001, 1001]) == units.Units((1000.0, 1000.0), 1.0)
    for name in ("ellipse", "circle", "block45", "block36-drag"):
        rows = np.asarray(sources.make(name).sample(jax.random.key(0), 4096))
        chosen = units.choose(rows.min(0), rows.max(0))
        assert chosen.scale == 1.0 and [c != 0 for c in chosen.centre] == (
            [False, False, False, True] if name == "block45" else []), name


def test_missing_and_corrupt_checkpoints_raise(tiny_set, tmp_path):
    with pytest.raises(FileNotFoundError, match="no relations checkpoint"):
        relations.load(tmp_path / "absent")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "meta").mkdir()
    with pytest.raises(ValueError, match=r"corrupt or foreign|not a jaml"):
        relations.load(tmp_path / "junk")
    rs, _ = tiny_set
    relations.save(rs, tmp_path / "rs")
    for path in (tmp_path / "rs" / "arrays").rglob("*"):
        if path.is_file():
            path.write_bytes(b"garbage")
    with pytest.raises(ValueError, match="corrupt"):
        relations.load(tmp_path / "rs")


@pytest.mark.parametrize(
    ("data", "error", "match"),
    [
        (np.zeros((10, 3), np.int32), TypeError, "floating-point"),
        (np.zeros((10,), np.float32), ValueError, r"shape \[N, D\]"),
        (np.zeros((0, 3), np.float32), ValueError, "empty"),
        (np.ones((10, 3), np.float32), ValueError, "constant"),
        (np.where(np.eye(10, 3) > 0, np.nan, 1.0).astype(np.float32), ValueError, "non-finite"),
        (np.full((10, 3), np.inf, np.float32), ValueError, "non-finite"),
    ],
)
def test_bad_data_raises_before_training(data, error, match):
    with pytest.raises(error, match=match):
        relations.fit(data, TINY)


def test_failing_or_misshapen_sampler_raises():
    def broken(key):
        raise RuntimeError("boom")

    with pytest.raises(ValueError, match=r"sampler failed.*boom"):
        relations.fit(broken, TINY)
    with pytest.raises(ValueError, match=r"sampler's output.*shape"):
        relations.fit(lambda key: jnp.zeros((4,)), TINY)


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("independence", "orthogonality", "independence must be one of"),
        ("objective", "mine", "objective must be one of"),
        ("max_relations", 0, "max_relations must be a positive integer"),
        ("batch_size", 1, "batch_size must be at least 2"),
        ("learning_rate", -1.0, "learning_rate must be a positive"),
        ("separation_ratio", math.inf, "separation_ratio must be a positive finite"),
        ("separation_top_fraction", 0.0, "separation_top_fraction"),
        ("min_angle", 2.0, "min_angle"),
        ("transversality_weight", -1.0, "transversality_weight"),
        ("syzygies_per_relation", -1, "syzygies_per_relation"),
        ("premine_attempts", 0, "premine_attempts must be a positive integer"),
        ("premine_clip", 0.0, "premine_clip must be a positive finite"),
        ("premine_steps", 0, "premine_steps must be None or a positive integer"),
    ],
)
def test_invalid_config_values_raise(field, value, match):
    with pytest.raises(ValueError, match=match):
        relations.Config(**{field: value})


def test_config_round_trips_and_rejects_unknown_fields():
    cfg = relations.Config(max_relations=3, objective="reference")
    assert relations.Config.from_dict(cfg.to_dict()) == cfg
    assert cfg.beta == 1.0 and relations.Config().beta == 1e3
    with pytest.raises(ValueError, match=r"unknown relations.Config fields"):
        relations.Config.from_dict({"max_relation": 2})


def test_evaluate_rejects_wrong_tau(tiny_set):
    rs, _ = tiny_set
    with pytest.raises(ValueError, match=r"\[..., 3\]"):
        relations.evaluate(rs, jnp.zeros((5, 4)))
    with pytest.raises(TypeError, match="floating-point"):
        relations.evaluate(rs, jnp.zeros((5, 3), jnp.int32))


def test_a_non_finite_loss_stops_and_keeps_the_last_finite_parameters():
    optimizer = __import__("optax").sgd(0.1)
    params = {"w": jnp.ones(3)}
    state = loop.init_state(params, optimizer, jax.random.key(0))

    def objective(p, x):
        loss = jnp.sum(p["w"] * x)
        return loss, ({}, jnp.asarray(False))

    state, _ = loop.optimizer_step(state, objective, optimizer, 10, jnp.ones(3))
    kept = state.params["w"]
    state, _ = loop.optimizer_step(state, objective, optimizer, 10, jnp.full(3, jnp.nan))
    assert int(state.status) == loop.NONFINITE and int(state.step) == 1
    np.testing.assert_array_equal(state.params["w"], kept)


def test_fit_stops_on_a_non_finite_loss_and_keeps_earlier_relations(caplog):
    rows = sources.make("ellipse").sample(jax.random.key(0), 512)
    first = relations.fit(rows, TINY.replace(max_relations=1))
    with caplog.at_level("ERROR", logger="jaml.relations"):
        rs = relations.fit(rows, TINY.replace(learning_rate=1e38), start=first)
    assert "non-finite" in caplog.text
    assert rs.num_relations == 1


def test_a_checkpoint_loads_where_its_devices_do_not_exist(tiny_set, tmp_path):
    """Relations fitted on one machine are imposed on another (a CPU's fit on a GPU): a set
    saved from this process's second device loads in a process that has one device only."""
    import os
    import subprocess
    import sys

    import jax

    rs, _ = tiny_set
    assert len(jax.devices()) == 2  # tests/conftest.py
    relations.save(jax.device_put(rs, jax.devices()[1]), tmp_path / "rs")
    script = ("import sys, numpy as np; from jaml import relations; "
              "rs = relations.load(sys.argv[1]); np.save(sys.argv[2], np.asarray(rs.on_means))")
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    subprocess.run([sys.executable, "-c", script, str(tmp_path / "rs"), str(tmp_path / "m.npy")],
                   check=True, env=env, capture_output=True)
    np.testing.assert_array_equal(np.load(tmp_path / "m.npy"), rs.on_means)


def test_only_the_codimension_th_transversal_relation_trains_on_premined_rows():
    """Pre-mining needs earlier relations to mine (k > 0), happens once at the data's
    codimension, not in syzygy mode, not with mining off; records that predate it read as
    what they ran (no pre-mining)."""
    from jaml.relations.training import MINED_CLIP, _clip, _premines

    cfg = relations.Config()
    assert [_premines(cfg, k, 2) for k in range(4)] == [False, True, False, False]
    assert not _premines(cfg, 0, 1)  # g1 has no earlier zero set to mine
    assert not _premines(relations.Config(independence="syzygy"), 1, 2)
    assert not _premines(relations.Config(mined_weight=0.0), 1, 2)
    assert not _premines(relations.Config(premine=False), 1, 2)
    assert _clip(cfg, 1, 2) == cfg.premine_clip and _clip(cfg, 2, 2) == MINED_CLIP
    old = relations.Config.from_record({"max_relations": 2, "mined_weight": 1.0})
    assert old.premine is False and old.mined_weight == 1.0 and old.premine_attempts == 1


def test_training_on_mined_rows_ends_when_the_cleared_share_stops_rising():
    """Once g_k separates, a window whose best cleared share is within 0.01 of the best before
    it ends the loop; not before it separates, nor while the share still rises. Records that
    predate the rule ran to the budget."""
    from jaml.relations.training import _Plateau

    def stops_at(cleared, off):
        until = _Plateau(ratio=5.0, window=2)
        for i, (c, o) in enumerate(zip(cleared, off, strict=True)):
            if until({"mined_cleared": c, "on_mean": 1.0, "off_mean": o}):
                return i
        return None

    rising = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]
    assert stops_at(rising, [9.0] * 7) is None
    flat = [0.1, 0.5, 0.52, 0.515, 0.518, 0.52]
    assert stops_at(flat, [9.0] * 6) == 4  # the window (0.515, 0.518) adds nothing to 0.52
    assert stops_at(flat, [9.0, 9.0, 9.0, 9.0, 4.0, 9.0]) == 5  # not while off/on < 5
    assert relations.Config.from_record({"mined_weight": 1.0}).mined_patience is None
    with pytest.raises(ValueError, match="mined_patience"):
        relations.Config(mined_patience=0)


@pytest.mark.parametrize("bad", ["nan", "on_data"])
def test_a_pre_mined_relation_that_fails_is_trained_again_without_its_rows(bad, monkeypatch,
                                                                           caplog):
    """Pre-mined rows that make g2's loss non-finite, or that lie on the data itself (a sparse
    sample judges "away" loosely) so g2 cannot separate, cost nothing: g2 is trained again the
    paper's way, and the fit keeps both relations."""
    import logging

    from jaml.relations import training

    rows = sources.make("ellipse").sample(jax.random.key(0), 512)
    real_mine = training.mine

    def mine(cfg, rs, batches, key, within, pool=None, codim=None):
        if rs.num_relations != 1:  # refinement: as usual
            return real_mine(cfg, rs, batches, key, within, pool, codim)
        found = (np.full((cfg.mine_points, 3), np.nan, np.float32) if bad == "nan"
                 else np.asarray(rows[: cfg.mine_points], np.float32))
        padded = np.concatenate([found, np.full((cfg.mine_points, 1), 50.0, np.float32)], -1)
        return (padded, cfg.mine_points), {"landed": 0.0, "spurious": 1.0}

    monkeypatch.setattr(training, "mine", mine)
    # One start: other starts, the last resorts and g_1 trained again are other tests'.
    cfg = relations.Config(max_relations=2, max_steps=300, chunk_steps=50, batch_size=64,
                           eval_batches=2, stop_patience=1, refine_rounds=0, codimension=2,
                           stop_when_complete=False, mine_points=64, premine_attempts=1)
    with caplog.at_level(logging.INFO, logger="jaml"):
        rs = relations.fit(rows, cfg)
    again = [r.getMessage() for r in caplog.records if "trained again" in r.getMessage()]
    assert len(again) == 1, [r.getMessage() for r in caplog.records]
    assert ("non-finite" in again[0]) == (bad == "nan")
    assert rs.num_relations == 2
    assert np.isfinite(np.asarray(relations.evaluate(rs, rows[:16]))).all()


def test_a_relation_set_without_relations_is_refused_where_it_would_mislead(tmp_path):
    """No relation: `holds` would accept every point, `penalty` be 0 everywhere, `project`
    call every point converged, and Orbax cannot save zero-size arrays (it left a temporary
    directory and hung at exit). Each refuses in one line instead."""
    rs = relations.RelationSet.empty(3, 2, 1.5, low=(0.0,) * 3, high=(1.0,) * 3)
    tau = np.full((4, 3), 10.0, np.float32)
    for call, name in ((lambda: relations.holds(rs, tau), "holds"),
                       (lambda: relations.penalty(rs, tau), "penalty"),
                       (lambda: relations.project(rs, tau), "project"),
                       (lambda: relations.save(rs, tmp_path / "rs"), "save")):
        with pytest.raises(ValueError, match=f"^{name}: this RelationSet has no relations"):
            call()
    assert not list(tmp_path.iterdir())
    assert relations.evaluate(rs, tau).shape == (4, 0)  # the values, an empty set of them


def test_fit_takes_the_path_of_a_csv_file_as_the_docs_say(tmp_path):
    """A path (str or Path) is read as `sources.make` reads it: the same rows as the array."""
    from jaml.relations import data

    rows = np.random.default_rng(0).normal(size=(64, 3)).astype(np.float32)
    np.savetxt(tmp_path / "rows.csv", rows, delimiter=",", header="a,b,c", comments="")
    for given in (tmp_path / "rows.csv", str(tmp_path / "rows.csv")):
        batches = data.prepare(given, 16, 0.0, jax.random.key(0), 2)
        got = np.concatenate([np.asarray(batches.held_out), np.asarray(batches.rows)])
        np.testing.assert_allclose(np.sort(got, axis=0), np.sort(rows, axis=0), rtol=1e-6)
        assert batches.dim_names == ("a", "b", "c")


def test_a_retired_field_reads_at_its_one_remaining_value_and_is_refused_at_another():
    """`cut_beyond_codim` (an experiment whose code is gone) stays readable in old records at
    False, what every fit does now; True ran code that no longer exists."""
    old = relations.Config.from_record({"max_relations": 2, "cut_beyond_codim": False})
    assert old.max_relations == 2 and "cut_beyond_codim" not in old.to_dict()
    with pytest.raises(ValueError, match=r"unknown relations.Config fields: \['cut_beyond"):
        relations.Config.from_record({"cut_beyond_codim": True})
    with pytest.raises(TypeError):
        relations.Config(cut_beyond_codim=False)
