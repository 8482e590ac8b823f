"""Imposing relations on latents (paper eq. 4): layout, penalty forms, gradients, a tiny run.

The relation used here is written by hand: g(τ) = tanh⁴(c·τ) with
c·τ = 0.2·(s1 − s0 − ½(v0 + v1)·dt), the trapezoid rule of a sliding block (scaled into tanh's
near-linear range). Its zero set is exactly that plane, so consistent latents give exactly zero
and inconsistent ones a known value.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml import learners, relations
from jaml.relations.networks import Relation
from jaml.relations.relation_set import RelationSet
from jaml.relations.transfer import LatentLayout, LayoutError, latent_penalty, residual

NAMES = ("theta", "s0", "v0", "a0", "s1", "v1")
DT = 0.5
COEFFS = 0.2 * np.array([0.0, -1.0, -DT / 2, 0.0, 1.0, -DT / 2], np.float32)  # in NAMES order
# PRED with a 1-entry static part and 2 dynamic entries per step: z_t = [theta, s_t, v_t].
LAYOUT = LatentLayout(static={"theta": 0}, dynamic={"s": 1, "v": 2}, actions={"a": 0})


def trapezoid_relations(on_mean=1e-3, scale=1.0) -> RelationSet:
    """One relation whose first hidden unit carries c·τ (c = scale · COEFFS) through three tanh
    layers and the output tanh: g = tanh(tanh(tanh(tanh(c·τ))))."""
    module = Relation(4, 3)
    params = module.init(jax.random.key(0), jnp.zeros((1, len(NAMES))))

    def handwritten(path, leaf):
        name = "/".join(str(getattr(p, "key", p)) for p in path)
        out = np.zeros(leaf.shape, np.float32)
        if name.endswith("kernel"):  # stored [out, in]
            if leaf.shape[1] == len(NAMES):
                out[0, :] = scale * COEFFS
            else:
                out[0, 0] = 1.0
        return jnp.asarray(out)

    params = jax.tree_util.tree_map_with_path(handwritten, params)
    rs = RelationSet.empty(len(NAMES), 3, 1.5, NAMES)
    return rs.append(params, on_mean, 1.0, 4)


def latents(s0, v0, v1, s1=None, theta=0.3):
    """z [B, 2, 3] for given per-row values; s1 defaults to the consistent value."""
    s0, v0, v1 = map(np.asarray, (s0, v0, v1))
    s1 = s0 + DT * (v0 + v1) / 2 if s1 is None else np.asarray(s1)
    theta = np.full_like(s0, theta)
    z = np.stack([np.stack([theta, s0, v0], -1), np.stack([theta, s1, v1], -1)], axis=1)
    return jnp.asarray(z, jnp.float32)


def test_penalty_is_zero_on_consistent_latents_and_grows_with_the_violation():
    rs = trapezoid_relations()
    pen = latent_penalty(rs, LAYOUT, latent_size=3, action_size=1, weight=1.0, form="sum")
    actions = jnp.ones((3, 2, 1))
    z = latents([0.1, 0.5, -0.2], [0.3, -1.0, 0.0], [0.7, 0.2, 0.4])
    np.testing.assert_allclose(pen(z, actions), 0.0, atol=1e-7)
    off = [0.01, 0.05, 0.2]
    bad = latents([0.1, 0.5, -0.2], [0.3, -1.0, 0.0], [0.7, 0.2, 0.4],
                  s1=np.asarray(z[:, 1, 1]) + off)
    value = np.asarray(pen(bad, actions))
    expected = np.tanh(np.tanh(np.tanh(np.tanh(0.2 * np.asarray(off)))))
    np.testing.assert_allclose(value, expected, rtol=1e-5)
    # weight scales it; the reference's hinge keeps only |g| above the recorded on-mean, and
    # averages over relations (one here).
    heavy = latent_penalty(rs, LAYOUT, latent_size=3, action_size=1, form="sum", weight=10.0)
    np.testing.assert_allclose(heavy(bad, actions), 10 * value, rtol=1e-6)
    hinge = latent_penalty(trapezoid_relations(on_mean=0.005), LAYOUT, latent_size=3,
                           action_size=1, weight=1.0, form="hinge")
    np.testing.assert_allclose(hinge(bad, actions), np.where(value > 0.005, value, 0.0),
                               rtol=1e-5)


def test_penalty_sums_over_consecutive_pairs_in_the_relations_order():
    """Three latent steps give two transitions (0→1, 1→2); a relation set whose coordinates
    are listed in another order reads the same latents by name."""
    rs = trapezoid_relations()
    pen = latent_penalty(rs, LAYOUT, latent_size=3, action_size=1, weight=1.0, form="sum")
    z2 = latents([0.0], [0.0], [0.0], s1=[0.1])
    three = jnp.concatenate([z2, z2[:, 1:] + jnp.asarray([0.0, 0.2, 0.0])], axis=1)
    g01 = np.tanh(np.tanh(np.tanh(np.tanh(0.2 * 0.1))))
    g12 = np.tanh(np.tanh(np.tanh(np.tanh(0.2 * 0.2))))
    np.testing.assert_allclose(pen(three, jnp.zeros((1, 3, 1))), [g01 + g12], rtol=1e-5)
    # The same relation with its coordinates permuted.
    order = [4, 0, 3, 1, 5, 2]
    rs_perm = trapezoid_relations()
    first = dict(rs_perm.params[0]["params"])
    first["hidden0_kernel"] = first["hidden0_kernel"][:, np.array(order)]
    rs_perm = rs_perm.replace(params=({"params": first},),
                              dim_names=tuple(NAMES[i] for i in order))
    pen_perm = latent_penalty(rs_perm, LAYOUT, latent_size=3, action_size=1, weight=1.0,
                              form="sum")
    np.testing.assert_allclose(pen_perm(three, jnp.zeros((1, 3, 1))), [g01 + g12], rtol=1e-5)


def test_layout_mismatch_and_unnamed_relations_are_named_errors():
    rs = trapezoid_relations()
    with pytest.raises(LayoutError, match="'theta' has no place"):
        latent_penalty(rs, LatentLayout(static={}, dynamic={"s": 1, "v": 2}), latent_size=3,
                       action_size=1)
    with pytest.raises(LayoutError, match="'omega' is not a relation coordinate"):
        latent_penalty(rs, LatentLayout(static={"theta": 0, "omega": 1},
                                        dynamic={"s": 1, "v": 2}), latent_size=3, action_size=1)
    with pytest.raises(LayoutError, match="index 5 outside"):
        latent_penalty(rs, LatentLayout(static={"theta": 0}, dynamic={"s": 1, "v": 5}),
                       latent_size=3, action_size=1)
    with pytest.raises(LayoutError, match="no coordinate names"):
        latent_penalty(rs.replace(dim_names=()), LAYOUT, latent_size=3, action_size=1)
    with pytest.raises(ValueError, match="form must be one of"):
        latent_penalty(rs, LAYOUT, latent_size=3, action_size=1, form="max")
    pen = latent_penalty(rs, LAYOUT, latent_size=3, action_size=1)
    with pytest.raises(ValueError, match="needs z"):
        pen(jnp.zeros((2, 2, 4)), jnp.zeros((2, 2, 1)))


def test_bad_relation_files_raise_named_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="no relations checkpoint"):
        relations.load(tmp_path / "missing")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "file").write_text("not a checkpoint")
    with pytest.raises(ValueError, match="relations checkpoint"):
        relations.load(tmp_path / "junk")


SMALL = dict(conv_filters=(8, 8, 8, 8), conv_features=16, deconv_filters=(8, 8, 8, 8),
             mlp_widths=(32,), hist=1, pred=1, static_dim=1, latent_dim=2, mu_nl=False)


def _frames(seed, b=16):
    """Moving colour gradients, [B, 2, 64, 64, 3] uint8, and actions [B, 2, 1]."""
    rng = np.random.default_rng(seed)
    ramp = np.linspace(0.0, 1.0, 64)
    coef = rng.uniform(size=(b, 1, 1, 1, 3))
    phase = rng.uniform(size=(b, 1, 1, 1, 1)) + np.arange(2)[None, :, None, None, None] * 0.1
    img = np.mod(ramp[None, None, None, :, None] * coef + ramp[None, None, :, None, None] * 0.3
                 + phase, 1.0)
    return (img * 255).astype(np.uint8), rng.uniform(-1, 1, size=(b, 2, 1)).astype(np.float32)


def _posterior_means(learner, variables, frames, actions):
    """μ [B, S, P] with BatchNorm on the batch's statistics, as in training (40 steps leave the
    running averages far from them)."""
    x, a = learner.check_batch(frames, actions)
    return learner.module.apply(variables, x, a, True, method="posterior",
                                mutable=["batch_stats"])[0][0]


def _tiny_pred():
    """A small PRED, the trapezoid penalty at weight 1000 and a first train state."""
    learner = learners.make("PRED", ld_dim=2, learning_rate=1e-3, **SMALL)
    rs = trapezoid_relations()
    pen = latent_penalty(rs, LAYOUT, latent_size=learner.config.penalty_dim, action_size=1,
                         weight=1000.0, form="sum")
    opt = learners.default_optimizer(learner)
    state0 = learners.init_train_state(learner, opt, jax.random.key(0), _frames(0))
    return learner, rs, pen, opt, state0


def test_penalty_reaches_the_encoder_and_not_the_decoder():
    learner, _, pen, _, state0 = _tiny_pred()
    data = _frames(0)

    # The penalty's gradient reaches the encoder's parameters (the conv stack and the head).
    def penalty_only(params):
        variables = {"params": params, "batch_stats": state0.batch_stats}
        x, a = learner.check_batch(*data)
        out, _ = learner.module.apply(variables, x, a, jax.random.key(1), train=True,
                                      mutable=["batch_stats"])
        return jnp.mean(pen(out.z, a))

    grads = jax.jit(jax.grad(penalty_only))(state0.params)  # one program, not op by op
    for part in ("conv", "head"):
        norm = sum(float(jnp.sum(g**2)) for g in jax.tree.leaves(grads[part]))
        assert norm > 0, part
    assert all(float(jnp.sum(g**2)) == 0 for g in jax.tree.leaves(grads["decoder"]))


@pytest.mark.slow  # two 50-step trainings, each compiled on its own: ~2 min on 2 CPU cores
def test_a_tiny_pred_run_with_the_penalty_lowers_the_residual():
    learner, rs, pen, opt, state0 = _tiny_pred()

    def train(latent_penalty):
        step = jax.jit(learners.make_train_step(learner, opt, latent_penalty))
        state = state0
        for i in range(50):
            state, _ = step(state, _frames(i + 1), jax.random.key(i))
        test = _frames(100, b=64)
        z = _posterior_means(learner, state.variables, *test)
        return float(jnp.mean(residual(rs, LAYOUT, z, test[1])))

    # Measured on this tiny setup: 0.06 with the penalty vs 0.11 without (the penalty first
    # shrinks the posterior's spread, then moves its mean; 50 steps do only part of that).
    plain, imposed = train(None), train(pen)
    assert imposed < 0.75 * plain, (imposed, plain)


def test_select_keeps_the_chosen_relations_and_their_statistics():
    """Three relations that differ (g_k = tanh⁴(k · c·τ)): the selection keeps relations 1 and
    3, their parameters with their statistics, in order."""
    rs = trapezoid_relations(on_mean=0.1)
    for k, on in ((2, 0.2), (3, 0.3)):
        rs = rs.append(trapezoid_relations(scale=k).params[0], on, float(k), 4)
    picked = rs.select([0, 2])
    assert picked.num_relations == 2 and picked.widths == (4, 4)
    np.testing.assert_allclose(picked.on_means, [0.1, 0.3])
    np.testing.assert_allclose(picked.off_means, [1.0, 3.0])
    tau = np.random.default_rng(0).normal(size=(5, len(NAMES))).astype(np.float32)
    by_hand = np.stack([np.tanh(np.tanh(np.tanh(np.tanh(k * tau @ COEFFS)))) for k in (1, 3)], -1)
    np.testing.assert_allclose(relations.evaluate(picked, tau), by_hand, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match=r"indices must name relations in 0\.\.2"):
        rs.select([3])


def test_ok_rows_are_those_under_every_on_mean_and_random_rows_match_their_count():
    """The reference's ok rows (|g_k| < on_mean_k on every transition), hand-computed from the
    known violations; the random control draws as many rows per batch, others among them."""
    on_mean = 0.005
    rs = trapezoid_relations(on_mean=on_mean)
    off = np.array([0.0, 0.001, 0.2, 0.0, 0.05, 0.0, 0.3, 0.0])
    z0 = latents(np.linspace(0, 0.5, 8), np.zeros(8), np.full(8, 0.4))
    bad = latents(np.linspace(0, 0.5, 8), np.zeros(8), np.full(8, 0.4),
                  s1=np.asarray(z0[:, 1, 1]) + off)
    actions = jnp.zeros((8, 2, 1))
    g = np.tanh(np.tanh(np.tanh(np.tanh(0.2 * off))))
    expected = g < on_mean
    pen = latent_penalty(rs, LAYOUT, latent_size=3, action_size=1, weight=2.0, ok_weight=10.0)
    np.testing.assert_array_equal(pen.ok(bad, actions), expected)
    terms = pen.terms(bad, actions, jax.random.key(0))
    np.testing.assert_array_equal(terms.ok, expected)
    np.testing.assert_allclose(terms.value, 2.0 * np.where(g > on_mean, g, 0.0), rtol=1e-5)
    assert terms.ok_weight == 10.0
    control = latent_penalty(rs, LAYOUT, latent_size=3, action_size=1, weight=0.0,
                             ok_weight=10.0, ok_rows="random")
    draws = [np.asarray(control.terms(bad, actions, jax.random.key(k)).ok) for k in range(20)]
    assert all(d.sum() == expected.sum() for d in draws)
    assert any((d != expected).any() for d in draws)
    np.testing.assert_array_equal(control(bad, actions), 0.0)
    # At another arm's measured rate: round(0.3 × 8) = 2 random rows per batch, whatever the
    # relations accept here.
    rate = latent_penalty(rs, LAYOUT, latent_size=3, action_size=1, weight=0.0, ok_weight=10.0,
                          ok_rows="random", ok_fraction=0.3)
    draws = [np.asarray(rate.terms(bad, actions, jax.random.key(k)).ok) for k in range(20)]
    assert all(d.sum() == 2 for d in draws) and len({d.tobytes() for d in draws}) > 1
    with pytest.raises(ValueError, match="ok_fraction"):
        latent_penalty(rs, LAYOUT, latent_size=3, action_size=1, ok_fraction=0.3)
    with pytest.raises(ValueError, match="ok_rows"):
        latent_penalty(rs, LAYOUT, latent_size=3, action_size=1, ok_rows="some")
    with pytest.raises(ValueError, match="ok_weight"):
        latent_penalty(rs, LAYOUT, latent_size=3, action_size=1, ok_weight=-1.0)


def test_the_ok_term_reweights_the_ok_rows_nll_and_no_ok_row_adds_nothing():
    """A PRED step with the reference's term: loss − the plain loss = ok_weight × the mean NLL
    of the rows the relations accept, and 0 when none is accepted."""
    learner = learners.make("PRED", ld_dim=2, conv_filters=(8, 8, 8, 8), conv_features=16,
                            deconv_filters=(8, 8, 8, 8), hist=1, pred=1, mlp_widths=(16,),
                            static_dim=1, latent_dim=2, static_per_step=True, mu_nl=False)
    frames = np.random.default_rng(0).integers(0, 255, (4, 2, 64, 64, 3), np.uint8)
    actions = np.zeros((4, 2, 1), np.float32)
    opt = learners.default_optimizer(learner)
    variables = learners.init_train_state(learner, opt, jax.random.key(0),
                                          (frames, actions)).variables
    key = jax.random.key(3)

    def loss(pen):
        return float(jax.jit(lambda v: learner.loss(v, key, frames, actions, pen)[0])(variables))

    plain = loss(None)
    x, a = learner.check_batch(frames, actions)
    out = jax.jit(lambda v: learner.module.apply(v, x, a, key, train=True,
                                                 mutable=["batch_stats"])[0])(variables)
    nll = 0.5 * np.sum((np.asarray(x) - np.asarray(out.recon)) ** 2, axis=(1, 2, 3, 4))
    tau = np.asarray(out.z)
    violation = np.abs(tau[:, 1, 1] - tau[:, 0, 1] - DT * (tau[:, 0, 2] + tau[:, 1, 2]) / 2)
    g = np.tanh(np.tanh(np.tanh(np.tanh(0.2 * violation))))
    on_mean = float(np.median(g))  # half the rows accepted
    pen = latent_penalty(trapezoid_relations(on_mean=on_mean), LAYOUT, latent_size=3,
                         action_size=1, weight=0.0, ok_weight=10.0)
    ok = g < on_mean
    assert 0 < ok.sum() < 4
    np.testing.assert_allclose(loss(pen) - plain, 10.0 * nll[ok].mean(), rtol=2e-4)
    none = latent_penalty(trapezoid_relations(on_mean=1e-12), LAYOUT, latent_size=3,
                          action_size=1, weight=0.0, ok_weight=10.0)
    np.testing.assert_allclose(loss(none), plain, rtol=1e-6)


def test_a_layout_placed_on_a_learners_declared_slots():
    """PRED with a static part of 3 and a dynamic part of 2 declares P = 5 entries: θ goes to
    the last static one (2), s and v to the dynamic ones (3, 4); too many names is refused."""
    from jaml import learners

    config = learners.default_config("PRED", ld_dim=5, static_dim=3, latent_dim=2)
    assert config.penalty_slots == {"static": (0, 1, 2), "dynamic": (3, 4)}
    placed = LatentLayout.place(config.penalty_slots, static=("theta",), dynamic=("s", "v"))
    assert placed == LatentLayout(static={"theta": 2}, dynamic={"s": 3, "v": 4},
                                  actions={"a": 0})
    vae = learners.default_config("VAE_rpl", ld_dim=5)
    assert vae.penalty_slots["static"] == ()
    with pytest.raises(LayoutError, match=r"1 static coordinates.*0 static entries"):
        LatentLayout.place(vae.penalty_slots, static=("theta",), dynamic=("s", "v"))


def test_a_run_configs_penalty_builds_the_penalty_it_names(tmp_path):
    """`jaml.stream.loop.latent_penalty` of a `PenaltyConfig`: the saved relation set, placed by
    name on the slots the learner declares, is the penalty built by hand with `LAYOUT`."""
    from types import SimpleNamespace

    from jaml.configs.stream import PenaltyConfig
    from jaml.stream.loop import latent_penalty as from_config

    relations.save(trapezoid_relations(), tmp_path / "checkpoint")
    learner = SimpleNamespace(config=SimpleNamespace(
        penalty_slots={"static": (0,), "dynamic": (1, 2)}, penalty_dim=3))
    env = SimpleNamespace(action_size=1)
    penalty = PenaltyConfig(weight=2.0, form="sum", relations=str(tmp_path / "checkpoint"),
                            used=(0,), static=("theta",), dynamic=("s", "v"))
    by_hand = latent_penalty(trapezoid_relations(), LAYOUT, latent_size=3, action_size=1,
                             weight=2.0, form="sum")
    z = latents([0.1, 0.5], [0.3, -1.0], [0.7, 0.2], s1=[0.4, 0.1])
    actions = jnp.ones((2, 2, 1))
    built = from_config(penalty, learner, env)
    np.testing.assert_allclose(built(z, actions), by_hand(z, actions), rtol=1e-6)
    assert np.all(np.asarray(by_hand(z, actions)) > 0)  # off the plane: a penalty to match
    with pytest.raises(ValueError, match=r"penalty\.relations names no relation set"):
        from_config(PenaltyConfig(), learner, env)
