"""VAE_v0, VAE_rpl and β-VAE (paper §2.1): one frame → conv → MLP → Gaussian latent → deconv.

The feed-forward model here is the reference's EncoderDynamic + ConvDecoder, which PRED reuses
with several input frames and several decoded steps (pred.py). Shapes: B batch, T time, S
decoded steps, Z per-step latent.
"""

from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaml.configs.learners import VAEConfig
from jaml.learners import elbo
from jaml.learners.learner import FRAME_SHAPE, Learner, Outputs
from jaml.learners.networks import MLP, ConvDecoder, ConvEncoder, GaussianHead


class StepwiseGaussianVAE(nn.Module):
    """A Gaussian posterior per decoded step (`posterior`, defined by subclasses), sampled with
    the reparameterisation trick and decoded frame by frame; shared by the VAE, PRED and SVAE.

    The first F = `config.static_size` entries of every step's latent are a static part (PRED's
    layout for the incline, reference PARAMS_PRED_BLK_SM). Shared (default): `posterior` repeats
    them over steps, one sample (step 0's) is drawn and repeated, and their KL counts once.
    Per step (`static_per_step`, the reference code): every step has its own F entries, sampled
    and KL-weighted like the dynamic ones. The decoder sees [f ⊕ z_t] per step. F = 0 for the
    other learners.
    """

    config: Any

    def posterior(self, x, a, train: bool):
        """x [B, T, H, W, C], a [B, T, A] → μ, logvar [B, S, F + Z]."""
        raise NotImplementedError

    def decode(self, z, train: bool):
        """z [B, S, F + Z] → [B, S, H, W, C]; each step decoded on its own."""
        b, s = z.shape[:2]
        if self.config.mu_nl:
            z = nn.sigmoid(z)
        return self.decoder(z.reshape(b * s, -1), train).reshape(b, s, *FRAME_SHAPE)

    def __call__(self, x, a, key, train: bool = True) -> Outputs:
        c = self.config
        f = 0 if _static_per_step(c) else c.static_size
        mu, logvar = self.posterior(x, a, train)
        z = elbo.reparameterize(key, mu, logvar)
        z = z.at[:, :, :f].set(jnp.broadcast_to(z[:, :1, :f], z[:, :, :f].shape))
        kl = elbo.kl_to_standard_normal(mu[..., f:], logvar[..., f:], c.kl_form).sum(axis=-1)
        if f:
            kl = kl + elbo.kl_to_standard_normal(mu[:, 0, :f], logvar[:, 0, :f], c.kl_form)
        return Outputs(recon=self.decode(z, train), kl={"kl": kl}, z=z)

    def encode(self, x, a) -> jax.Array:
        """[B, Z]: the static posterior mean once, then every step's dynamic mean; with a
        per-step static part, every step's whole mean (the reference's latent code)."""
        f = 0 if _static_per_step(self.config) else self.config.static_size
        mu, _ = self.posterior(x, a, False)
        return jnp.concatenate([mu[:, 0, :f], mu[..., f:].reshape(mu.shape[0], -1)], axis=-1)

    def reconstruct(self, x, a) -> jax.Array:
        mu, _ = self.posterior(x, a, False)
        return self.decode(mu, False)


def _static_per_step(config) -> bool:
    return bool(getattr(config, "static_per_step", False))


class FeedForwardVAE(StepwiseGaussianVAE):
    """Conv features ⊕ actions of the first `hist` frames → MLP → posterior over S steps → decode.

    The encoder sees each input frame's action as `config.current_action` says
    (`elbo.encoder_actions`). With a per-step static part the MLP's output is S blocks of
    [f_t ⊕ z_t]; shared, one f then S blocks of z_t. config needs hist, latent_steps, z_step,
    static_size, mlp_widths and the LearnerConfig fields.
    """

    config: Any

    def setup(self):
        c = self.config
        self.conv = ConvEncoder(c.conv_filters, c.conv_features, c.conv_dtype,
                                activation_dtype=c.act_dtype)
        self.trunk = MLP(c.mlp_widths)
        self.head = GaussianHead(
            c.latent_steps * (c.static_size + c.z_step) if _static_per_step(c)
            else c.static_size + c.latent_steps * c.z_step,
            "elu" if c.mu_nl else "none",
            c.logvar_limit,
        )
        self.decoder = ConvDecoder(c.deconv_filters, compute_dtype=c.conv_dtype,
                                   activation_dtype=c.act_dtype,
                                   upsample_form=c.upsample_form)

    def posterior(self, x, a, train: bool):
        """x [B, T, H, W, C], a [B, T, A] → μ, logvar [B, S, F + Z] from the first `hist`
        frames and the actions between them."""
        c = self.config
        b, h, f = x.shape[0], c.hist, c.static_size
        feats = self.conv(x[:, :h].reshape(b * h, *FRAME_SHAPE), train).reshape(b, h, -1)
        seen = elbo.encoder_actions(a[:, :h], h, c.current_action)
        mu, logvar = self.head(self.trunk(jnp.concatenate([feats, seen], -1).reshape(b, -1)))
        if _static_per_step(c):
            return (mu.reshape(b, c.latent_steps, f + c.z_step),
                    logvar.reshape(b, c.latent_steps, f + c.z_step))

        def per_step(v):  # [B, F + S·Z] → [B, S, F + Z], the static part repeated
            static = jnp.broadcast_to(v[:, None, :f], (b, c.latent_steps, f))
            return jnp.concatenate([static, v[:, f:].reshape(b, c.latent_steps, c.z_step)], -1)

        return per_step(mu), per_step(logvar)


def make_vae(name: str, config: VAEConfig) -> Learner:
    return Learner(name, config, FeedForwardVAE(config), {"kl": config.beta})
