"""PRED (paper §4): T frames in → a latent chunked into T+L parts → T+L frames decoded.

Shapes: B batch, T input frames (`hist`), L predicted frames (`pred`), Z per-step latent.
"""

from __future__ import annotations

from jaml.configs.learners import PREDConfig
from jaml.learners.learner import Learner
from jaml.learners.vae import FeedForwardVAE


def make_pred(name: str, config: PREDConfig) -> Learner:
    # The same EncoderDynamic + ConvDecoder as the VAE: the MLP sees T frames and its latent is
    # chunked into T + L per-step parts, each decoded by the shared deconv stack.
    return Learner(name, config, FeedForwardVAE(config), {"kl": config.beta})
