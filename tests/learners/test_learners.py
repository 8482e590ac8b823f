"""Contract sweep over every registered learner, plus PRED, penalties, KL and input checks.

The networks are shrunk (8 filters, small MLP/RNN widths) but keep the 64×64 frames and the
spec's depth; test_spec_architecture checks the full-size layer shapes by abstract evaluation.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml import learners
from jaml.relations.networks import Relation
from jaml.relations.relation_set import RelationSet, penalty

# One of the default suite's longest modules (a compile per learner): scheduled early, see
# tests/conftest.py.
pytestmark = pytest.mark.first

B, A, LD = 2, 2, 2
SMALL_CONV = {"conv_filters": (8, 8, 8, 8), "conv_features": 16, "deconv_filters": (8, 8, 8, 8)}
# Per learner: tiny overrides, and its encode size worked out by hand (2·LD = 4 per VAE step).
TINY = {
    "VAE_v0": ({"mlp_widths": (32, 32)}, 4),
    "VAE_rpl": ({"mlp_widths": (32, 32)}, 4),
    "beta-VAE": ({"mlp_widths": (32, 32)}, 4),
    "SVAE": ({"hist": 3, "rnn_hidden": 16}, 3 * 4),
    "PRED": ({"hist": 2, "pred": 1, "mlp_widths": (32, 32)}, 3 * 4),
    # static LD + 3 steps × dynamic LD
    "DSA": ({"hist": 3, "rnn_hidden": 16, "prior_hidden": 16}, 2 + 3 * 2),
    # 4×4 cells × (where 4 + presence + depth + what 2) + background 2
    "SPAIR": ({"backbone_filters": (8, 8, 8), "lateral_widths": (16,), "passthrough": 8,
               "glimpse_size": 8, "what_dim": 2, "bg_dim": 2, "object_filters": (8, 8),
               "object_hidden": 16, "bg_hidden": 16}, 16 * (4 + 1 + 1 + 2) + 2),
}


def tiny(name, **extra):
    return learners.make(name, ld_dim=LD, **SMALL_CONV, **TINY[name][0], **extra)


def batch(seed, t, b=B):
    """Smooth random images (a colour gradient per sequence, moving over time) and actions.

    Built in numpy: eager JAX would compile a small program per op.
    """
    rng = np.random.default_rng(seed)
    coef = rng.uniform(size=(b, 1, 1, 1, 3))
    ramp = np.linspace(0.0, 1.0, 64)
    rows, cols = ramp[:, None, None], ramp[None, :, None]  # [64, 1, 1], [1, 64, 1]
    phase = np.arange(t)[None, :, None, None, None] / (t + 1)
    img = np.mod(cols * coef + rows * 0.3 + phase, 1.0)  # [B, T, 64, 64, 3]
    return (img * 255).astype(np.uint8), rng.normal(size=(b, t, A)).astype(np.float32)


@pytest.fixture(scope="module")
def runs():
    """name → trained record; every learner is built, initialised and trained once."""
    cache = {}

    def get(name):
        if name not in cache:
            learner = tiny(name, learning_rate=1e-3)
            data = batch(0, learner.seq_len)
            opt = learners.default_optimizer(learner)
            state0 = learners.init_train_state(learner, opt, jax.random.key(0), data)
            traces = []

            def counted(state, b, key):
                traces.append(1)  # runs once per trace, i.e. per compilation
                return learners.make_train_step(learner, opt)(state, b, key)

            step = jax.jit(counted)
            state, history = state0, []
            for i in range(3):
                state, metrics = step(state, data, jax.random.key(i))
                history.append(jax.device_get(metrics))
            cache[name] = dict(learner=learner, data=data, state0=state0, state=state,
                               history=history, step=step, traces=traces)
        return cache[name]

    return get


def test_registry_lists_every_learner_and_the_sweep_covers_it():
    assert set(learners.ALL_LEARNERS) == {"VAE_v0", "VAE_rpl", "beta-VAE", "SVAE", "PRED", "DSA",
                                      "SPAIR"}
    assert set(TINY) == set(learners.ALL_LEARNERS)


@pytest.mark.parametrize("name", learners.ALL_LEARNERS)
def test_learner_trains_with_finite_loss_and_declared_latent(runs, name):
    run = runs(name)
    learner, (frames, actions) = run["learner"], run["data"]
    losses = [float(m["loss"]) for m in run["history"]]
    assert all(np.isfinite(losses)), losses
    # Same batch three times at lr 1e-3: the loss must go down.
    assert losses[-1] < losses[0], losses
    assert int(run["state"].step) == 3
    z = jax.jit(learner.encode)(run["state"].variables, frames, actions)
    assert z.shape == (B, TINY[name][1]) == (B, learner.latent_size)
    assert bool(jnp.all(jnp.isfinite(z)))
    # Training moved the parameters and the BatchNorm running statistics.
    for key in ("params", "batch_stats"):
        before = jax.tree.leaves(getattr(run["state0"], key))
        after = jax.tree.leaves(getattr(run["state"], key))
        assert any(not np.allclose(a, b) for a, b in zip(before, after, strict=True)), key


@pytest.mark.parametrize("name", learners.ALL_LEARNERS)
def test_jitted_step_does_not_recompile_on_a_new_batch(runs, name):
    run = runs(name)
    other = batch(1, run["learner"].seq_len)
    _, metrics = run["step"](run["state"], other, jax.random.key(7))
    assert np.isfinite(float(metrics["loss"]))
    assert len(run["traces"]) == 1


@pytest.mark.parametrize("name", learners.ALL_LEARNERS)
def test_same_seed_same_params_and_another_seed_differs(runs, name):
    run = runs(name)
    learner, opt = run["learner"], learners.default_optimizer(run["learner"])
    again = learners.init_train_state(learner, opt, jax.random.key(0), run["data"]).params
    for a, b in zip(jax.tree.leaves(run["state0"].params), jax.tree.leaves(again), strict=True):
        np.testing.assert_array_equal(a, b)
    other = learners.init_train_state(learner, opt, jax.random.key(1), run["data"]).params
    assert any(not np.allclose(a, b) for a, b in zip(jax.tree.leaves(again),
                                                     jax.tree.leaves(other), strict=True))


@pytest.mark.parametrize("name", learners.ALL_LEARNERS)
def test_the_encoder_sees_the_current_action_only_when_observed(runs, name):
    """"observed" (the reference code): the executed action of every input frame reaches the
    latent, a_{h−1} (the move into the first predicted frame) included; "hidden" zeroes a_{h−1}.
    Actions after the input frames never reach it; SPAIR reads no action."""
    run = runs(name)
    (frames, actions), variables = run["data"], run["state"].variables
    observed = run["learner"]
    hidden = tiny(name, learning_rate=1e-3, current_action="hidden")
    hist = observed.config.hist
    assert observed.config.current_action == "observed"
    later, current = actions.copy(), actions.copy()
    later[:, hist:] = 7.0
    current[:, hist - 1] += 3.0
    for learner in (observed, hidden):
        encode = jax.jit(learner.encode)
        base = encode(variables, frames, actions)
        np.testing.assert_array_equal(encode(variables, frames, later), base)
        moved = not np.allclose(encode(variables, frames, current), base)
        assert moved == (learner is observed and name != "SPAIR"), learner.config.current_action
    if hist > 1:  # the actions between input frames reach the latent either way
        earlier = actions.copy()
        earlier[:, 0] += 3.0
        encode = jax.jit(hidden.encode)
        assert not np.allclose(encode(variables, frames, earlier),
                               encode(variables, frames, actions))
    assert (observed.config.actions_seen, hidden.config.actions_seen) == (
        (0, 0) if name == "SPAIR" else (hist, hist - 1))


def _sampled(learner, seed, b=B, key=1):
    """(frames, actions, variables, the training-mode outputs) of a fresh learner on a batch."""
    frames, actions = batch(seed, learner.seq_len, b=b)
    opt = learners.default_optimizer(learner)
    variables = learners.init_train_state(learner, opt, jax.random.key(0),
                                          (frames, actions)).variables
    x, a = learner.check_batch(frames, actions)
    # Jitted: run eagerly, every op of the model compiles apart.
    out = jax.jit(lambda v: learner.module.apply(v, x, a, jax.random.key(key), train=True,
                                                 mutable=["batch_stats"])[0])(variables)
    return frames, actions, variables, out


def test_pred_static_part_is_shared_by_every_step_and_counted_once():
    """F static entries: one sample repeated over the T + L steps, [f, z_1..z_S] encoded, and
    the KL equals the hand-assembled sum (static once, dynamic per step)."""
    learner = learners.make("PRED", ld_dim=LD, **SMALL_CONV, hist=1, pred=2,
                            mlp_widths=(16,), static_dim=3, latent_dim=2)
    cfg = learner.config
    assert (cfg.penalty_dim, cfg.latent_size) == (3 + 2, 3 + 3 * 2)
    frames, actions, variables, out = _sampled(learner, 3)
    x, a = learner.check_batch(frames, actions)
    assert out.z.shape == (B, 3, 5)
    np.testing.assert_array_equal(out.z[:, 1:, :3], np.broadcast_to(out.z[:, :1, :3],
                                                                    (B, 2, 3)))
    assert not np.allclose(out.z[:, 0, 3:], out.z[:, 1, 3:])
    (mu, logvar), _ = jax.jit(lambda v: learner.module.apply(
        v, x, a, True, method="posterior", mutable=["batch_stats"]))(variables)
    kl = lambda m, lv: 0.5 * np.sum(np.exp(lv) + m**2 - 1.0 - lv, axis=-1)  # noqa: E731
    expected = kl(mu[:, 0, :3], logvar[:, 0, :3]) + kl(mu[..., 3:], logvar[..., 3:]).sum(-1)
    np.testing.assert_allclose(out.kl["kl"], expected, rtol=1e-5)
    mu, _ = jax.jit(lambda v: learner.module.apply(v, x, a, False, method="posterior"))(variables)
    z = learner.encode(variables, frames, actions)
    # Two separately compiled programs of the same network: equal to float32 rounding (their
    # fusions may sum in another order; 5e-6 relative was seen on 0.01-sized entries).
    np.testing.assert_allclose(z, np.concatenate([mu[:, 0, :3], mu[..., 3:].reshape(B, -1)],
                                                 -1), rtol=1e-5, atol=1e-6)


def reference_kl(mu, logvar):
    """The released code's KL term (utils/prob.py), written out: it reads logvar as log σ."""
    return -0.5 * np.sum(1 + 2 * logvar - mu**2 - np.exp(logvar) ** 2, axis=-1)


