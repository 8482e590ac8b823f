"""Rotation-block error (docs/reference/suite.md §5) against hand-computed rotations, the
Rearrange block layout, the reference's regressor loss, and a regressor fitted with rotation
blocks."""

import math

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaml import evaluation
from jaml.evaluation import rotation

# Regressor fits: compiled at XLA's full level (28 s → 16 s for this module).
pytestmark = pytest.mark.xla_optimized


def rx(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], np.float32)


def rz(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], np.float32)


Q = Rotation.from_euler("xyz", [0.3, -1.1, 2.0]).as_matrix().astype(np.float32)


def err(r_true, r_pred):
    return float(rotation.principal_axis_error(jnp.asarray(r_true), jnp.asarray(r_pred)))


def test_identical_and_axis_flipped_rotations_score_zero():
    assert err(Q, Q) < 1e-6
    # R̂ = R·Rx(π): M[:, 2] = −e_z, the same axis with the other sign.
    assert err(Q, Q @ rx(math.pi)) < 1e-6


def test_spin_about_the_principal_axis_is_ignored():
    """M = Rz(θ): the z axes agree, so the principal-axis error is 0 while the angle is θ."""
    for t in (0.4, 1.3, 2.9):
        assert err(Q, Q @ rz(t)) < 1e-6
        np.testing.assert_allclose(rotation.rotation_angle(Q, Q @ rz(t)), t, atol=1e-3)
        np.testing.assert_allclose(rotation.principal_axis_angle(Q, Q @ rz(t)), 0.0, atol=1e-3)


@pytest.mark.parametrize("t", [math.pi / 2, math.pi / 3, 2 * math.pi / 3, 0.1])
def test_tilt_about_x_by_hand(t):
    """M = Rx(θ): M[:, 2] = (0, −sin θ, cos θ) → error (|sin θ| + min(|cos θ − 1|, |cos θ + 1|))/3
    (π/2: 2/3; π/3: (0.866 + 0.5)/3); the axes are min(θ, π − θ) apart."""
    expected = (abs(math.sin(t)) + min(abs(math.cos(t) - 1), abs(math.cos(t) + 1))) / 3
    np.testing.assert_allclose(err(Q, Q @ rx(t)), expected, atol=1e-5)
    np.testing.assert_allclose(err(np.eye(3), rx(t)), expected, atol=1e-5)
    np.testing.assert_allclose(rotation.principal_axis_angle(Q, Q @ rx(t)), min(t, math.pi - t),
                               atol=1e-3)
    np.testing.assert_allclose(rotation.rotation_angle(Q, Q @ rx(t)), t, atol=1e-3)
    if t == math.pi / 2:
        np.testing.assert_allclose(err(np.eye(3), rx(t)), 2 / 3, atol=1e-6)


def test_a_non_orthonormal_prediction_is_scored_as_is():
    # R̂ = 0 (a regressor that predicts nothing): M[:, 2] = 0 → (0 + 0 + 1)/3.
    np.testing.assert_allclose(err(Q, np.zeros((3, 3), np.float32)), 1 / 3, atol=1e-6)


def test_rearrange_block_layout():
    # Reacher: version/10, sin/cos of two joints (5), then per object 3 position + 9 rotation.
    assert rotation.rearrange_rotation_starts() == (8, 20, 32, 44)
    assert rotation.rearrange_rotation_starts(prefix=15) == (18, 30, 42, 54)  # Franka, 63 dims
    mask = rotation.euclidean_mask(53, rotation.rearrange_rotation_starts())
    assert mask.sum() == 53 - 36 and list(np.nonzero(mask)[0][:8]) == [0, 1, 2, 3, 4, 5, 6, 7]
    assert not mask[8:17].any() and mask[17:20].all()
    with pytest.raises(ValueError, match="does not fit"):
        rotation.check_starts((50,), 53)
    with pytest.raises(ValueError, match="overlap"):
        rotation.check_starts((8, 12), 53)


