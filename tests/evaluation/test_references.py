"""The reference latents against closed forms: PCA's subspace is the SVD's, the projection a
fixed linear map, the true state the target padded with zero columns."""

import jax
import numpy as np
import pytest

from jaml.evaluation import references


def _low_rank_pixels(seed=0, n=300, p=192, rank=3):
    """uint8 [n, p] rows: a mean plus `rank` strong directions plus small noise, so the top
    components are well separated from the rest."""
    rng = np.random.default_rng(seed)
    basis = np.linalg.qr(rng.normal(size=(p, rank)))[0]
    scores = rng.normal(size=(n, rank)) * np.array([40.0, 25.0, 15.0])
    x = 128 + scores @ basis.T * 3 + rng.normal(size=(n, p))
    return np.clip(np.round(x), 0, 255).astype(np.uint8)


def test_pca_basis_spans_the_svds_leading_subspace():
    pixels = _low_rank_pixels()
    mean, comps = references.pca_basis(pixels, jax.random.key(0), width=3)
    x = pixels / 255.0
    np.testing.assert_allclose(mean, x.mean(axis=0), atol=1e-6)
    vt = np.linalg.svd(x - x.mean(axis=0), full_matrices=False)[2][:3]
    # Principal angles between the two 3-d subspaces: all cosines 1.
    cosines = np.linalg.svd(vt @ np.asarray(comps, np.float64), compute_uv=False)
    np.testing.assert_allclose(cosines, 1.0, atol=1e-4)
    latents = references.pca_latents(pixels, mean, comps)
    np.testing.assert_allclose(latents, (x - x.mean(axis=0)) @ np.asarray(comps), atol=1e-4)


def test_random_projection_is_one_fixed_linear_map_of_the_pixels():
    pixels = _low_rank_pixels(n=20)
    key = jax.random.key(3)
    z = np.asarray(references.random_projection(pixels, key))
    assert z.shape == (20, references.WIDTH)
    matrix = np.asarray(references.random_projection(np.eye(192) * 255, key))  # its columns
    np.testing.assert_allclose(z, pixels / 255.0 @ matrix, rtol=1e-4, atol=1e-5)
    np.testing.assert_array_equal(z, references.random_projection(pixels, key))


@pytest.mark.parametrize("width", [4, 11])
def test_reference_latents_pad_every_row_to_one_width(width):
    rng = np.random.default_rng(1)
    pixels = _low_rank_pixels(n=40)
    states = rng.normal(size=(40, width)).astype(np.float32)
    out = references.reference_latents(pixels[:30], states[:30],
                                       {"t": (pixels[30:], states[30:])}, jax.random.key(0))
    assert list(out) == list(references.NAMES)
    wide = max(width, references.WIDTH)
    train, tests = out["true_state"]
    np.testing.assert_array_equal(train[:, :width], states[:30])
    np.testing.assert_array_equal(tests["t"][:, width:], 0.0)
    for name in references.NAMES:
        assert out[name][0].shape == (30, wide) and out[name][1]["t"].shape == (10, wide)