def test_pred_static_per_step_and_the_reference_kl():
    """The reference's PRED_BLK_SM: each step has its own static entries (sampled apart,
    KL-weighted per step), `encode` gives every step's whole mean, and the KL is its form."""
    learner = learners.make("PRED", ld_dim=LD, **SMALL_CONV, hist=1, pred=1,
                            mlp_widths=(16,), static_dim=3, latent_dim=2,
                            static_per_step=True, kl_form="reference")
    cfg = learner.config
    assert (cfg.penalty_dim, cfg.latent_size) == (5, 2 * 5)
    frames, actions, variables, out = _sampled(learner, 4)
    x, a = learner.check_batch(frames, actions)
    assert out.z.shape == (B, 2, 5)
    assert not np.allclose(out.z[:, 0, :3], out.z[:, 1, :3])  # nothing ties the static parts
    (mu, logvar), _ = jax.jit(lambda v: learner.module.apply(
        v, x, a, True, method="posterior", mutable=["batch_stats"]))(variables)
    mu, logvar = np.asarray(mu, np.float64), np.asarray(logvar, np.float64)
    np.testing.assert_allclose(out.kl["kl"], reference_kl(mu, logvar).sum(-1), rtol=1e-5)
    mu_eval, _ = jax.jit(lambda v: learner.module.apply(v, x, a, False,
                                                        method="posterior"))(variables)
    np.testing.assert_allclose(learner.encode(variables, frames, actions),
                               np.asarray(mu_eval).reshape(B, -1), rtol=1e-5, atol=1e-6)


