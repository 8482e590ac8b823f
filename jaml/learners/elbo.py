"""ELBO pieces (paper §4 eq. 4, docs/reference/suite.md §4): Gaussian KLs, reparameterised
samples, likelihood.

Shapes: B batch, T time, H, W, C image, Z latent. Every function maps over leading axes.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaml.configs.learners import CURRENT_ACTIONS, KL_FORMS


def frames_to_float(frames: jax.Array) -> jax.Array:
    """uint8 [..., H, W, C] in 0..255 → float32 in [0, 1]; floating frames pass as float32."""
    if frames.dtype == jnp.uint8:
        return frames.astype(jnp.float32) / 255.0
    if not jnp.issubdtype(frames.dtype, jnp.floating):
        raise TypeError(f"frames must be uint8 or floating, got dtype {frames.dtype}")
    return frames.astype(jnp.float32)




def encoder_actions(a: jax.Array, hist: int, current_action: str = "observed") -> jax.Array:
    """[B, T, A]: the actions an encoder sees with its first `hist` frames.

    a_t is executed after frame t. "observed" (the reference code) passes every input frame's
    executed action, a_{hist−1} (the move into the first predicted frame) included. "hidden"
    zeroes a_t for t ≥ hist − 1: under a trained policy that action is a function of the state
    the frame shows and carries it into the latent past the pixels (a choice for scoring on
    π_curr; the reference uses the dummy 0 only where PPO reads latents).
    """
    if current_action not in CURRENT_ACTIONS:
        raise ValueError(f"current_action must be one of {CURRENT_ACTIONS}, got "
                         f"{current_action!r}")
    if current_action == "observed":
        return a
    keep = jnp.arange(a.shape[1]) < hist - 1
    return jnp.where(keep[None, :, None], a, 0.0)


def reparameterize(key: jax.Array, mu: jax.Array, logvar: jax.Array) -> jax.Array:
    """[..., Z]: z = μ + ε·exp(½ logvar), ε ~ N(0, I); logvar is log σ²."""
    return mu + jax.random.normal(key, mu.shape, mu.dtype) * jnp.exp(0.5 * logvar)




def kl_to_standard_normal(mu: jax.Array, logvar: jax.Array, form: str = "standard") -> jax.Array:
    """[...]: the KL term of μ, logvar [..., Z] against N(0, I), summed over Z.

    "standard": KL(N(μ, diag σ²) ‖ N(0, I)) = ½ Σ_Z (σ² + μ² − 1 − log σ²), logvar = log σ².
    "reference": the reference code's ½ Σ_Z (e^{2 logvar} + μ² − 1 − 2 logvar), which reads
    logvar as log σ here while its sampler uses σ = e^{logvar/2} (utils/prob.py): the same
    minimum at logvar = 0, twice the pull on the log-variance, e^{2 logvar} above it.
    """
    if form == "standard":
        return 0.5 * jnp.sum(jnp.exp(logvar) + jnp.square(mu) - 1.0 - logvar, axis=-1)
    if form == "reference":
        return 0.5 * jnp.sum(jnp.exp(2.0 * logvar) + jnp.square(mu) - 1.0 - 2.0 * logvar,
                             axis=-1)
    raise ValueError(f"kl form must be one of {KL_FORMS}, got {form!r}")


def gaussian_kl(mu_q, logvar_q, mu_p, logvar_p) -> jax.Array:
    """[...]: KL(N(μ_q, σ_q²) ‖ N(μ_p, σ_p²)) summed over the last axis Z of [..., Z] inputs.

    ½ Σ_Z (logvar_p − logvar_q + (σ_q² + (μ_q − μ_p)²) / σ_p² − 1); used for DSA's learned priors.
    """
    ratio = (jnp.exp(logvar_q) + jnp.square(mu_q - mu_p)) * jnp.exp(-logvar_p)
    return 0.5 * jnp.sum(logvar_p - logvar_q + ratio - 1.0, axis=-1)


def gaussian_loglik(x: jax.Array, x_hat: jax.Array) -> jax.Array:
    """[...]: log p(x | x̂) = −½ Σ_{H,W,C} (x − x̂)² for x, x̂ [..., H, W, C]
    (docs/reference/suite.md §4).

    A unit-variance Gaussian without its constant −½ HWC log 2π, which carries no gradient.
    """
    return -0.5 * jnp.sum(jnp.square(x - x_hat), axis=(-3, -2, -1))
