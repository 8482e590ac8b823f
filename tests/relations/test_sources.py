"""Data sources against closed forms, hand-computed values and an independent ODE solve."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from jaml import sources
from jaml.relations.data import prepare


def test_ellipse_lies_on_hyperboloid_and_plane():
    tau = sources.HyperboloidPlaneCurve().sample(jax.random.key(0), 4096)
    residuals = sources.HyperboloidPlaneCurve.residuals(tau)
    assert float(jnp.max(jnp.abs(residuals))) < 1e-5
    lo, hi = np.asarray(tau.min(0)), np.asarray(tau.max(0))
    np.testing.assert_allclose(lo, [-math.sqrt(2), -3, -2], atol=1e-2)
    np.testing.assert_allclose(hi, [math.sqrt(2), 1, 0], atol=1e-2)


def test_the_circle_preset_lies_on_the_unit_circle_all_round():
    tau = sources.make("circle").sample(jax.random.key(0), 4096)
    assert float(jnp.max(jnp.abs(sources.Circle.residuals(tau)))) < 1e-5
    angles = np.sort(np.arctan2(np.asarray(tau[:, 1]), np.asarray(tau[:, 0])))
    assert np.diff(angles).max() < 0.02 and angles[0] < -3.1 and angles[-1] > 3.1


def test_off_manifold_is_uniform_in_the_data_box():
    batches = prepare(sources.make("ellipse"), 1024, 0.0, jax.random.key(0), 4)
    off = np.asarray(batches.off(jax.random.key(1), batches.data, 20_000))
    low, high = np.asarray(batches.low), np.asarray(batches.high)
    assert (off >= low).all() and (off <= high).all()
    np.testing.assert_allclose(off.mean(0), (low + high) / 2, atol=0.03 * (high - low).max())


@pytest.mark.parametrize(
    ("incline", "friction", "c"),
    [(math.pi / 4, 0.0, 6.9296465), (math.pi / 5, 0.2, 4.1746222), (0.4, 0.2, 2.0110202)],
)
def test_block_presets_satisfy_the_constant_acceleration_relations(incline, friction, c):
    src = sources.BlockOnIncline(incline=incline, friction=friction)
    s0, v0, s1, v1 = np.asarray(src.sample(jax.random.key(0), 2048)).T
    assert float(sources.downhill_acceleration(9.8, incline, friction)) == pytest.approx(
        c, abs=1e-6
    )
    np.testing.assert_allclose(v1 - v0, c, atol=1e-5)
    np.testing.assert_allclose(s1 - s0 - v0, c / 2, atol=1e-5)


def test_block45_hand_computed_example():
    c = sources.downhill_acceleration(9.8, math.pi / 4, 0.0)
    s1, v1 = sources.flow(0.5, -0.5, 1.0, c, 0.0, "none")
    assert float(s1) == pytest.approx(3.4648232, abs=1e-5)
    assert float(v1) == pytest.approx(6.4296465, abs=1e-5)


def test_conservative_block_with_ranged_incline():
    src = sources.BlockOnIncline(incline=(0.1, 1.0))
    s0, v0, s1, v1 = np.asarray(src.sample(jax.random.key(0), 4096)).T
    np.testing.assert_allclose(s1 - s0, (v0 + v1) / 2, atol=1e-5)
    ratio = (v1 - v0) / 9.8
    assert ratio.min() >= math.sin(0.1) - 1e-6 and ratio.max() <= math.sin(1.0) + 1e-6


def _ode(s0, v0, t, c, r, drag):
    drag_fn = {
        "none": lambda v: 0.0,
        "linear": lambda v: r * v,
        "quadratic": lambda v: r * v * abs(v),
    }
    sol = solve_ivp(
        lambda _, y: [y[1], c - drag_fn[drag](y[1])],
        (0.0, t),
        [s0, v0],
        method="DOP853",
        rtol=1e-12,
        atol=1e-13,
    )
    return sol.y[0, -1], sol.y[1, -1]


@pytest.mark.parametrize(
    ("drag", "incline", "start", "expected"),
    [
        ("quadratic", 0.4, (0.5, -0.5), (0.93672189, 1.12438136)),
        ("quadratic", 0.4, (0.0, 0.0), (0.78194949, 1.26098246)),
        ("quadratic", 0.4, (0.0, 3.0), (1.84012464, 1.47893851)),
        ("linear", 0.4, (0.5, -0.5), (0.92375271, 1.08726750)),
        ("linear", math.pi / 5, (0.0, 0.0), (1.53575767, 2.63886449)),
    ],
)
def test_closed_forms_match_reference_values_and_ode(drag, incline, start, expected):
    with jax.enable_x64(True):
        c = float(sources.downhill_acceleration(9.8, incline, 0.2))
        s, v = sources.flow(jnp.float64(start[0]), jnp.float64(start[1]), 1.0, c, 1.0, drag)
        np.testing.assert_allclose([float(s), float(v)], expected, atol=1e-8)
        np.testing.assert_allclose([float(s), float(v)], _ode(*start, 1.0, c, 1.0, drag), atol=1e-8)


@pytest.mark.parametrize("drag", ["none", "linear", "quadratic"])
def test_closed_forms_match_ode_across_regimes(drag):
    # Includes climbing starts that stop and turn (v0 < 0) and starts above terminal speed.
    with jax.enable_x64(True):
        c = float(sources.downhill_acceleration(9.8, 0.4, 0.2))
        for v0 in (-3.0, -1.0, -0.2, 0.0, 0.5, 1.0, 2.5, 4.0):
            for t in (0.0, 0.3, 1.0, 2.0):
                s, v = sources.flow(jnp.float64(0.1), jnp.float64(v0), t, c, 1.0, drag)
                np.testing.assert_allclose(
                    [float(s), float(v)],
                    _ode(0.1, v0, t, c, 1.0, drag),
                    atol=1e-8,
                    err_msg=f"v0={v0} t={t}",
                )


def test_rows_are_time_major_and_named():
    src = sources.BlockOnIncline(times=(0.0, 0.5, 1.0))
    assert src.dim_names == (
        "position_0",
        "velocity_0",
        "position_1",
        "velocity_1",
        "position_2",
        "velocity_2",
    )
    tau = np.asarray(src.sample(jax.random.key(0), 8))
    assert tau.shape == (8, 6)
    np.testing.assert_allclose(tau[:, 3] - tau[:, 1], 9.8 * math.sin(math.pi / 4) * 0.5, atol=1e-5)


def test_an_observed_incline_is_the_last_entry_and_sets_each_rows_acceleration():
    src = sources.BlockOnIncline(incline=(0.1, 1.0), observe_incline=True)
    assert src.dim_names[-1] == "incline" and len(src.dim_names) == 5
    _, v0, _, v1, theta = np.asarray(src.sample(jax.random.key(0), 512)).T
    assert theta.min() >= 0.1 and theta.max() <= 1.0 and np.ptp(theta) > 0.5
    np.testing.assert_allclose(v1 - v0, 9.8 * np.sin(theta), atol=1e-5)


def test_bad_source_parameters_raise():
    with pytest.raises(ValueError, match="unknown drag"):
        sources.BlockOnIncline(drag="cubic")
    with pytest.raises(ValueError, match="downhill acceleration"):
        sources.BlockOnIncline(incline=0.1, friction=0.8, drag="quadratic", drag_coef=1.0)
    with pytest.raises(ValueError, match="drag_coef > 0"):
        sources.BlockOnIncline(drag="linear")
    with pytest.raises(ValueError, match="strictly increasing"):
        sources.BlockOnIncline(times=(1.0, 0.0))
    with pytest.raises(ValueError, match="valid sources"):
        sources.make("torus")


def test_make_overrides_replace_preset_fields():
    src = sources.make("block45", friction=0.1)
    assert src.friction == 0.1 and src.name == "block45"
    with pytest.raises(ValueError, match="unknown source overrides"):
        sources.make("block45", mass=1.0)


def test_prepare_draws_a_sources_pool_once():
    """A source with pool_size is sampled once, before training, and then behaves as rows."""
    rows = np.asarray(sources.make("block45").sample(jax.random.key(0), 300))
    calls = []

    class Pooled:
        name, dim_names, pool_size = "pooled", ("s0", "v0", "s1", "v1"), 300

        def sample(self, key, n):
            calls.append(n)
            return rows

    batches = prepare(Pooled(), 64, 0.0, jax.random.key(0), 4)
    assert calls == [300] and batches.sampler is None and batches.dim_names == Pooled.dim_names
    # the pool's rows, a tenth held out of training for the quality report, in the fit's units
    # (the block's next velocity, centred 4.7 half-sides out, is centred: `relations.units`)
    pooled = np.concatenate([np.asarray(batches.rows), np.asarray(batches.held_out)])
    assert [c != 0 for c in batches.units.centre] == [False, False, False, True]
    np.testing.assert_array_equal(np.sort(pooled, axis=0),
                                  np.sort(batches.units.to_fit(rows), axis=0))
    assert batches.held_out.shape == (30, 4)
    np.testing.assert_array_equal(np.asarray(batches.low),
                                  batches.units.to_fit(rows.min(0).astype(np.float64)))
    on = np.asarray(batches.on(jax.random.key(1), batches.data))
    assert on.shape == (64, 4) and np.isin(on[:, 0], np.asarray(batches.rows)[:, 0]).all()
    Pooled.pool_size = 1
    with pytest.raises(ValueError, match="pool_size"):
        prepare(Pooled(), 64, 0.0, jax.random.key(0), 4)


def test_a_fits_programs_do_not_depend_on_its_seed():
    """The data box comes from a calibration sample drawn with the fit's key; the compiled
    relation loop must take it as an argument, or every seed compiles its own program and the
    persistent compilation cache never serves a later fit."""
    from jaml import relations
    from jaml.relations.networks import Relation
    from jaml.relations.training import relation_trainer

    cfg = relations.Config(chunk_steps=2)
    texts = []
    for seed in (0, 1):
        batches = prepare(sources.make("ellipse"), 64, 0.1, jax.random.key(seed), 2)
        params = Relation(4).init(jax.random.key(seed), jnp.zeros((1, 3)))
        chunk, state, args = relation_trainer(
            cfg, batches, relations.RelationSet.empty(3, 3, 1.5), params, jax.random.key(seed), 10)
        texts.append(chunk.lower(state, args).as_text())
    assert not np.array_equal(*(np.asarray(prepare(sources.make("ellipse"), 64, 0.1,
                                                   jax.random.key(s), 2).low) for s in (0, 1)))
    assert texts[0] == texts[1]


# Another valid value of every Config field the relation loop does not read.
_OUTSIDE_THE_LOOP = {
    "max_relations": 3, "seed": 7, "syzygy_learning_rate": 3e-4, "max_steps": 1234,
    "syzygies_per_relation": 2, "syzygy_max_steps": 77, "syzygy_push_steps": 55,
    "syzygy_training": "joint", "transversal_first": False, "syzygy_clip": 5.0,
    "tolerance": 2.5, "noise_scale": 0.1, "mine_points": 64, "refine_rounds": 1,
    "premine": False, "premine_clip": 3.0, "premine_steps": 99, "premine_attempts": 1,
    "mined_patience": None, "codimension": 2, "stop_when_complete": False,
    "pretrain_steps": 17, "eval_batches": 3,
}


def test_the_relation_loop_reads_no_config_field_outside_its_key(monkeypatch):
    """Fits whose configs differ only outside `training.LOOP_FIELDS` run one compiled loop, so
    none of those fields may shape it: built afresh with every one of them changed, the loop
    lowers to the same program, with and without syzygies and mined rows; a field of the key
    changes it."""
    import dataclasses

    from jaml import relations
    from jaml.relations import training
    from jaml.relations.networks import Relation, SyzygyCoefficients

    outside = {f.name for f in dataclasses.fields(relations.Config)} - set(training.LOOP_FIELDS)
    assert set(_OUTSIDE_THE_LOOP) == outside  # a new field is placed on one side or the other
    monkeypatch.setattr(training, "_relation_loop", training._build_relation_loop)  # uncached
    base = relations.Config(chunk_steps=2, batch_size=32)
    batches = prepare(sources.make("ellipse"), 32, 0.0, jax.random.key(0), 2)
    g1 = Relation(4).init(jax.random.key(1), jnp.zeros((1, 3)))
    rs = relations.RelationSet.empty(3, 3, 1.5).append(g1, 0.1, 1.0, 4)
    params = Relation(8).init(jax.random.key(2), jnp.zeros((1, 3)))
    f = SyzygyCoefficients(1, base.syzygy_width, 3).init(jax.random.key(3), jnp.zeros((1, 3)))
    syzygies = jax.tree.map(lambda x: x[None], f)
    pool = (np.zeros((8, 4), np.float32), 2)

    def lowered(cfg):
        texts = []
        for syz in (None, syzygies):
            chunk, state, args = training.relation_trainer(
                cfg, batches, rs, params, jax.random.key(4), 10, syz, 0.1, pool)
            texts.append(chunk.lower(state, args).as_text())
        return texts

    reference = lowered(base)
    assert lowered(base.replace(**_OUTSIDE_THE_LOOP)) == reference
    assert lowered(base.replace(separation_ratio=7.0)) != reference


def test_the_syzygy_loop_reads_no_config_field_outside_its_key_and_compiles_once():
    """`fit_syzygy` on (module, params) pairs keeps its loop by `training.SYZYGY_LOOP_FIELDS`,
    the sampler and the relations' modules: lowered with every other field changed it is the
    same program, a key field changes it, and a later round with other parameters, key and
    thickening compiles nothing."""
    import dataclasses
    import logging

    from jaml import relations
    from jaml.relations import training
    from jaml.relations.networks import Relation

    fields = {f.name for f in dataclasses.fields(relations.Config)}
    read = {"syzygy_width", "depth", "syzygy_learning_rate", "syzygy_max_steps", "max_steps",
            "stop_patience", "chunk_steps", "separation_ratio"}  # syzygy_steps: the two steps'
    base = relations.Config(chunk_steps=2, batch_size=32, syzygy_max_steps=40)
    other = {"max_relations": 3, "seed": 7, "learning_rate": 3e-4, "batch_size": 32,
             "base_width": 8, "max_width": 16, "gradient_cap": 0.5, "independence": "syzygy",
             "objective": "reference", "transversality_weight": 3.0,
             "separation_top_fraction": 0.5, "min_angle": 0.3, "mined_weight": 0.0}
    changed = {k: v for k, v in _OUTSIDE_THE_LOOP.items() if k not in read} | other
    assert set(changed) | read == fields  # a new field is placed on one side or the other
    batches = prepare(sources.make("ellipse"), 32, 0.0, jax.random.key(0), 2)
    earlier = [(Relation(4), Relation(4).init(jax.random.key(1), jnp.zeros((1, 3))))]
    g = (Relation(8), Relation(8).init(jax.random.key(2), jnp.zeros((1, 3))))

    def lowered(cfg):
        program = training._syzygy_loop.__wrapped__(
            training._LoopConfig(cfg, training.SYZYGY_LOOP_FIELDS), batches.static(),
            (earlier[0][0],), g[0])
        params = program.module.init(jax.random.key(3), jnp.zeros((1, 3)))
        state = training.init_state(params, program.optimizer, jax.random.key(4))
        args = (batches.data, (earlier[0][1],), g[1], jnp.float32(0.1))
        return program.chunk.lower(state, args).as_text()

    reference = lowered(base)
    assert lowered(base.replace(**changed)) == reference
    assert lowered(base.replace(separation_ratio=7.0)) != reference

    training.fit_syzygy(base, batches, earlier, g, jax.random.key(5), 0.1)
    logs = []
    handler = logging.Handler()
    handler.emit = lambda record: logs.append(record.getMessage())
    logger = logging.getLogger("jax")
    logger.addHandler(handler)
    try:
        with jax.log_compiles():
            g_later = (g[0], jax.tree.map(lambda x: 2 * x, g[1]))
            training.fit_syzygy(base, batches, earlier, g_later, jax.random.key(6), 0.3)
    finally:
        logger.removeHandler(handler)
    assert not [m for m in logs if m.startswith(("Compiling jit(run)", "Compiling jit(judge)"))]


def test_two_fits_of_equal_sources_key_their_programs_alike():
    """`Batches.static()` keys the compiled programs: equal for two `sources.make` of the same
    source and options (a bound `sample` would be equal only for one object), different for
    other options, and a source that cannot be hashed is equal only to itself."""
    def static(source, seed=0):
        return prepare(source, 32, 0.0, jax.random.key(seed), 2).static()

    first, again = static(sources.make("ellipse")), static(sources.make("ellipse"), seed=1)
    assert first == again and hash(first) == hash(again)
    assert static(sources.make("block45")) != static(sources.make("block45", friction=0.1))

    class Unhashable:
        __hash__ = None

        def sample(self, key, n):
            return sources.make("circle").sample(key, n)

    one = Unhashable()
    assert static(one) == static(one) and static(one) != static(Unhashable())