class _FixedTerms:
    """A penalty with the reference's extra term: value z[:, 0, 0]², ok rows given."""

    def __init__(self, ok, weight, ok_weight):
        self.ok, self.weight, self.ok_weight = np.asarray(ok), weight, ok_weight

    def __call__(self, z, actions):
        return self.weight * z[:, 0, 0] ** 2

    def terms(self, z, actions, key):
        from jaml.learners.learner import PenaltyTerms

        return PenaltyTerms(self(z, actions), jnp.asarray(self.ok), self.ok_weight)


@pytest.mark.parametrize("ok", [[True, False, True], [False, False, False]])
def test_reference_recipe_loss_is_s_times_the_released_formula(ok):
    """Our loss with weight S·1e3 and ok_weight 10 equals S × the released code's
    −mean_b mean_t loglik + 1e3·mean_b penalty + 10·(−mean_{ok b} mean_t loglik)
    + mean_{b,t} KL_t (the ok term only when some row is ok), written out from the outputs."""
    learner = learners.make("PRED", ld_dim=LD, **SMALL_CONV, hist=1, pred=1,
                            mlp_widths=(16,), static_dim=3, latent_dim=2,
                            static_per_step=True, kl_form="reference")
    b, s = 3, 2
    frames, actions, variables, out = _sampled(learner, 5, b=b, key=2)
    penalty = _FixedTerms(ok, weight=s * 1e3, ok_weight=10.0)
    loss, metrics = jax.jit(lambda v: learner.loss(v, jax.random.key(2), frames, actions,
                                                   penalty))(variables)
    x, _ = learner.check_batch(frames, actions)
    loglik = -0.5 * np.sum((np.asarray(x, np.float64) - np.asarray(out.recon)) ** 2,
                           axis=(2, 3, 4))  # [B, S]
    frame_mean = loglik.mean(axis=1)
    ok = np.asarray(ok)
    released = (-frame_mean.mean() + 1e3 * np.mean(np.asarray(out.z)[:, 0, 0] ** 2)
                + (10.0 * -frame_mean[ok].mean() if ok.any() else 0.0)
                + np.asarray(out.kl["kl"]).mean() / s)
    np.testing.assert_allclose(loss, s * released, rtol=1e-5)
    np.testing.assert_allclose(metrics["ok_fraction"], ok.mean())


