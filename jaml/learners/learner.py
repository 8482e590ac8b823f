"""The one interface every learner shares: config base, model outputs, `Learner` (init/loss/encode).

Shapes: B batch, T time (the learner's `seq_len`), H = W = 64, C = 3, A action, S latent steps,
P per-step latent passed to a penalty, Z flattened latent code.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from jaml.configs.learners import (  # noqa: F401  (the learners import them from here)
    COMPUTE_DTYPE_NAMES,
    LearnerConfig,
    RecurrentConfig,
    SingleFrameConfig,
)
from jaml.learners import elbo

FRAME_SHAPE = (64, 64, 3)

# latent_penalty(z [B, S, P], actions [B, S, A]) -> [B]   (paper eq. 4: Σ_k |g_k(τ̃, a)|)
LatentPenalty = Callable[[jax.Array, jax.Array], jax.Array]


@struct.dataclass
class PenaltyTerms:
    """What a latent penalty with a `terms(z, actions, key)` method adds to the loss.

    value: [B] the penalty per sequence. ok: [B] bool, rows that get `ok_weight` × their NLL
    once more, averaged over the ok rows (the reference's extra reconstruction term on rows
    whose latents satisfy every relation; none when no row is ok).
    """

    value: jax.Array
    ok: jax.Array
    ok_weight: float = struct.field(pytree_node=False, default=0.0)


@struct.dataclass
class Outputs:
    """What a learner's model returns for a batch in training mode.

    recon: [B, S, H, W, C] decoded means for the last S frames.
    kl: name → [B] KL terms (summed over latent dims and steps), before weighting.
    z: [B, S, P] the sampled latent τ̃ (pre-sigmoid) handed to a latent penalty.
    """

    recon: jax.Array
    kl: Mapping[str, jax.Array]
    z: jax.Array


@dataclasses.dataclass(frozen=True)
class Learner:
    """A learner: a Flax model with the reference's loss, behind pure functions of arrays.

    `variables` are Flax variables {"params", "batch_stats"} (the conv stacks use BatchNorm).
    """

    name: str
    config: LearnerConfig
    module: nn.Module
    kl_weights: Mapping[str, float]

    @property
    def seq_len(self) -> int:
        return self.config.seq_len

    @property
    def latent_size(self) -> int:
        return self.config.latent_size

    def check_batch(self, frames, actions) -> tuple[jax.Array, jax.Array]:
        """uint8 [B, T, 64, 64, 3] (or float in [0, 1]), [B, T, A] → float arrays; raise if bad."""
        frames, actions = jnp.asarray(frames), jnp.asarray(actions)
        if frames.ndim != 5 or tuple(frames.shape[2:]) != FRAME_SHAPE:
            raise ValueError(
                f"{self.name}: frames must be [B, T, 64, 64, 3], got {tuple(frames.shape)}"
            )
        if frames.shape[1] != self.seq_len:
            raise ValueError(
                f"{self.name}: sequence length must be T = {self.seq_len}, got "
                f"frames {tuple(frames.shape)}"
            )
        if actions.ndim != 3 or tuple(actions.shape[:2]) != tuple(frames.shape[:2]):
            raise ValueError(
                f"{self.name}: actions must be [B, T, A] = [{frames.shape[0]}, "
                f"{frames.shape[1]}, A] to match frames, got {tuple(actions.shape)}"
            )
        return elbo.frames_to_float(frames), actions.astype(jnp.float32)

    def check_recon(self, recon, batch: int) -> None:
        """Raise a one-line error unless `recon` is [B, S, 64, 64, 3] (S: latent_steps)."""
        expected = (batch, self.config.latent_steps, *FRAME_SHAPE)
        if tuple(jnp.shape(recon)) != expected:
            raise ValueError(
                f"{self.name}: Outputs.recon must be [B, S, 64, 64, 3] = {list(expected)} (the "
                f"last S = config.latent_steps frames decoded), got {list(jnp.shape(recon))}; "
                "make the module's __call__ return recon of that shape (docs/own_learner.md)")

    def module_init(self, key: jax.Array, x: jax.Array, a: jax.Array) -> dict[str, Any]:
        """Flax variables from checked float inputs (traceable; `init` jits it)."""
        params_key, sample_key = jax.random.split(key)
        return dict(self.module.init({"params": params_key}, x, a, sample_key, train=True))

    def init(self, key: jax.Array, frames, actions) -> dict[str, Any]:
        """Flax variables for batches shaped like (frames, actions)."""
        x, a = self.check_batch(frames, actions)
        # Jitted: op-by-op initialisation of the conv stacks is several times slower on CPU.
        return jax.jit(self.module_init)(key, x, a)

    def loss_and_stats(
        self, variables, key, frames, actions, latent_penalty: LatentPenalty | None = None
    ):
        """(loss, (metrics, new batch_stats)): `loss` plus the BatchNorm statistics it updated."""
        x, a = self.check_batch(frames, actions)
        out, updates = self.module.apply(variables, x, a, key, train=True, mutable=["batch_stats"])
        self.check_recon(out.recon, len(x))
        steps = out.recon.shape[1]
        # Unit-variance Gaussian log-likelihood of the decoded frames (docs/reference/suite.md §4),
        # summed over them as in the paper's ELBO, or averaged as in the reference code
        # (`frame_nll`).
        loglik = elbo.gaussian_loglik(x[:, x.shape[1] - steps :], out.recon)  # [B, S]
        nll = -(jnp.sum if self.config.frame_nll == "sum" else jnp.mean)(loglik, axis=1)
        kl = sum(self.kl_weights[k] * v for k, v in out.kl.items())
        ok_term, ok_fraction = jnp.zeros(()), None
        if latent_penalty is None:
            penalty = jnp.zeros_like(nll)
        elif hasattr(latent_penalty, "terms"):
            terms = latent_penalty.terms(out.z, a[:, a.shape[1] - steps :],
                                         jax.random.fold_in(key, 1))
            penalty = terms.value
            count = jnp.sum(terms.ok)
            ok_fraction = count / terms.ok.shape[0]
            ok_term = terms.ok_weight * jnp.where(
                count > 0, jnp.sum(jnp.where(terms.ok, nll, 0.0)) / jnp.maximum(count, 1), 0.0)
        else:
            penalty = latent_penalty(out.z, a[:, a.shape[1] - steps :])
        if jnp.shape(penalty) != nll.shape:
            raise ValueError(
                f"latent_penalty must return [B] = {nll.shape}, got {jnp.shape(penalty)}"
            )
        loss = jnp.mean(nll + kl + penalty) + ok_term
        metrics = {
            "loss": loss,
            "nll": jnp.mean(nll),
            "kl": jnp.mean(sum(out.kl.values())),
            "penalty": jnp.mean(penalty),
        }
        if ok_fraction is not None:
            metrics["ok_fraction"] = ok_fraction
        if len(out.kl) > 1:
            metrics.update({k: jnp.mean(v) for k, v in out.kl.items()})
        return loss, (metrics, updates["batch_stats"])

    def loss(
        self, variables, key, frames, actions, latent_penalty: LatentPenalty | None = None
    ) -> tuple[jax.Array, dict]:
        """(scalar loss, metrics): −ELBO (β-weighted KL) + mean latent penalty (paper eq. 4).

        frames uint8 [B, T, 64, 64, 3], actions [B, T, A]. `latent_penalty(z, a)` receives the
        sampled latent z [B, S, P] and the actions of those steps [B, S, A] and returns [B]; see
        docs/learners.md for S and P per learner. BatchNorm runs on batch statistics.
        """
        loss, (metrics, _) = self.loss_and_stats(variables, key, frames, actions, latent_penalty)
        return loss, metrics

    def encode(self, variables, frames, actions) -> jax.Array:
        """[B, Z]: the posterior mean (pre-sigmoid) flattened over steps; BatchNorm in eval mode."""
        x, a = self.check_batch(frames, actions)
        return self.module.apply(variables, x, a, method="encode")

    def reconstruct(self, variables, frames, actions) -> jax.Array:
        """[B, S, 64, 64, 3] in (0, 1): frames decoded from the posterior mean, eval mode."""
        x, a = self.check_batch(frames, actions)
        return self.module.apply(variables, x, a, method="reconstruct")
