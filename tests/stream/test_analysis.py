"""Stacked analysis: R runs analysed by one `evaluate_runs` call must each get what `evaluate`
gives that run alone (the same keys: the same replay rows, rollouts and regressor fit).
Rearrange's rotation blocks: the report's objK_rotation entries are the principal-axis errors of
the regressor's predictions (docs/reference/suite.md §5), the same on both paths; other domains'
reports are what the analysis gave before rotation blocks existed.

The regressor checks run by default (≈ 45 s on 2 shared cores, mostly compilation); the
rotation-block tests use synthetic encodings shaped like RearrangeGeom's (53-entry LD state)
instead of compiling its stream. The whole analysis compiles the env and renderer three times
(the epoch that fills the replays, one run's rollouts, the vmapped rollouts): ≈ 10 min on 2
cores shared with other jobs, so it is slow.
"""

import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_mjx
from jaml import evaluation, stream
from jaml.evaluation import alignment, rotation
from jaml.stream import analysis
from jaml.stream import replay as replay_lib
from tests.stream.test_loop import tiny

SEEDS = (0, 1)


@pytest.fixture(autouse=True, scope="module")
def _fast_compiling_prng():
    with jax.threefry_partitionable(False):  # see tests/learners/conftest.py
        yield


def small():
    """VAE_v0 (no kept slots) with narrow convolutions; 8 replay slots fill in one epoch."""
    narrow = {"learner_config.conv_filters": (8, 8, 8, 8), "learner_config.conv_features": 16,
              "learner_config.deconv_filters": (8, 8, 8, 8)}
    return tiny(learner="VAE_v0", overrides={"replay.slots": 8, **narrow}, learner_steps=1)


@pytest.mark.parametrize("normalize", [True, False])
def test_stacked_regressor_fits_match_each_fit_alone(normalize):
    rng = np.random.default_rng(0)
    R, N, Z, D = 3, 40, 5, 2
    x, y = rng.normal(size=(R, N, Z)), rng.normal(size=(R, N, D)) * [1.0, 3.0]
    tests = {"a": (rng.normal(size=(R, 16, Z)), rng.normal(size=(R, 16, D)))}
    seeds = [3, 11, 2**31 - 2]
    # batch 8 < 28 fit rows: random minibatches (the paper-size path), dropout on.
    options = dict(num_iterations=50, batch_size=8, normalize=normalize)
    together = alignment.alignment_errors_runs(x, y, tests, seeds, **options)
    for r, seed in enumerate(seeds):
        alone = alignment.alignment_errors(x[r], y[r], {"a": (tests["a"][0][r], tests["a"][1][r])},
                                           seed, **options)
        assert list(together) == list(alone)  # the same order: run records follow it
        for k in alone:
            # The same keys and rows; only rounding differs (normalisation stats on the device
            # rather than the host, batched rather than single matmuls): ~1e-7 relative per step,
            # grown by 50 Adam steps to well under 1e-5 of errors of order 1.
            np.testing.assert_allclose(together[k][r], alone[k], rtol=1e-5, atol=1e-6, err_msg=k)