def _ld(rotations, rng):
    """[N, 53]: random Euclidean entries and the given per-object rotations [N, 4, 3, 3]."""
    n = rotations.shape[0]
    ld = rng.uniform(-1, 1, size=(n, 53)).astype(np.float32)
    for j, s in enumerate(rotation.rearrange_rotation_starts()):
        ld[:, s:s + 9] = rotations[:, j].reshape(n, 9)
    return ld


def test_block_errors_and_the_reference_loss_by_hand():
    rng = np.random.default_rng(0)
    true_r = np.broadcast_to(Q, (2, 4, 3, 3)).copy()
    pred_r = true_r.copy()
    tilts = [0.0, math.pi / 2, math.pi / 3, math.pi]  # per object
    for j, t in enumerate(tilts):
        pred_r[:, j] = Q @ rx(t)
    true, pred = _ld(true_r, rng), _ld(pred_r, rng)
    starts = rotation.rearrange_rotation_starts()
    mask = rotation.euclidean_mask(53, starts)
    pred[:, mask] = true[:, mask] + 0.25  # every Euclidean entry off by 0.25
    expected = [(abs(math.sin(t)) + min(abs(math.cos(t) - 1), abs(math.cos(t) + 1))) / 3
                for t in tilts]  # 0, 2/3, 0.455, 0
    errs = np.asarray(rotation.block_errors(jnp.asarray(pred), jnp.asarray(true), starts))
    np.testing.assert_allclose(errs, np.broadcast_to(expected, (2, 4)), atol=1e-5)
    loss = float(rotation.alignment_loss(jnp.asarray(pred), jnp.asarray(true), starts))
    np.testing.assert_allclose(loss, 0.25 + sum(expected), atol=1e-5)


def test_regressor_with_rotation_blocks():
    """Latents that carry the state fit the blocks closely; pure-noise latents cannot."""
    rng = np.random.default_rng(1)
    n = 3000
    rots = Rotation.random(n, random_state=2).as_matrix().astype(np.float32)  # [N, 3, 3]
    states = np.concatenate([rng.uniform(-1, 1, size=(n, 3)), rots.reshape(n, 9)],
                            axis=1).astype(np.float32)
    latents = np.tanh(states @ rng.normal(size=(12, 16)).astype(np.float32) / 2)
    noise = rng.normal(size=(n, 16)).astype(np.float32)
    fast = {"num_iterations": 1500, "batch_size": 128, "normalize": False,
            "rotation_starts": (3,), "learning_rate": 1e-3}
    tr, te = slice(0, 2000), slice(2000, n)
    good = evaluation.fit_regressor(latents[tr], states[tr], **fast)
    bad = evaluation.fit_regressor(noise[tr], states[tr], **fast)
    e_good = float(evaluation.rotation_errors(good, latents[te], states[te], (3,))[0])
    e_bad = float(evaluation.rotation_errors(bad, noise[te], states[te], (3,))[0])
    assert e_good < 0.5 * e_bad, (e_good, e_bad)
    # The per-dimension errors keep their [D] shape.
    assert evaluation.regressor_error(good, latents[te], states[te]).shape == (12,)
    with pytest.raises(ValueError, match="normalize=False"):
        evaluation.fit_regressor(latents[tr], states[tr], **{**fast, "normalize": True})
    with pytest.raises(ValueError, match="does not fit"):
        evaluation.fit_regressor(latents[tr], states[tr], **{**fast, "rotation_starts": (5,)})


def test_rotation_blocks_come_from_the_metadata():
    names = ["version", "a_x", *(f"a_r{i}{j}" for i in range(3) for j in range(3))]
    groups = ["other", "position", *["orientation"] * 9]
    assert rotation.ld_blocks(names, groups) == ((2,), ("a_rotation",))
    assert rotation.ld_blocks(["x", "v"], ["position", "velocity"]) == ((), ())
    with pytest.raises(ValueError, match="not a 9-entry rotation block"):
        rotation.ld_blocks(names[:-1], groups[:-1])  # a block cut short
    swapped = [*names[:2], names[3], names[2], *names[4:]]
    with pytest.raises(ValueError, match="not a 9-entry rotation block"):
        rotation.ld_blocks(swapped, groups)  # not row-major
