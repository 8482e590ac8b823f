"""The on-manifold data contract: a `Source` draws rows τ ∈ R^D on the manifold to learn."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import jax


@runtime_checkable
class Source(Protocol):
    """A sampler of on-manifold rows.

    `sample(key, n)` must be a pure, jittable function of the key (n static) returning a float
    array [n, D] whose columns are named by `dim_names`.

    Optional attribute `pool_size: int | None`: when set, `relations.fit` (through
    `jaml.relations.data.prepare`) calls `sample(key, pool_size)` once, before training, and
    trains on those rows as if the user had passed them, instead of calling `sample` inside its
    jitted loop for every batch. Sources whose draws are expensive (MJX rollouts) set it.
    """

    name: str

    @property
    def dim_names(self) -> tuple[str, ...]: ...

    def sample(self, key: jax.Array, n: int) -> jax.Array: ...