@pytest.mark.slow
def test_stacked_runs_analysed_at_once_match_each_run_alone():
    s = stream.build(small())
    states = stream.stack_runs([s.init(jax.random.PRNGKey(seed)) for seed in SEEDS])
    states, _ = stream.run_stacked_epochs(s, states, 1)  # fills the replays, one PPO update
    keys = [jax.random.PRNGKey(10 + seed) for seed in SEEDS]
    pi_rand_keys = [jax.random.PRNGKey(20 + seed) for seed in SEEDS]
    together = analysis.evaluate_runs(s, states, jax.numpy.stack(keys),
                                      jax.numpy.stack(pi_rand_keys))
    assert len(together) == len(SEEDS)
    for r, state in enumerate(stream.unstack_runs(states)):
        alone = analysis.evaluate(s, state, keys[r], pi_rand_keys[r])
        assert list(together[r]["errors"]) == list(alone["errors"]) == [
            "pi_rand", "pi_curr", "validation"]
        # The same keys give the same replay rows and rollouts (vmapping the physics, renderer
        # and policy does not change them beyond rounding), each run's encoder is applied alone
        # (the same convolutions), and the regressor fits agree to ~1e-6 (the test above):
        # errors and distortion agree to 1e-4 relative, far below the seeds' differences.
        for k, v in alone["errors"].items():
            np.testing.assert_allclose(together[r]["errors"][k], v, rtol=1e-4, atol=1e-6,
                                       err_msg=k)
        np.testing.assert_allclose(together[r]["distortion"], alone["distortion"], rtol=1e-4)
    assert together[0]["errors"]["pi_rand"] != together[1]["errors"]["pi_rand"]
    # Kept π_rand sets (as `run_many` keeps them): the call that rolls them out and the next,
    # which reads them back from the host, report exactly what the analysis reports without.
    kept = [analysis.PiRandSet() for _ in SEEDS]
    for _ in range(2):
        assert analysis.evaluate_runs(s, states, jax.numpy.stack(keys),
                                      jax.numpy.stack(pi_rand_keys), pi_rand_sets=kept) == together
    assert kept[0].holds(s, pi_rand_keys[0], s.config.eval.rand)
    assert kept[1].holds(s, pi_rand_keys[1], s.config.eval.rand)


# ---------------------------------------------------------------------------------------------
# Rotation blocks, on synthetic encodings (no stream compiled).

Z = 6
EVAL_TRAIN = 56  # 16 held-out rows, as many as each test set: one compiled scoring shape


def _random_rotations(rng, n):
    """[n, 3, 3] rotations (QR of Gaussian matrices, det +1)."""
    q, r = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    return q * np.linalg.det(q)[:, None, None]


def _synthetic(env, key, n):
    """(latents [n, Z], LD [n, D]) drawn from `key`: LD states in the env's layout (rotation
    entries: true rotations, the rest in [−1, 1]) and latents a noisy linear map of them."""
    rng = np.random.default_rng(int(jax.random.randint(key, (), 0, 2**30)))
    names = list(env.ld_state_names)
    ld = rng.uniform(-1, 1, size=(n, len(names)))
    for k in range(sum(n.endswith("_r00") for n in names)):
        s = names.index(f"obj{k}_r00")
        ld[:, s:s + 9] = _random_rotations(rng, n).reshape(n, 9)
    latents = ld @ np.random.default_rng(7).normal(size=(len(names), Z)) / 4
    latents += 0.1 * rng.normal(size=latents.shape)
    return latents.astype(np.float32), ld.astype(np.float32)


def _fake_stream(monkeypatch, env_name, **changes):
    """A Stream stand-in (config, env, seq_len) whose encoded data sets are `_synthetic` draws
    from the keys the analysis passes, for one run and for stacked runs."""
    env = envs_mjx.make(env_name, pixels="off")
    config = stream.for_env(env_name, "VAE_rpl", {
        "num_envs": 8, "eval.train": EVAL_TRAIN, "eval.rand": 16, "eval.curr": 16,
        "eval.regressor_iterations": 30, "ppo.num_minibatches": 4, **changes})
    fake = types.SimpleNamespace(config=config, env=env, seq_len=1)

    def one(stream_, s, key, num, random=None, fingerprints=False, kept=None, store=None):
        sets = _synthetic(env, key, num)
        if fingerprints:  # every input distinct
            sets += (np.arange(num, dtype=np.uint32)[:, None],)
        return sets

    def runs(stream_, states, keys, num, random=None, fingerprints=False, kept=None,
             store=None):
        sets = [one(stream_, None, k, num, fingerprints=fingerprints) for k in keys]
        return tuple(np.stack(x) for x in zip(*sets, strict=True))

    monkeypatch.setattr(analysis, "encoded_replay", runs)
    monkeypatch.setattr(analysis, "encoded_rollouts", runs)
    return fake


