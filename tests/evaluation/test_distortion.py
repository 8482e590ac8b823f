"""Distortion Var(ρ) (eq. 5): zero for similarities, additive ρ, zero distances."""

import math

import numpy as np
import pytest

from jaml import evaluation

N, D = 2000, 3


def _states(seed=0, n=N):
    return np.random.default_rng(seed).uniform(-1.0, 1.0, size=(n, D))


def _similarity(seed=1, out_dim=5):
    """τ ↦ s·τQ + b with Q [D, out_dim] having orthonormal rows: a rotation into R^out_dim."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(out_dim, D)))
    scale, shift = 2.5, rng.normal(size=out_dim) * 3.0
    return lambda t: scale * t @ q.T + shift


def test_coefficients_match_a_plain_loop():
    rng = np.random.default_rng(3)
    lat, st = rng.normal(size=(7, 4)), rng.normal(size=(7, 2))
    rho, valid = evaluation.distortion_coefficients(lat, st, num_pairs=50, seed=5)
    i, j = evaluation.sample_pairs(7, 50, seed=5)
    for k, (a, b) in enumerate(zip(np.asarray(i), np.asarray(j), strict=True)):
        assert a != b
        expected = math.log(np.linalg.norm(lat[a] - lat[b]) / np.linalg.norm(st[a] - st[b]))
        assert valid[k]
        assert rho[k] == pytest.approx(expected, rel=1e-5, abs=1e-5)
    expected_var = np.var(np.asarray(rho, np.float64))
    assert evaluation.distortion(lat, st, num_pairs=50, seed=5) == pytest.approx(expected_var)


@pytest.mark.parametrize("out_dim", [D, 5])
def test_similarity_has_zero_distortion(out_dim):
    t = _states()
    assert evaluation.distortion(_similarity(out_dim=out_dim)(t), t) < 1e-9


def test_nonlinear_warp_has_positive_distortion():
    t = _states()
    warped = np.tanh(2.0 * t) + 0.3 * t**3
    assert evaluation.distortion(warped, t) > 1e-3


def test_rho_is_additive_under_composition():
    t = _states()
    a = np.random.default_rng(4).normal(size=(D, D))
    g = np.tanh(t @ a)  # g: τ ↦ tanh(τA)
    h = g**3 + g  # h = f ∘ g with f(u) = u³ + u, elementwise
    rho_h, valid_h = evaluation.distortion_coefficients(h, t, seed=7)
    rho_g, valid_g = evaluation.distortion_coefficients(g, t, seed=7)
    rho_f, valid_f = evaluation.distortion_coefficients(h, g, seed=7)  # f on (g(τ1), g(τ2))
    assert np.all(valid_h) and np.all(valid_g) and np.all(valid_f)
    np.testing.assert_allclose(rho_h, np.asarray(rho_g) + np.asarray(rho_f), atol=2e-5)
    # A similarity after g adds a constant to every ρ, so the variance is unchanged.
    sim_g = _similarity()(g)
    assert evaluation.distortion(sim_g, t, seed=7) == pytest.approx(
        evaluation.distortion(g, t, seed=7), rel=1e-4
    )
    assert evaluation.distortion(h, t, seed=7) != pytest.approx(
        evaluation.distortion(g, t, seed=7), rel=1e-2
    )


def test_coincident_pairs_are_skipped():
    base = _states(n=10)
    t = np.concatenate([base, base])  # every point appears twice
    lat = np.sin(3.0 * t) + t
    rho, valid = evaluation.distortion_coefficients(lat, t, num_pairs=400, seed=2)
    i, j = (np.asarray(v) for v in evaluation.sample_pairs(20, 400, seed=2))
    coincident = (i % 10) == (j % 10)
    assert coincident.any() and (~coincident).any()
    np.testing.assert_array_equal(np.asarray(valid), ~coincident)
    assert np.all(np.isnan(np.asarray(rho)[coincident]))
    value = evaluation.distortion(lat, t, num_pairs=400, seed=2)
    assert np.isfinite(value)
    assert value == pytest.approx(np.var(np.asarray(rho, np.float64)[~coincident]))


def test_collapsed_distinct_states_give_infinite_distortion():
    t = _states(n=50)
    lat = t.copy()
    lat[1:10] = lat[0]  # the encoder maps ten distinct states to one latent
    num_pairs = 2000  # ≈ 2000·90/2450 ≈ 73 pairs expected among the collapsed ten
    assert evaluation.distortion(lat, t, num_pairs=num_pairs) == math.inf
    assert math.isfinite(evaluation.distortion(t, t, num_pairs=num_pairs))


def test_pairs_with_equal_inputs_are_skipped_not_infinite():
    """States a fraction of a pixel apart give one frame and so one latent: with `inputs`
    saying so, those pairs are skipped (as τ1 = τ2 is); a collapse of distinct inputs stays +∞."""
    t = _states(n=50)
    lat = t.copy()
    lat[1:10] = lat[0]
    same_frame = np.arange(50)[:, None]
    same_frame[1:10] = 0  # the ten states rendered one frame
    value = evaluation.distortion(lat, t, num_pairs=2000, inputs=same_frame)
    # By hand: ρ over the sampled pairs outside the ten, and between them and the rest.
    i, j = (np.asarray(x) for x in evaluation.sample_pairs(50, 2000, seed=0))
    keep = same_frame[i, 0] != same_frame[j, 0]
    rho = np.log(np.linalg.norm(lat[i] - lat[j], axis=-1)[keep]
                 / np.linalg.norm(t[i] - t[j], axis=-1)[keep])
    assert keep.sum() < 2000 and value == pytest.approx(np.var(rho), rel=1e-5)
    distinct = np.arange(50)[:, None]  # the same latents from ten distinct inputs: a collapse
    assert evaluation.distortion(lat, t, num_pairs=2000, inputs=distinct) == math.inf
    with pytest.raises(ValueError, match=r"inputs must be \[N, K\] with N = 50"):
        evaluation.distortion(lat, t, inputs=np.arange(49)[:, None])


def test_same_seed_same_result():
    t = _states()
    warped = np.tanh(2.0 * t)
    assert evaluation.distortion(warped, t, seed=3) == evaluation.distortion(warped, t, seed=3)
    assert evaluation.distortion(warped, t, seed=3) != evaluation.distortion(warped, t, seed=4)


def test_bad_inputs_raise():
    t = _states(n=20)
    cases = {
        "mismatched N": (t[:-1], t),
        "2-D": (t[:, 0], t),
        "floating-point dtype": (t.astype(np.int64), t),
        "NaN or inf": (np.where(t > 0.9, np.inf, t), t),
        "too few samples": (t[:1], t[:1]),
        "non-coincident pairs": (t, np.zeros_like(t)),
    }
    for expected, (lat, st) in cases.items():
        with pytest.raises(ValueError, match=expected):
            evaluation.distortion(lat, st)
    with pytest.raises(ValueError, match="num_pairs"):
        evaluation.distortion(t, t, num_pairs=1)


NAMES = ("texture_id", "object_id", "theta", "position", "velocity")


def test_irregularity_of_a_scaled_copy_is_zero_and_ignores_other_latent_columns():
    """A latent whose constrained entries are an exact scaled copy of τ's continuous entries
    stretches every pair alike: std of the log-ratios 0, whatever its other entries hold."""
    rng = np.random.default_rng(0)
    states = np.concatenate([rng.integers(0, 3, (60, 2)) / 6.0, rng.uniform(size=(60, 3))], 1)
    latents = np.concatenate([rng.normal(size=(60, 2)), 3.0 * states[:, 2:],
                              rng.normal(size=(60, 4))], 1)
    assert evaluation.irregularity(latents, states, NAMES) == pytest.approx(0.0, abs=1e-9)
    warped = latents.copy()
    warped[:, 3] = warped[:, 3] ** 3
    assert evaluation.irregularity(warped, states, NAMES) > 0.1


def test_irregularity_matches_a_hand_computation():
    """Four points, two objects: only the pairs (0, 1) and (2, 3) share their ids; the result
    is the (n − 1)-normalised std of their two log-ratios, ε = 1e-10 included."""
    states = np.array([[0, 0, 0.0, 0.0, 0.0], [0, 0, 0.0, 3.0, 4.0],
                       [0, 1 / 6, 0.0, 1.0, 0.0], [0, 1 / 6, 0.0, 1.0, 2.0]])
    latents = np.array([[9, 9, 0.0, 0.0, 0.0], [9, 9, 0.0, 1.0, 0.0],
                        [9, 9, 0.0, 0.0, 0.0], [9, 9, 0.0, 0.0, 4.0]])
    eps = 1e-10
    r1 = np.log((1.0 + eps) / (5.0 + eps))
    r2 = np.log((4.0 + eps) / (2.0 + eps))
    expected = np.std([r1, r2], ddof=1)
    assert evaluation.irregularity(latents, states, NAMES) == pytest.approx(expected, rel=1e-9)
    # Only the first num_points points count: with 3, one pair is left, and no std.
    assert np.isnan(evaluation.irregularity(latents, states, NAMES, num_points=3))
    with pytest.raises(ValueError, match="names"):
        evaluation.irregularity(latents, states, NAMES[:4])


def test_the_trimmed_distortion_leaves_out_the_collapsed_pairs_and_counts_them():
    """Points 0 and 1 share a latent but not a state: the exact figure is +inf, the trimmed one
    the variance of the other pairs' ρ computed by hand, and the count the collapsed pairs."""
    states = np.arange(12.0).reshape(6, 2) ** 1.5
    latents = np.concatenate([np.zeros((2, 3)), np.arange(12.0).reshape(4, 3) + 1])
    i, j = (np.asarray(x) for x in evaluation.sample_pairs(6, 50, seed=1))
    collapsed = (i < 2) & (j < 2)
    with np.errstate(divide="ignore"):  # log 0 at the collapsed pairs
        rho = (np.log(np.linalg.norm(latents[i] - latents[j], axis=1))
               - np.log(np.linalg.norm(states[i] - states[j], axis=1)))
    exact, trimmed, left_out = evaluation.distortion_trimmed(latents, states, 50, seed=1)
    assert collapsed.any() and exact == math.inf and left_out == int(collapsed.sum())
    assert trimmed == pytest.approx(np.var(rho[~collapsed]), rel=1e-6)
    # No collapsed pair: both figures are eq. 5's.
    spread = latents + np.arange(6)[:, None]
    exact, trimmed, left_out = evaluation.distortion_trimmed(spread, states, 50, seed=1)
    assert left_out == 0 and exact == trimmed == pytest.approx(
        evaluation.distortion(spread, states, 50, seed=1), rel=1e-12)
