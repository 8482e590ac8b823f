"""The pure training step shared by all learners: (state, batch, key) → (state, metrics)."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import optax
from flax import struct

from jaml.learners.learner import LatentPenalty, Learner


class Batch(NamedTuple):
    """frames uint8 [B, T, 64, 64, 3]; actions float [B, T, A]."""

    frames: jax.Array
    actions: jax.Array


@struct.dataclass
class TrainState:
    """step: scalar int; params / batch_stats: the Flax collections; opt_state: the optimizer's."""

    step: jax.Array
    params: Any
    batch_stats: Any
    opt_state: Any

    @property
    def variables(self) -> dict[str, Any]:
        """What `Learner.encode` / `loss` / `reconstruct` take."""
        return {"params": self.params, "batch_stats": self.batch_stats}


def default_optimizer(learner: Learner) -> optax.GradientTransformation:
    """Adam at the config's learning rate (reference: 1e-4, no gradient clipping)."""
    return optax.adam(learner.config.learning_rate)


def init_train_state(learner: Learner, optimizer: optax.GradientTransformation, key: jax.Array,
                     batch) -> TrainState:
    """A fresh TrainState for batches shaped like `batch` (frames, actions)."""
    frames, actions = learner.check_batch(*batch)

    # One jitted program: op-by-op initialisation dispatches (and compiles) per parameter shape.
    @jax.jit
    def init(key, frames, actions):
        variables = learner.module_init(key, frames, actions)
        params = variables["params"]
        return TrainState(step=jax.numpy.zeros((), jax.numpy.int32), params=params,
                          batch_stats=variables.get("batch_stats", {}),
                          opt_state=optimizer.init(params))

    return init(key, frames, actions)


# XLA options for programs that train the learners on the CPU (`compiler_options`). jaxlib
# 0.10's CPU backend hands dots, reductions and convolutions to YNNPACK, where the conv stacks'
# convolutions run slower than on XLA's Eigen path; the list is that default less
# LIBRARY_FUSION_TYPE_INDIVIDUAL_CONVOLUTION (docs/notes/learners.md, Measurements).
CPU_COMPILER_OPTIONS = {
    "xla_cpu_experimental_ynn_fusion_type":
        "LIBRARY_FUSION_TYPE_INDIVIDUAL_DOT,LIBRARY_FUSION_TYPE_REDUCE",
}


def compiler_options() -> dict[str, str] | None:
    """`jax.jit(..., compiler_options=...)` for a train step on the default backend:
    `CPU_COMPILER_OPTIONS` on the CPU, None (XLA's defaults) elsewhere. Per program, not a
    process-wide XLA flag."""
    return dict(CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else None


def make_train_step(learner: Learner, optimizer: optax.GradientTransformation,
                    latent_penalty: LatentPenalty | None = None):
    """A pure, jittable `(state, batch, key) -> (state, metrics)`: one optimizer step on `loss`.

    latent_penalty(z [B, S, P], actions [B, S, A]) -> [B] is added to the loss (paper eq. 4);
    it is closed over, so relation parameters it captures are compile-time constants.
    """

    def step(state: TrainState, batch, key: jax.Array):
        frames, actions = batch

        def loss_fn(params):
            variables = {"params": params, "batch_stats": state.batch_stats}
            return learner.loss_and_stats(variables, key, frames, actions, latent_penalty)

        (_, (metrics, batch_stats)), grads = jax.value_and_grad(loss_fn, has_aux=True)(
            state.params)
        updates, opt_state = optimizer.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        new_state = TrainState(step=state.step + 1, params=params, batch_stats=batch_stats,
                               opt_state=opt_state)
        return new_state, {**metrics, "grad_norm": optax.tree.norm(grads)}

    return step
