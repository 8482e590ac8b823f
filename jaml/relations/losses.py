"""The losses of Algorithm 1 as pure math on arrays (paper eq. 1–3, App. B.3.1).

Shapes: B rows, D data dimensions, J earlier relations. Input gradients are per-row gradients of
g with respect to τ (`input_gradients`); the reference code used the gradient of the batch *mean*
(1/B of it), so its hinge constants are in those units: the "reference" terms below take the
true gradient and the batch size and apply the 1/B factor themselves.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

EPS = 1e-15


def input_gradients(g: Callable[[jax.Array], jax.Array], tau: jax.Array):
    """(g(τ) [B], ∇_τ g(τ) [B, D]) for a row-wise g: rows τ [B, D] → [B].

    One `jax.grad` of Σ_i g(τ_i): rows are independent, so ∂Σ/∂τ_i = ∇g(τ_i). A single reverse
    pass over the batch is cheaper than `vmap` of per-row gradients.
    """

    def total(t):
        y = g(t)
        return jnp.sum(y), y

    (_, y), v = jax.value_and_grad(total, has_aux=True)(tau)
    return y, v


def _norm(v):
    return jnp.sqrt(jnp.sum(v**2, axis=-1))


# --- the paper's objective (eq. 1, 2, 3) ---------------------------------------------------


def distance(y: jax.Array, v: jax.Array) -> jax.Array:
    """d_g = |g| / ‖∇g‖ [B]: distance to where g's linearisation vanishes (eq. 1)."""
    return jnp.abs(y) / jnp.maximum(_norm(v), EPS)


def log_gradient_norm(v: jax.Array, cap: float | None = None) -> jax.Array:
    """−log ‖∇g‖ [B]: keeps g away from the trivial relation g ≡ 0 (eq. 1); with a `cap`,
    −log min(‖∇g‖, cap): no push to steepen g past it."""
    norm = jnp.maximum(_norm(v), EPS)
    return -jnp.log(norm if cap is None else jnp.minimum(norm, cap))


def sin_squared(u: jax.Array, v: jax.Array) -> jax.Array:
    """sin² of the angle between rows of u [..., D] and v [..., D], floored at 1e-15 → [...]."""
    cos = jnp.sum(u * v, axis=-1) / jnp.maximum(_norm(u) * _norm(v), EPS)
    return jnp.maximum(1.0 - cos**2, EPS)


def log_sin_product(earlier: jax.Array, v: jax.Array) -> jax.Array:
    """−log Π_j sin²θ(∇g_j, ∇g_k) [B] (eq. 2). earlier [J, B, D], v [B, D]."""
    return -jnp.sum(jnp.log(sin_squared(earlier, v[None])), axis=0)


def clip_to(term: jax.Array, first: jax.Array, factor: float = 2.0) -> jax.Array:
    """Scale a scalar loss term down to at most `factor` × |first| (App. B.3.1).

    The paper clips "the loss from other components if it is more than twice the magnitude of
    the 1st term", so on-manifold vanishing always dominates. Scaling (rather than a hard
    clamp) keeps the term's gradient direction; the bound itself carries no gradient.
    """
    limit = factor * jax.lax.stop_gradient(jnp.abs(first))
    size = jax.lax.stop_gradient(jnp.abs(term))
    return term * jnp.minimum(1.0, limit / jnp.maximum(size, EPS))


# --- the reference implementation's objective ------------------------------------------------

REF_GRAD_FLOOR = 1e-4  # in units of ∇g / B
REF_ON_FLOOR = 0.05


def reference_gradient_term(v: jax.Array, batch_size: int) -> jax.Array:
    """1 − 100·min(‖∇g‖/B, 1e-4) [B]: the reference's linear hinge in place of −log‖∇g‖."""
    return 1.0 - 100.0 * jnp.minimum(_norm(v) / batch_size, REF_GRAD_FLOOR)


def reference_distance_term(y: jax.Array, v: jax.Array, batch_size: int) -> jax.Array:
    """max(0.05, 1e-3·|g|/‖∇g/B‖) [B]: the reference's hinged d_g (≈ 1.024 d_g at B = 1024)."""
    scaled = jnp.maximum(_norm(v) / batch_size, EPS)
    return jnp.maximum(REF_ON_FLOOR, 1e-3 * jnp.abs(y) / scaled)


def reference_transversality(earlier: jax.Array, v: jax.Array) -> jax.Array:
    """1 − Π_j |sin θ(∇g_j, ∇g_k)| [B]: the reference's product of |sin| (not sin²)."""
    return 1.0 - jnp.prod(jnp.sqrt(sin_squared(earlier, v[None])), axis=0)


# --- shared pieces ---------------------------------------------------------------------------


def mean_angle(earlier: jax.Array, v: jax.Array) -> jax.Array:
    """Mean over j and rows of arccos|cos θ(∇g_j, ∇g_k)| ∈ [0, π/2]. earlier [J, B, D]."""
    return jnp.mean(jnp.arcsin(jnp.sqrt(jnp.clip(sin_squared(earlier, v[None]), 0.0, 1.0))))


def syzygy_residual(coefficients: jax.Array, earlier: jax.Array, y: jax.Array) -> jax.Array:
    """Σ_j f_j(τ) g_j(τ) − g_k(τ) [B]: a restricted syzygy's value (Def. 3.1, f_k = −1).

    coefficients [B, J], earlier = g_1..g_{k−1} values [B, J], y = g_k values [B].
    """
    return jnp.sum(coefficients * earlier, axis=-1) - y


def separated(on_abs: jax.Array, off_abs: jax.Array, ratio: float, top_fraction: float):
    """App. B.3.1 stopping rule: mean off-manifold |g| > ratio × on-manifold statistic.

    The on-manifold statistic is the mean of the largest ⌊top_fraction·B⌋ values of |g| (the
    reference used the top 20%, stricter than a mean; all rows when B ≤ 10 or fraction 1).
    """
    return ratio * top_mean(on_abs, top_fraction) < jnp.mean(off_abs)


def top_mean(values: jax.Array, top_fraction: float) -> jax.Array:
    """Mean of the largest ⌊top_fraction·B⌋ of values [B] (all of them when B ≤ 10)."""
    count = values.shape[0]
    top = int(top_fraction * count) if count > 10 else count
    return jnp.mean(jax.lax.top_k(values, max(top, 1))[0])


def mined_hinge(y_abs: jax.Array, level: jax.Array) -> jax.Array:
    """max(0, log level − log |g|) [B]: |g| pushed above `level` on mined rows (jaml's own term).

    Mined rows lie on the earlier relations' zero set away from the data; a relation that
    vanishes there leaves that spurious part in the intersection. In log units the term is
    blind to g's scale, and it stops acting once |g| clears the level; a floor of 1 % of the
    level inside the logarithm keeps its gradient bounded where g is still zero.
    """
    floor = 0.01 * level + EPS  # bounds the gradient where g is still zero
    return jnp.maximum(0.0, jnp.log(level + EPS) - jnp.log(y_abs + floor))
