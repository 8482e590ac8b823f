"""The analytic domain of the paper's Fig. 5: a hyperboloid cut by a plane.

The curve {x² + y² − 2z² − 1 = 0} ∩ {y − 2z − 1 = 0} is the ellipse
τ(t) = (√2 cos t, 2 sin t − 1, sin t − 1), t ∈ [0, 2π): two independent relations cut a
1-D manifold out of R³, so AML with transversality should find exactly two.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp


@dataclasses.dataclass(frozen=True)
class HyperboloidPlaneCurve:
    """Points on the ellipse where the hyperboloid meets the plane.

    Attributes:
      arc_fraction: fraction of the full ellipse the parameter t covers (1 = the whole curve).
    """

    arc_fraction: float = 1.0
    name: str = "ellipse"

    def __post_init__(self):
        if not 0.0 < self.arc_fraction <= 1.0:
            raise ValueError(f"arc_fraction must lie in (0, 1], got {self.arc_fraction}")

    @property
    def dim_names(self) -> tuple[str, ...]:
        return ("x", "y", "z")

    def sample(self, key: jax.Array, n: int) -> jax.Array:
        t = jax.random.uniform(key, (n,), maxval=2.0 * jnp.pi * self.arc_fraction)
        s = jnp.sin(t)
        return jnp.stack([jnp.sqrt(2.0) * jnp.cos(t), 2.0 * s - 1.0, s - 1.0], axis=-1)

    @staticmethod
    def residuals(tau: jax.Array) -> jax.Array:
        """[..., 2]: (hyperboloid x² + y² − 2z² − 1, plane y − 2z − 1) at τ [..., 3]."""
        x, y, z = tau[..., 0], tau[..., 1], tau[..., 2]
        return jnp.stack([x**2 + y**2 - 2.0 * z**2 - 1.0, y - 2.0 * z - 1.0], axis=-1)


@dataclasses.dataclass(frozen=True)
class Circle:
    """Points on the unit circle in R²: a 1-D manifold one relation cuts alone (codimension 1),
    the smallest case of a zero set that must not have parts away from the data."""

    name: str = "circle"

    @property
    def dim_names(self) -> tuple[str, ...]:
        return ("x", "y")

    def sample(self, key: jax.Array, n: int) -> jax.Array:
        t = jax.random.uniform(key, (n,), maxval=2.0 * jnp.pi)
        return jnp.stack([jnp.cos(t), jnp.sin(t)], axis=-1)

    @staticmethod
    def residuals(tau: jax.Array) -> jax.Array:
        """[..., 1]: x² + y² − 1 at τ [..., 2]."""
        return (tau[..., 0] ** 2 + tau[..., 1] ** 2 - 1.0)[..., None]
