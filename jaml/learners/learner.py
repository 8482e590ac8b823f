"""The one interface every learner shares: config base, model outputs, `Learner` (init/loss/encode).

Shapes: B batch, T time (the learner's `seq_len`), H = W = 64, C = 3, A action, S latent steps,
P per-step latent passed to a penalty, Z flattened latent code.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Callable, Mapping
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

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


COMPUTE_DTYPES = {"float32": jnp.float32, "bfloat16": jnp.bfloat16}


@dataclasses.dataclass(frozen=True)
class LearnerConfig:
    """What every learner shares; defaults reproduce the reference (suite_reference.md §4).

    ld_dim: size D of the true low-dimensional state; the per-step latent defaults to 2·D.
    latent_dim: per-step latent size; None means 2·ld_dim (DSA: the dynamic part, None → D).
    beta: weight of the KL term (β-VAE; DSA weighs only the dynamic KL with it).
    mu_nl: the reference's `mu_nl=Sigmoid`: ELU on the posterior mean and a sigmoid on the
      sample before decoding.
    frame_nll: how the decoded frames' log-likelihoods combine: "sum" is the sequence ELBO of
      paper eq. 4 (log p(x_{1:S} | τ) = Σ_t log p(x_t | τ_t)), the reference's balance too (it
      averages likelihood and KL over the frames); "mean" averages the likelihood alone, which
      weighs the KL S times more per frame and collapsed the posteriors of PRED and SVAE
      (S = 24) in our runs (docs/learners.md). Same for S = 1.
    compute_dtype: "float32" (default) or "bfloat16": the dtype of the shared conv encoder's
      and decoder's convolutions (VAEs, PRED, SVAE, DSA; not SPAIR's): mixed precision, with
      parameters, batch norms, heads, the loss and the optimizer in float32. Not in the
      reference.
    current_action: "observed" (the reference code): the encoder sees the executed action of
      every input frame, the one into the first predicted frame included; "hidden": that last
      action is zeroed (`elbo.encoder_actions`).
    kl_form: "standard" KL to N(0, I), or the reference code's form (`elbo.kl_to_standard_normal`;
      learners with a standard-normal prior: VAEs, PRED, SVAE).
    """

    ld_dim: int
    latent_dim: int | None = None
    beta: float = 1.0
    learning_rate: float = 1e-4
    logvar_limit: float = 6.0
    mu_nl: bool = True
    conv_filters: tuple[int, ...] = (64, 128, 128, 256)
    conv_features: int = 128
    deconv_filters: tuple[int, ...] = (256, 128, 128, 64)
    frame_nll: str = "sum"
    compute_dtype: str = "float32"
    current_action: str = "observed"
    kl_form: str = "standard"

    def __post_init__(self):
        if self.current_action not in elbo.CURRENT_ACTIONS:
            raise ValueError(f"current_action must be one of {list(elbo.CURRENT_ACTIONS)}, got "
                             f"{self.current_action!r}")
        if self.kl_form not in elbo.KL_FORMS:
            raise ValueError(f"kl_form must be one of {list(elbo.KL_FORMS)}, got "
                             f"{self.kl_form!r}")
        if self.compute_dtype not in COMPUTE_DTYPES:
            raise ValueError(f"compute_dtype must be one of {list(COMPUTE_DTYPES)}, got "
                             f"{self.compute_dtype!r}")
        if self.frame_nll not in ("sum", "mean"):
            raise ValueError(f"frame_nll must be 'sum' or 'mean', got "
                             f"{self.frame_nll!r}")
        if int(self.ld_dim) < 1:
            raise ValueError(f"ld_dim must be ≥ 1, got {self.ld_dim}")
        if self.latent_dim is not None and int(self.latent_dim) < 1:
            raise ValueError(f"latent_dim must be ≥ 1 or None, got {self.latent_dim}")
        if not self.beta >= 0 or not self.learning_rate > 0 or not self.logvar_limit > 0:
            raise ValueError(f"beta must be ≥ 0, learning_rate and logvar_limit > 0; got beta "
                             f"{self.beta}, learning_rate {self.learning_rate}, logvar_limit "
                             f"{self.logvar_limit}")

    def replace(self, **changes) -> LearnerConfig:
        return dataclasses.replace(self, **changes)

    @property
    def conv_dtype(self):
        """compute_dtype as a JAX dtype, for the conv encoder and decoder."""
        return COMPUTE_DTYPES[self.compute_dtype]

    @property
    def actions_seen(self) -> int:
        """How many of a sequence's first actions the encoder reads (`current_action`)."""
        hist = self.hist
        return hist if self.current_action == "observed" else hist - 1

    @property
    def z_step(self) -> int:
        """Per-step latent size."""
        return self.latent_dim or 2 * self.ld_dim

    # Overridden per family.
    @property
    def seq_len(self) -> int:
        """T: frames per batch sequence."""
        raise NotImplementedError

    @property
    def latent_steps(self) -> int:
        """S: latent steps, one decoded frame each (the last S frames of the sequence)."""
        raise NotImplementedError

    @property
    def static_size(self) -> int:
        """F: latent entries shared by all steps (PRED's static part; 0 for most learners)."""
        return 0

    @property
    def penalty_dim(self) -> int:
        """P: per-step size of the sampled latent handed to a latent penalty."""
        return self.static_size + self.z_step

    @property
    def latent_size(self) -> int:
        """Z: size of `encode`'s flattened posterior mean."""
        return self.static_size + self.latent_steps * self.z_step

    @property
    def penalty_slots(self) -> dict[str, tuple[int, ...]]:
        """Which entries of the per-step penalty latent (P) are static (one value per
        sequence) and which dynamic (one per step): what `relations.LatentLayout.place` puts a
        relation set's coordinates on."""
        return {"static": tuple(range(self.static_size)),
                "dynamic": tuple(range(self.static_size, self.penalty_dim))}


@dataclasses.dataclass(frozen=True)
class SingleFrameConfig(LearnerConfig):
    """Learners that see one frame and decode it (VAE, SPAIR): hist = T = S = 1."""

    @property
    def hist(self) -> int:
        return 1

    @property
    def seq_len(self) -> int:
        return 1

    @property
    def latent_steps(self) -> int:
        return 1


@dataclasses.dataclass(frozen=True)
class RecurrentConfig(LearnerConfig):
    """Learners that encode all `hist` frames with an RNN and keep one latent per frame.

    min_hist: the fewest frames the model can work with (a class constant, not a field).
    """

    hist: int = 24
    rnn_hidden: int = 512
    min_hist: typing.ClassVar[int] = 1

    def __post_init__(self):
        super().__post_init__()
        if self.hist < self.min_hist:
            raise ValueError(f"{type(self).__name__} needs hist ≥ {self.min_hist}, got {self.hist}")

    @property
    def seq_len(self) -> int:
        return self.hist

    @property
    def latent_steps(self) -> int:
        return self.hist


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
        steps = out.recon.shape[1]
        # Unit-variance Gaussian log-likelihood of the decoded frames (reference §4), summed over
        # them as in the paper's ELBO, or averaged as in the reference code (`frame_nll`).
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
