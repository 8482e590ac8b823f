"""Off-manifold samplers (paper §3.1): uniform points in a box around the data, or thickening.

Random points of a box almost never satisfy equations of motion, so they serve as negatives for
the stopping rule; thickening (jittering on-manifold rows by a fraction of the box) gives points
near the manifold, which restricted syzygies are trained on.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def bounding_box(rows: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Per-column (min, max) of rows [N, D]."""
    return jnp.min(rows, axis=0), jnp.max(rows, axis=0)


def uniform_in_box(key: jax.Array, low: jax.Array, high: jax.Array, n: int) -> jax.Array:
    """[n, D] independent uniform draws in the box [low, high]."""
    return jax.random.uniform(key, (n, low.shape[-1]), minval=low, maxval=high)


def thicken(key: jax.Array, rows: jax.Array, low, high, sigma) -> jax.Array:
    """rows + (U[0,1) − ½)·(high − low)·σ: on-manifold rows jittered by a fraction σ of the box."""
    jitter = jax.random.uniform(key, rows.shape) - 0.5
    return rows + jitter * (high - low) * sigma