def test_pred_decodes_t_plus_l_frames_from_the_first_t(runs):
    run = runs("PRED")
    learner, (frames, actions), variables = run["learner"], run["data"], run["state"].variables
    recon = jax.jit(learner.reconstruct)(variables, frames, actions)
    assert recon.shape == (B, 2 + 1, 64, 64, 3)
    assert float(recon.min()) > 0.0 and float(recon.max()) < 1.0
    # The last L frames and actions are targets only: the latent must not depend on them.
    encode = jax.jit(learner.encode)
    late_frames, late_actions, early_frames = frames.copy(), actions.copy(), frames.copy()
    late_frames[:, 2:], late_actions[:, 2:], early_frames[:, :1] = 0, 5.0, 0
    changed = encode(variables, late_frames, late_actions)
    np.testing.assert_array_equal(changed, encode(variables, frames, actions))
    assert not np.allclose(encode(variables, early_frames, actions), changed)


@pytest.mark.parametrize("frame_nll", ["sum", "mean"])
def test_sequence_nll_combines_the_decoded_frames(runs, frame_nll):
    """PRED's NLL is −Σ_t log p(x_t | τ_t) over its T + L frames (paper eq. 4), or the mean over
    them with frame_nll="mean" (the reference code), written out here from the decoded means."""
    run = runs("PRED")
    learner = tiny("PRED", frame_nll=frame_nll)
    (frames, actions), variables = run["data"], run["state0"].variables
    key = jax.random.key(3)
    _, metrics = jax.jit(learner.loss)(variables, key, frames, actions)
    x = frames.astype(np.float64) / 255.0
    apply = jax.jit(lambda v, x, a, k: learner.module.apply(v, x, a, k, train=True,
                                                            mutable=["batch_stats"]))
    out, _ = apply(variables, jnp.asarray(x, jnp.float32), jnp.asarray(actions), key)
    per_frame = 0.5 * np.sum((x - np.asarray(out.recon, np.float64)) ** 2, axis=(2, 3, 4))
    combine = np.sum if frame_nll == "sum" else np.mean
    np.testing.assert_allclose(metrics["nll"], np.mean(combine(per_frame, axis=1)), rtol=1e-4)


def test_frame_nll_is_checked():
    with pytest.raises(ValueError, match="frame_nll"):
        tiny("PRED", frame_nll="max")


def _relation_penalty(dim, seen=None):
    """Σ_k |g_k([z_t ⊕ a_t])| summed over steps, from a random relation, as a caller imposes it."""
    relation = Relation(8, 2)
    rs = RelationSet.empty(dim, depth=2, tolerance=1.5).append(
        relation.init(jax.random.key(5), jnp.zeros((dim,))), 0.0, 1.0, width=8)

    def aml(z, a):
        if seen is not None:
            seen["shapes"] = (z.shape, a.shape)
        return penalty(rs, jnp.concatenate([z, a], axis=-1)).sum(axis=1)

    return aml


