"""Alignment regressor: known answers for invertible, noise and half-informative latents."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from jaml import evaluation
from jaml.evaluation import alignment

# E|x − median| / std for a normal variable: what the best constant predictor (the median, under
# an L1 loss) scores in training-std units when latents carry no information about the state.
NORMAL_NOISE_LEVEL = math.sqrt(2.0 / math.pi)  # ≈ 0.798

# Shrunk for speed; everything else (widths, dropout, lr, L1, Adam, split, normalisation) default.
FAST = {"num_iterations": 1500, "batch_size": 128}
N_TRAIN, N_TEST, D, Z = 3000, 2000, 4, 8

# 1500 regressor steps per fit: compiled at XLA's full level (70 s → 27 s for this module).
pytestmark = pytest.mark.xla_optimized


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(0)
    states = rng.normal(size=(N_TRAIN, D)).astype(np.float32)
    states_test = rng.normal(size=(N_TEST, D)).astype(np.float32)
    mix = rng.normal(size=(D, Z)).astype(np.float32)
    assert np.linalg.matrix_rank(mix) == D
    perm = rng.permutation(Z)

    def invertible(s):  # full-rank linear map into Z > D, tanh, then a permutation of latents
        return np.tanh(s @ mix / 2.0)[:, perm]

    half_mix = rng.normal(size=(D // 2, Z)).astype(np.float32)

    def keep_half(s):  # only the first D/2 state dimensions reach the latents
        return np.tanh(s[:, : D // 2] @ half_mix / 2.0)

    return {
        "rng": rng,
        "states": states,
        "states_test": states_test,
        "invertible": invertible,
        "keep_half": keep_half,
    }


@pytest.fixture(scope="module")
def invertible_errors(data):
    f, s, st = data["invertible"], data["states"], data["states_test"]
    wide = 2.0 * data["rng"].normal(size=(N_TEST, D)).astype(np.float32)  # off the train support
    return evaluation.alignment_errors(
        f(s), s, {"pi_curr": (f(st), st), "pi_rand": (f(wide), wide)}, seed=0, **FAST
    )


def test_invertible_map_aligns(invertible_errors):
    err = np.asarray(invertible_errors["pi_curr"])
    assert err.shape == (D,)
    assert np.all(err < 0.15), err
    assert np.all(np.asarray(invertible_errors["validation"]) < 0.15)
    # States twice as spread as in training: tanh saturates and the regressor extrapolates.
    assert np.mean(invertible_errors["pi_rand"]) > 2 * np.mean(err)


def test_noise_latents_score_the_median_predictor(data):
    s, st, rng = data["states"], data["states_test"], data["rng"]
    noise_train = rng.normal(size=(N_TRAIN, Z)).astype(np.float32)
    noise_test = rng.normal(size=(N_TEST, Z)).astype(np.float32)
    err = np.asarray(evaluation.alignment_error(noise_train, s, noise_test, st, **FAST))
    assert abs(err.mean() - NORMAL_NOISE_LEVEL) < 0.04, err
    assert np.all(np.abs(err - NORMAL_NOISE_LEVEL) < 0.08), err
    # The regressor fed noise scores what the latent-free constant scores on the same rows.
    constant = evaluation.constant_errors(s, {"test": st}, **FAST)["test"]
    np.testing.assert_allclose(err, constant, atol=0.05)


def test_constant_errors_by_hand():
    # 5 rows: the first (30 %, floored) is held out, the median of [1, 2, 3, 10] is 2.5.
    y = np.array([[0.0], [1.0], [2.0], [3.0], [10.0]])
    test = np.array([[0.0], [5.0]])  # |0 − 2.5| and |5 − 2.5|
    raw = evaluation.constant_errors(y, {"t": test}, normalize=False)["t"]
    np.testing.assert_allclose(raw, [2.5], rtol=1e-6)
    std = math.sqrt(((1 - 4) ** 2 + (2 - 4) ** 2 + (3 - 4) ** 2 + (10 - 4) ** 2) / 4)
    z = evaluation.constant_errors(y, {"t": test})["t"]  # training-std units by default
    np.testing.assert_allclose(z, [2.5 / std], rtol=1e-5)
    # With `validation`, the held-out row too (|0 − 2.5|), or NaN where none is held out.
    both = evaluation.constant_errors(y, {"t": test}, normalize=False, validation=True)
    assert list(both) == ["t", "validation"]
    np.testing.assert_allclose(both["validation"], [2.5], rtol=1e-6)
    none = evaluation.constant_errors(y, {"t": test}, validation=True, validation_fraction=0.0)
    assert np.isnan(none["validation"]).all() and none["validation"].shape == (1,)
    with pytest.raises(ValueError, match='"validation" is reserved'):
        evaluation.constant_errors(y, {"validation": test}, validation=True)


def test_constant_errors_score_rotation_blocks_by_their_principal_axis():
    identity = np.eye(3).reshape(1, 9)
    quarter_turn_x = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float).reshape(1, 9)
    train = np.repeat(identity, 10, axis=0)  # median block: the identity
    errors = evaluation.constant_errors(
        train, {"same": identity, "turned": quarter_turn_x}, normalize=False,
        rotation_starts=(0,))
    assert errors["same"].shape == (10,)  # 9 entries, then the block's principal-axis error
    np.testing.assert_allclose(errors["same"], 0.0, atol=1e-7)
    # The z axis turned onto −y: min(|M[i,2] − e_z[i]|, |M[i,2] + e_z[i]|) = (0, 1, 1) → 2/3.
    np.testing.assert_allclose(errors["turned"][-1], 2 / 3, rtol=1e-6)
    np.testing.assert_allclose(errors["turned"][:9],
                               np.abs(quarter_turn_x - identity)[0], atol=1e-7)
    with pytest.raises(ValueError, match=r"test_states\['bad'\] must be \[Nt, 9\]"):
        evaluation.constant_errors(train, {"bad": np.zeros((2, 3))}, normalize=False)


def test_half_the_state_is_recovered_per_dimension(data):
    h, s, st = data["keep_half"], data["states"], data["states_test"]
    err = np.asarray(evaluation.alignment_error(h(s), s, h(st), st, **FAST))
    kept, dropped = err[: D // 2], err[D // 2 :]
    assert np.all(kept < 0.1), err
    assert np.all(np.abs(dropped - NORMAL_NOISE_LEVEL) < 0.08), err


def test_error_is_in_training_std_units(data, invertible_errors):
    f, s, st = data["invertible"], data["states"], data["states_test"]
    scale = np.array([100.0, 0.01, 1.0, 5.0], np.float32)
    shift = np.array([3.0, -1.0, 0.0, 50.0], np.float32)
    err = evaluation.alignment_error(f(s), s * scale + shift, f(st), st * scale + shift, **FAST)
    np.testing.assert_allclose(err, invertible_errors["pi_curr"], rtol=0.05, atol=0.005)


def test_same_seed_same_result_without_recompiling(data, invertible_errors):
    f, s, st = data["invertible"], data["states"], data["states_test"]
    compiled = alignment._train._cache_size()
    again = evaluation.alignment_error(f(s), s, f(st), st, seed=0, **FAST)
    other = evaluation.alignment_error(f(s), s, f(st), st, seed=1, **FAST)
    assert alignment._train._cache_size() == compiled
    np.testing.assert_array_equal(again, invertible_errors["pi_curr"])
    assert not np.array_equal(other, again)


def test_error_by_hand_for_a_constant_regressor():
    rng = np.random.default_rng(1)
    y = rng.uniform(-2, 5, size=(50, 3)).astype(np.float32)
    x = rng.normal(size=(50, 2)).astype(np.float32)
    mean, std = np.array([1.0, 0.0, -1.0]), np.array([2.0, 0.5, 4.0])
    zeros = [
        {"w": jnp.zeros((2, 4)), "b": jnp.zeros(4)},
        {"w": jnp.zeros((4, 3)), "b": jnp.zeros(3)},
    ]
    reg = alignment.Regressor(zeros, jnp.asarray(mean, jnp.float32),
                              jnp.asarray(std, jnp.float32), jnp.full(3, jnp.nan))
    # The net predicts 0 in normalised units, i.e. the training mean.
    expected = np.abs(y - mean).mean(axis=0) / std
    np.testing.assert_allclose(evaluation.regressor_error(reg, x, y), expected, rtol=1e-5)


def test_minibatch_and_split_follow_the_reference():
    cfg = evaluation.RegressorConfig()
    assert (cfg.hidden, cfg.dropout, cfg.learning_rate, cfg.num_iterations) == (
        (256, 256), 0.2, 1e-4, 10_000)
    assert cfg.batch_for(10_000) == 4096  # VAE: L = 1
    assert evaluation.RegressorConfig(seq_len=24).batch_for(10_000) == 4 * 42
    assert evaluation.RegressorConfig(seq_len=16).batch_for(10_000) == 4 * 64
    assert cfg.batch_for(1000) == 1000
    assert cfg.split(10_000) == 3000


def test_bad_inputs_raise_before_training(data):
    s, st = data["states"], data["states_test"]
    lat = data["invertible"](s)
    lat_t = data["invertible"](st)
    cases = {
        "mismatched N": (lat[:-1], s, lat_t, st),
        "2-D": (lat[:, 0], s, lat_t, st),
        "2-D array": (lat, s, lat_t, st[None]),
        "floating-point dtype": (lat, s.astype(np.int32), lat_t, st),
        "NaN or inf": (np.where(np.arange(N_TRAIN)[:, None] == 7, np.nan, lat), s, lat_t, st),
        "differ from the training": (lat, s, lat_t[:, :3], st),
        "too few samples": (lat[:1], s[:1], lat_t, st),
    }
    inf_test = lat_t.copy()
    inf_test[3, 1] = np.inf
    cases["NaN or inf "] = (lat, s, inf_test, st)
    for expected, args in cases.items():
        with pytest.raises(ValueError, match=expected.strip()):
            evaluation.alignment_error(*args, **FAST)
    with pytest.raises(ValueError, match="test_sets"):
        evaluation.alignment_errors(lat, s, {}, **FAST)
    with pytest.raises(ValueError, match="epochs"):
        evaluation.alignment_error(lat, s, lat_t, st, epochs=3)
    with pytest.raises(ValueError, match="dropout"):
        evaluation.alignment_error(lat, s, lat_t, st, dropout=1.5)


@pytest.mark.slow
def test_spec_defaults_align_an_invertible_map(data):
    """All reference defaults for a sequence learner with L = 24 (≈ 47 s on 2 CPU cores)."""
    f, st = data["invertible"], data["states_test"]
    rng = np.random.default_rng(2)
    s10k = rng.normal(size=(10_000, D)).astype(np.float32)
    err = np.asarray(evaluation.alignment_error(f(s10k), s10k, f(st), st, seq_len=24))
    assert np.all(err < 0.08), err
