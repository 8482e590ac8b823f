"""Brax 0.14's trainers on JAX 0.10: `jax.device_put_replicated`, removed from JAX, restored.

`brax.training.agents.{ppo,sac}.train` call `jax.device_put_replicated(state, devices)` once to
copy their training state to every local device for `jax.pmap`; JAX 0.10 raises
AttributeError ("deprecated; use jax.device_put"). `install()` (run by `envs_mjx.base`, which
every env imports) adds the function JAX's migration guide gives as the drop-in, only where JAX
lacks one: nothing else in JAX changes, and a JAX that still has it keeps its own.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P


def device_put_replicated(x, devices):
    """Each leaf stacked len(devices) times along a new leading axis, one copy per device."""
    devices = list(devices)
    sharding = NamedSharding(Mesh(np.asarray(devices), ("replicas",)), P("replicas"))
    return jax.tree.map(
        lambda a: jax.device_put(jnp.broadcast_to(a, (len(devices), *jnp.shape(a))), sharding),
        x)


def install() -> bool:
    """Adds `jax.device_put_replicated` where JAX has none; returns whether it did."""
    try:
        jax.device_put_replicated  # noqa: B018
        return False
    except AttributeError:
        jax.device_put_replicated = device_put_replicated
        return True