def _predict(params, x):
    """The regressor's eval-mode predictions, in NumPy: ReLU MLP, linear last layer."""
    h = np.asarray(x, np.float64)
    for layer in params[:-1]:
        h = np.maximum(h @ np.asarray(layer["w"]) + np.asarray(layer["b"]), 0.0)
    return h @ np.asarray(params[-1]["w"]) + np.asarray(params[-1]["b"])


def test_rearrange_rotation_blocks_are_scored_by_their_principal_axis(monkeypatch):
    fake = _fake_stream(monkeypatch, "RearrangeGeom")
    names = list(fake.env.ld_state_names)
    starts = [names.index(f"obj{k}_r00") for k in range(4)]
    labels = [f"obj{k}_rotation" for k in range(4)]
    assert not fake.config.eval.regressor_normalize  # for_env: Rearrange's targets used as is
    assert analysis.rotation_blocks(fake) == (tuple(starts), tuple(labels))
    assert analysis.error_names(fake) == names + labels
    key, pi_rand_key = jax.random.PRNGKey(3), jax.random.PRNGKey(5)
    report = analysis.evaluate(fake, None, key, pi_rand_key)
    assert list(report["errors"]) == ["pi_rand", "pi_curr", "validation"]
    # By hand: the regressor (the seed the analysis draws, the reference's loss), its
    # predictions in NumPy, each block's principal-axis error of R_trueᵀR̂.
    k_train, k_curr, k_reg = jax.random.split(key, 3)
    seed = int(jax.random.randint(k_reg, (), 0, 2**31 - 1))
    train = _synthetic(fake.env, k_train, EVAL_TRAIN)
    regressor = evaluation.fit_regressor(*train, seed, seq_len=1, num_iterations=30,
                                         normalize=False, rotation_starts=tuple(starts))
    held_out = tuple(a[:16] for a in train)  # the leading 30 % (16 of 56 rows)
    for test_set, (lat, ld) in (("pi_rand", _synthetic(fake.env, pi_rand_key, 16)),
                                ("pi_curr", _synthetic(fake.env, k_curr, 16)),
                                ("validation", held_out)):
        pred = _predict(regressor.params, lat)
        by_block = [float(np.mean(rotation.principal_axis_error(
            ld[:, s:s + 9].reshape(-1, 3, 3), pred[:, s:s + 9].reshape(-1, 3, 3))))
            for s in starts]
        errors = np.asarray(report["errors"][test_set])
        assert errors.shape == (len(names) + 4,)
        np.testing.assert_allclose(errors[len(names):], by_block, rtol=1e-4, err_msg=test_set)
        np.testing.assert_allclose(errors[:len(names)], np.abs(pred - ld).mean(axis=0),
                                   rtol=1e-4, atol=1e-6, err_msg=test_set)
        # The latent-free level on the same rows: the fit rows' median (the last 40 of 56),
        # blocks scored by the same principal-axis error.
        constant = np.median(train[1][16:], axis=0)
        baseline = np.asarray(report["baseline"][test_set])
        np.testing.assert_allclose(baseline[:len(names)], np.abs(constant - ld).mean(axis=0),
                                   rtol=1e-5, atol=1e-6, err_msg=test_set)
        const_blocks = np.broadcast_to(constant, ld.shape)
        np.testing.assert_allclose(baseline[len(names):], [float(np.mean(
            rotation.principal_axis_error(ld[:, s:s + 9].reshape(-1, 3, 3),
                                          const_blocks[:, s:s + 9].reshape(-1, 3, 3))))
            for s in starts], rtol=1e-5, err_msg=test_set)
    assert list(report["baseline"]) == ["pi_rand", "pi_curr", "validation"]
    # The records: the LD entries, then objK_rotation.
    records = evaluation.history_records(6, "VAE_rpl", {"pi_rand": report["errors"]["pi_rand"]},
                                         analysis.error_names(fake))
    assert list(records[0]["errors"])[-5:] == ["obj3_r22", *labels]