def test_latent_penalty_changes_gradients_and_a_zero_penalty_does_not(runs):
    run = runs("VAE_v0")
    # Eight frames: BatchNorm over two would amplify the two programs' rounding differences.
    learner, (frames, actions) = run["learner"], batch(2, 1, b=8)
    variables, key = run["state"].variables, jax.random.key(3)
    aml = _relation_penalty(learner.config.z_step + A)

    grad = jax.grad(learner.loss, has_aux=True)

    @jax.jit
    def all_grads(variables):
        # One program for the three cases: XLA shares their common forward pass, so this
        # compiles about as fast as one gradient.
        return (grad(variables, key, frames, actions),
                grad(variables, key, frames, actions, lambda z, a: jnp.zeros(z.shape[0])),
                grad(variables, key, frames, actions, lambda z, a: 10.0 * aml(z, a)))

    (g_none, m_none), (g_zero, m_zero), (g_aml, m_aml) = all_grads(variables)
    g_none, g_zero, g_aml = g_none["params"], g_zero["params"], g_aml["params"]
    assert float(m_aml["penalty"]) > 0.0 and float(m_zero["penalty"]) == 0.0
    np.testing.assert_allclose(m_aml["loss"], m_none["loss"] + m_aml["penalty"], rtol=1e-5)
    flat = lambda g: np.concatenate([np.ravel(x) for x in jax.tree.leaves(g)])  # noqa: E731
    # A zero penalty changes nothing beyond float reassociation between the cases (the
    # loss is ~500); the relations (weighted 10×) move the gradients by orders of magnitude more.
    rel = lambda g: np.linalg.norm(flat(g) - flat(g_none)) / np.linalg.norm(flat(g_none))  # noqa: E731
    assert rel(g_zero) < 1e-6
    assert rel(g_aml) > 100 * max(rel(g_zero), 1e-6)
    # The decoder never sees the penalty: its gradients agree; the encoder's head moves.
    dec = lambda g: flat(g["decoder"])  # noqa: E731
    head = lambda g: flat(g["head"])  # noqa: E731
    assert np.linalg.norm(dec(g_aml) - dec(g_none)) < 1e-4 * np.linalg.norm(dec(g_none))
    assert np.linalg.norm(head(g_aml) - head(g_none)) > 1e-2 * np.linalg.norm(head(g_none))


@pytest.mark.parametrize("name", learners.ALL_LEARNERS)
def test_penalty_receives_the_documented_shapes(name):
    learner = tiny(name)
    frames, actions = batch(0, learner.seq_len)
    variables = jax.eval_shape(learner.init, jax.random.key(0), frames, actions)
    seen = {}
    aml = _relation_penalty(learner.config.penalty_dim + A, seen)
    jax.eval_shape(lambda v: learner.loss(v, jax.random.key(0), frames, actions, aml), variables)
    # S = decoded steps (PRED: T + L); P = per-step latent (DSA: static ⊕ dynamic; SPAIR: the
    # whole sampled latent, laid out as `encode`).
    steps, width = {"SVAE": (3, 4), "PRED": (2 + 1, 4), "DSA": (3, 2 + 2),
                    "SPAIR": (1, TINY["SPAIR"][1])}.get(name, (1, 4))
    assert seen["shapes"] == ((B, steps, width), (B, steps, A))


@pytest.mark.parametrize("name", ["VAE_v0", "beta-VAE"])
def test_loss_is_nll_plus_beta_kl(runs, name):
    metrics = runs(name)["history"][0]
    beta = {"VAE_v0": 1.0, "beta-VAE": 5.0}[name]
    np.testing.assert_allclose(metrics["loss"], metrics["nll"] + beta * metrics["kl"], rtol=1e-5)
    # The NLL is −log p of the decoded mean, between the perfect and the worst reconstruction.
    assert 0.0 < float(metrics["nll"]) < 0.5 * 64 * 64 * 3


def test_learner_kl_is_the_closed_form_of_its_posterior(runs):
    run = runs("VAE_v0")
    learner, (frames, actions) = run["learner"], run["data"]
    # history[0] was computed from state0 on this batch, BatchNorm on batch statistics.
    posterior = jax.jit(lambda v, x, a: learner.module.apply(
        v, x, a, True, method="posterior", mutable=["batch_stats"])[0])
    mu, logvar = posterior(run["state0"].variables, *learner.check_batch(frames, actions))
    mu, logvar = np.asarray(mu, np.float64), np.asarray(logvar, np.float64)
    closed = 0.5 * (np.exp(logvar) + mu**2 - 1 - logvar).sum(axis=(1, 2)).mean()
    np.testing.assert_allclose(run["history"][0]["kl"], closed, rtol=1e-4)


