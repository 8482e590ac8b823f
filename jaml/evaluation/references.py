"""Reference latents for an alignment report: what the same regressor scores on the same rows
given latents that are not the encoder's, so an encoder's error is read as a place between them.

- "true_state": the target itself as the latent (the floor: what the regressor reaches, its
  fit and its extrapolation from the training rows to a test set's included);
- "pca": the leading `WIDTH` principal components of the last input frame's pixels, fit on the
  training rows' frames (what a linear map of raw pixels keeps);
- "random_projection": the last input frame's pixels through a fixed Gaussian matrix;
- the constant predictor (the ceiling: no information) is `alignment.constant_errors`.

Shapes: N rows, P = 64·64·3 pixels, D LD-state width, K = WIDTH.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

WIDTH = 8  # components of the pixel references, a learner's latent width's order
NAMES = ("true_state", "pca", "random_projection")
_OVERSAMPLE, _POWER_ITERATIONS = 8, 4  # randomized PCA (Halko, Martinsson & Tropp 2011)


@functools.partial(jax.jit, static_argnames="width")
def pca_basis(pixels: jax.Array, key: jax.Array, width: int = WIDTH):
    """(mean [P], components [P, K]) of pixels [N, P] (uint8 or float, read as /255): the top
    `width` right singular vectors of the centred rows, by a randomized range finder with power
    iterations, so that it costs O(N·P·K) rather than an SVD of N × P."""
    x = pixels.astype(jnp.float32) / 255.0
    mean = x.mean(axis=0)
    x = x - mean
    omega = jax.random.normal(key, (x.shape[1], width + _OVERSAMPLE), jnp.float32)
    q = jnp.linalg.qr(x @ omega)[0]
    for _ in range(_POWER_ITERATIONS):
        q = jnp.linalg.qr(x @ jnp.linalg.qr(x.T @ q)[0])[0]
    _, _, vt = jnp.linalg.svd(q.T @ x, full_matrices=False)
    return mean, vt[:width].T


@jax.jit
def pca_latents(pixels: jax.Array, mean: jax.Array, components: jax.Array) -> jax.Array:
    """[N, K]: pixels [N, P] (read as /255) on a `pca_basis`."""
    return (pixels.astype(jnp.float32) / 255.0 - mean) @ components


@functools.partial(jax.jit, static_argnames="width")
def random_projection(pixels: jax.Array, key: jax.Array, width: int = WIDTH) -> jax.Array:
    """[N, K]: pixels [N, P] (read as /255) times a Gaussian matrix drawn from `key`, scaled by
    1/√P so the latents are of order one."""
    p = pixels.shape[1]
    matrix = jax.random.normal(key, (p, width), jnp.float32) / jnp.sqrt(p)
    return (pixels.astype(jnp.float32) / 255.0) @ matrix


def reference_latents(train_pixels, train_states, tests: dict, key: jax.Array
                      ) -> dict[str, tuple]:
    """{reference: (train latents [N, K'], {test set: latents [Nt, K']})} for NAMES, from the
    training rows' pixels [N, P] and states [N, D] and each test set's (pixels, states); all
    widths padded with zero columns to K' = max(D, WIDTH), so one vmapped fit takes the three
    (a zero input column leaves an MLP's function unchanged)."""
    k_pca, k_proj = jax.random.split(key)
    mean, components = pca_basis(jnp.asarray(train_pixels), k_pca)
    width = max(np.shape(train_states)[1], WIDTH)

    def pad(x):
        x = np.asarray(x, np.float32)
        return np.pad(x, ((0, 0), (0, width - x.shape[1])))

    def of(name, pixels, states):
        if name == "true_state":
            return pad(states)
        if name == "pca":
            return pad(pca_latents(jnp.asarray(pixels), mean, components))
        return pad(random_projection(jnp.asarray(pixels), k_proj))

    return {name: (of(name, train_pixels, train_states),
                   {k: of(name, px, st) for k, (px, st) in tests.items()}) for name in NAMES}