def test_rearrange_stacked_runs_get_the_rotation_errors_of_each_run_alone(monkeypatch):
    fake = _fake_stream(monkeypatch, "RearrangeGeom")
    keys = [jax.random.PRNGKey(3), jax.random.PRNGKey(4)]
    pi_rand_keys = [jax.random.PRNGKey(5), jax.random.PRNGKey(6)]
    together = analysis.evaluate_runs(fake, None, jax.numpy.stack(keys),
                                      jax.numpy.stack(pi_rand_keys))
    for r in range(2):
        alone = analysis.evaluate(fake, None, keys[r], pi_rand_keys[r])
        assert list(alone["errors"]) == list(together[r]["errors"])
        for k, v in alone["errors"].items():
            assert len(v) == len(analysis.error_names(fake))
            np.testing.assert_allclose(together[r]["errors"][k], v, rtol=1e-5, atol=1e-6,
                                       err_msg=k)
        for k, v in alone["baseline"].items():
            np.testing.assert_allclose(together[r]["baseline"][k], v, rtol=1e-6, err_msg=k)
    assert together[0]["errors"]["pi_rand"][-4:] != together[1]["errors"]["pi_rand"][-4:]


def test_other_domains_are_analysed_as_before(monkeypatch):
    """CartPole (no rotation blocks, z-scored targets): each test set's error is the fitted
    regressor's NumPy predictions against the targets standardised by the fit rows' mean and
    std, and its baseline the fit rows' median scored the same way, both by hand."""
    fake = _fake_stream(monkeypatch, "CartPole")
    assert analysis.rotation_blocks(fake) == ((), ())
    assert analysis.error_names(fake) == list(fake.env.ld_state_names)
    key, pi_rand_key = jax.random.PRNGKey(3), jax.random.PRNGKey(5)
    report = analysis.evaluate(fake, None, key, pi_rand_key)
    assert list(report["errors"]) == ["pi_rand", "pi_curr", "validation"]
    k_train, k_curr, k_reg = jax.random.split(key, 3)
    seed = int(jax.random.randint(k_reg, (), 0, 2**31 - 1))
    train = _synthetic(fake.env, k_train, EVAL_TRAIN)
    regressor = evaluation.fit_regressor(*train, seed, seq_len=1, num_iterations=30,
                                         normalize=True)
    fit = np.asarray(train[1][16:], np.float64)  # the last 40 of 56 rows: the fit rows
    mean, std = fit.mean(axis=0), fit.std(axis=0) + 1e-6
    np.testing.assert_allclose(regressor.mean, mean, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(regressor.std, std, rtol=1e-4)
    for test_set, (lat, ld) in (("pi_rand", _synthetic(fake.env, pi_rand_key, 16)),
                                ("pi_curr", _synthetic(fake.env, k_curr, 16)),
                                ("validation", tuple(a[:16] for a in train))):
        target = (np.asarray(ld, np.float64) - mean) / std
        np.testing.assert_allclose(report["errors"][test_set],
                                   np.abs(_predict(regressor.params, lat) - target).mean(axis=0),
                                   rtol=1e-4, atol=1e-5, err_msg=test_set)
        np.testing.assert_allclose(report["baseline"][test_set],
                                   np.abs(np.median(fit, axis=0) - ld).mean(axis=0) / std,
                                   rtol=1e-5, atol=1e-6, err_msg=test_set)
    assert list(report["baseline"]) == ["pi_rand", "pi_curr", "validation"]
    # The released code's distortion on the π_rand and replay rows, as `evaluation` scores them.
    names = fake.env.ld_state_names
    for part, (lat, ld) in (("pi_rand", _synthetic(fake.env, pi_rand_key, 16)),
                            ("replay", train)):
        expected = evaluation.irregularity(np.asarray(lat), np.asarray(ld), names)
        assert report["irregularity"][part] == pytest.approx(expected, rel=1e-6), part


def test_rearrange_with_normalised_targets_is_refused():
    config = stream.for_env("RearrangeGeom", "VAE_rpl", {"eval.regressor_normalize": True})
    with pytest.raises(ValueError, match=r"rotation blocks .* set eval.regressor_normalize=False"):
        stream.build(config)



def test_input_fingerprints_follow_what_the_encoder_reads():
    """Equal for sequences that differ only after the last input frame (frames after it, the
    action at it); different for one pixel or one earlier action; stacked runs as one by one."""
    rng = np.random.default_rng(0)
    frames = np.repeat(rng.integers(0, 256, (1, 3, 64, 64, 3), dtype=np.uint8), 4, axis=0)
    actions = np.repeat(rng.uniform(-1, 1, (1, 3, 2)).astype(np.float32), 4, axis=0)
    frames[1, 2] = 0  # after the two input frames
    actions[1, 1] = 0.5  # at the last input frame (the encoder zeroes it)
    frames[2, 0, 10, 20, 1] ^= 1  # one pixel of an input frame
    actions[3, 0, 1] += 1e-3  # the action between the input frames
    fp = np.asarray(analysis.input_fingerprints(2, frames, actions))
    assert fp.shape == (4, 2) and fp.dtype == np.uint32
    assert (fp[1] == fp[0]).all()
    assert (fp[2] != fp[0]).any() and (fp[3] != fp[0]).any() and (fp[2] != fp[3]).any()
    runs = np.asarray(analysis.input_fingerprints(2, np.stack([frames, frames[::-1]]),
                                                  np.stack([actions, actions[::-1]])))
    np.testing.assert_array_equal(runs, np.stack([fp, fp[::-1]]))


# ---------------------------------------------------------------------------------------------
# Kept π_rand sets, with stand-in rollouts and encoders (no stream compiled).

E, L = 4, 3  # envs per chunk, frames per sequence


def _columns(key, lead=()):
    kf, kl = jax.random.split(key)
    return replay_lib.Columns(
        frames=jax.random.randint(kf, (*lead, E, L, 2, 2, 3), 0, 256).astype(np.uint8),
        actions=jnp.zeros((*lead, E, L, 1)), ld=jax.random.normal(kl, (*lead, E, L, 2)),
        starts=jnp.zeros((*lead, E, L), bool))


def _stand_ins(monkeypatch):
    """Rollouts whose sequences depend on the chunk's key and the carried env state (a
    counter), and an encoder whose latents depend on the variables; counts the rollouts."""
    calls = {"chunks": 0}

    def chunk(stream_, states, carry, keys):
        calls["chunks"] += 1
        env_states, random = carry
        return (env_states + 1, random), jax.vmap(
            lambda k, e: _columns(jax.random.fold_in(k, e)))(keys, env_states)

    def encode(stream_, variables, seqs, fingerprints=False):
        pixels = seqs.frames.reshape(*seqs.frames.shape[:-4], -1).astype(np.float32)
        scale = jnp.reshape(variables, (-1,) + (1,) * (pixels.ndim - 1))
        out = (pixels.mean(-1, keepdims=True) * scale, seqs.ld[..., -1, :])
        return (*out, pixels[..., :2].astype(np.uint32)) if fingerprints else out

    monkeypatch.setattr(analysis, "_rollout_start",
                        lambda stream_, states, ks, random: jnp.zeros(len(ks), jnp.int32))
    monkeypatch.setattr(analysis, "_rollout_chunk", chunk)
    monkeypatch.setattr(analysis, "_encode", encode)
    config = types.SimpleNamespace(env="CartPole", env_config=None, num_envs=E,
                                   eval=stream.EvalConfig(transient=120))
    fake = types.SimpleNamespace(config=config, seq_len=L)
    fake.jit = lambda fun, **_: lambda *args: fun(fake, *args)  # as `Stream.jit`, unjitted
    return fake, calls


def _state(variables):
    return types.SimpleNamespace(learner=types.SimpleNamespace(variables=jnp.asarray(variables)))


def _assert_same(a, b):
    assert len(a) == len(b) == 3
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_a_kept_pi_rand_set_is_encoded_again_not_rolled_out_again(monkeypatch):
    fake, calls = _stand_ins(monkeypatch)
    key, num = jax.random.PRNGKey(5), 10  # 3 chunks of 4 envs
    kept = analysis.PiRandSet()

    def encoded_rollouts(variables, key, random=True, kept=None):  # one run: R = 1
        return analysis.encoded_rollouts(fake, _state([variables]), key[None], num, random,
                                         True, kept=None if kept is None else [kept])

    first = encoded_rollouts(1.0, key, kept=kept)
    assert calls["chunks"] == 3 and kept.holds(fake, key, num) and len(kept.chunks) == 3
    assert isinstance(kept.chunks[0].frames, np.ndarray)  # on the host
    # Later analyses (trained variables): the kept sequences, encoded by the new encoder, are
    # what rolling them out again from the same key gives.
    again = encoded_rollouts(2.0, key, kept=kept)
    assert calls["chunks"] == 3
    _assert_same(again, encoded_rollouts(2.0, key))
    assert calls["chunks"] == 6
    assert not np.array_equal(first[0], again[0])  # the encoder's change shows
    # Another key (or size) is rolled out and replaces the kept set.
    other = jax.random.PRNGKey(6)
    encoded_rollouts(2.0, other, kept=kept)
    assert calls["chunks"] == 9 and kept.holds(fake, other, num)
    assert not kept.holds(fake, key, num) and not kept.holds(fake, other, 11)
    # Nor a stream whose rollouts differ (another transient), nor π_curr's sequences.
    longer = types.SimpleNamespace(config=types.SimpleNamespace(**{
        **vars(fake.config), "eval": stream.EvalConfig(transient=121)}), seq_len=L)
    assert not kept.holds(longer, other, num)
    with pytest.raises(ValueError, match="π_rand"):
        encoded_rollouts(2.0, other, random=False, kept=kept)


def test_kept_pi_rand_sets_of_stacked_runs_are_each_runs_own(monkeypatch):
    fake, calls = _stand_ins(monkeypatch)
    keys, num = jnp.stack([jax.random.PRNGKey(5), jax.random.PRNGKey(7)]), 10
    states = _state([1.0, 3.0])
    kept = [analysis.PiRandSet(), analysis.PiRandSet()]
    first = analysis.encoded_rollouts(fake, states, keys, num, True, True, kept=kept)
    assert calls["chunks"] == 3
    assert kept[0].holds(fake, keys[0], num) and kept[1].holds(fake, keys[1], num)
    assert kept[0].chunks[0].frames.shape == (E, L, 2, 2, 3)  # one run's columns each,
    assert kept[0].chunks[0].frames.base is None  # a copy: freed with its run's set alone
    again = analysis.encoded_rollouts(fake, states, keys, num, True, True, kept=kept)
    assert calls["chunks"] == 3
    _assert_same(first, again)
    _assert_same(first, analysis.encoded_rollouts(fake, states, keys, num, True, True))
    # A run's kept set is what its rollouts give alone (the stand-in's per-key sequences).
    alone = analysis.PiRandSet()
    analysis.encoded_rollouts(fake, _state([1.0]), keys[1:], num, True, True, kept=[alone])
    assert calls["chunks"] == 9
    for c in range(3):
        np.testing.assert_array_equal(kept[1].chunks[c].frames, alone.chunks[c].frames)
    # One run without its set: every run is rolled out again, and every set refreshed.
    kept[1] = analysis.PiRandSet()
    analysis.encoded_rollouts(fake, states, keys, num, True, True, kept=kept)
    assert calls["chunks"] == 12 and kept[1].holds(fake, keys[1], num)
