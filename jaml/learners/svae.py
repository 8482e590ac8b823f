"""SVAE (paper §2.1): per-frame conv features ⊕ actions → bi-LSTM → RNN → a latent per step.

Shapes: B batch, T time, Z per-step latent.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaml.configs.learners import SVAEConfig
from jaml.learners import elbo
from jaml.learners.learner import FRAME_SHAPE, Learner
from jaml.learners.networks import ConvDecoder, ConvEncoder, GaussianHead, RNNEncoder
from jaml.learners.vae import StepwiseGaussianVAE


class SequenceVAE(StepwiseGaussianVAE):
    """The reference's EncoderDynamicRNN with a per-step ConvDecoder."""

    config: SVAEConfig

    def setup(self):
        c = self.config
        self.conv = ConvEncoder(c.conv_filters, c.conv_features, c.conv_dtype,
                                activation_dtype=c.act_dtype)
        self.rnn = RNNEncoder(c.rnn_hidden)
        self.head = GaussianHead(c.z_step, "elu" if c.mu_nl else "none", c.logvar_limit)
        self.decoder = ConvDecoder(c.deconv_filters, compute_dtype=c.conv_dtype,
                                   activation_dtype=c.act_dtype,
                                   upsample_form=c.upsample_form)

    def posterior(self, x, a, train: bool):
        """x [B, T, H, W, C], a [B, T, A] → μ, logvar [B, T, Z]."""
        b, t = x.shape[:2]
        feats = self.conv(x.reshape(b * t, *FRAME_SHAPE), train).reshape(b, t, -1)
        a = elbo.encoder_actions(a, t, self.config.current_action)
        return self.head(self.rnn(jnp.concatenate([feats, a], axis=-1)))


def make_svae(name: str, config: SVAEConfig) -> Learner:
    return Learner(name, config, SequenceVAE(config), {"kl": config.beta})