def test_spec_architecture_at_full_size():
    learner = learners.make("VAE_rpl", ld_dim=4)
    frames, actions = jnp.zeros((B, 1, 64, 64, 3), jnp.uint8), jnp.zeros((B, 1, 3))
    shapes = jax.eval_shape(learner.init, jax.random.key(0), frames, actions)["params"]
    conv = shapes["conv"]
    assert [conv[f"conv{i}"]["kernel"].shape for i in range(4)] == [
        (4, 4, 3, 64), (4, 4, 64, 128), (4, 4, 128, 128), (4, 4, 128, 256)]
    assert conv["conv_out"]["kernel"].shape == (4, 4, 256, 128)
    assert all("bias" not in conv[k] for k in conv if k.startswith("conv"))
    dec = shapes["decoder"]
    assert [dec[f"deconv{i}"]["kernel"].shape for i in range(4)] == [
        (4, 4, 8, 256), (4, 4, 256, 128), (4, 4, 128, 128), (4, 4, 128, 64)]
    assert dec["deconv_out"]["kernel"].shape == (4, 4, 64, 3)
    assert shapes["trunk"]["dense0"]["kernel"].shape == (128 + 3, 1024)
    assert shapes["head"]["mu"]["kernel"].shape == (512, 8)
    out = jax.eval_shape(lambda v: learner.reconstruct(v, frames, actions),
                         jax.eval_shape(learner.init, jax.random.key(0), frames, actions))
    assert out.shape == (B, 1, 64, 64, 3)
    # Reference defaults: latent 2·D per step, Adam 1e-4, β = 5 for β-VAE; VAE_v0 is VAE_rpl
    # (their replays differ: tests/stream/test_loop.py).
    assert learner.latent_size == 8 and learner.config.learning_rate == 1e-4
    assert learners.make("beta-VAE", ld_dim=4).config.beta == 5.0
    assert learners.make("VAE_v0", ld_dim=4).config == learners.make("VAE_rpl", ld_dim=4).config
    assert learners.make("PRED", ld_dim=4).seq_len == 24
    assert learners.make("DSA", ld_dim=4).latent_size == 4 + 24 * 4


def test_bad_names_configs_and_shapes_raise():
    with pytest.raises(ValueError, match="valid names: VAE_v0, VAE_rpl, beta-VAE"):
        learners.make("VAE", ld_dim=2)
    with pytest.raises(ValueError, match="unknown config fields"):
        learners.make("PRED", ld_dim=2, horizon=3)
    with pytest.raises(ValueError, match="ld_dim"):
        learners.make("SVAE")
    with pytest.raises(ValueError, match="ld_dim must be"):
        learners.make("VAE_v0", ld_dim=0)
    with pytest.raises(ValueError, match="needs a SVAEConfig"):
        learners.make("SVAE", config=learners.VAEConfig(ld_dim=2))
    with pytest.raises(ValueError, match="hist ≥ 2"):
        learners.make("DSA", ld_dim=2, hist=1)
    learner = tiny("SVAE")
    frames, actions = batch(0, 3)
    key = jax.random.key(0)
    with pytest.raises(ValueError, match="sequence length must be T = 3"):
        learner.init(key, frames[:, :2], actions[:, :2])
    with pytest.raises(ValueError, match=r"actions must be \[B, T, A\]"):
        learner.init(key, frames, actions[:1])
    with pytest.raises(ValueError, match=r"frames must be \[B, T, 64, 64, 3\]"):
        learner.init(key, frames[:, :, :32, :32], actions)
    with pytest.raises(ValueError, match=r"actions must be \[B, T, A\]"):
        learner.encode({}, frames, actions[..., 0])


def test_a_penalty_of_the_wrong_shape_raises():
    learner = tiny("VAE_v0")
    frames, actions = batch(0, 1)
    variables = jax.eval_shape(learner.init, jax.random.key(0), frames, actions)
    with pytest.raises(ValueError, match="latent_penalty must return"):
        jax.eval_shape(lambda v: learner.loss(v, jax.random.key(0), frames, actions,
                                              lambda z, a: jnp.abs(z).sum(-1)), variables)
