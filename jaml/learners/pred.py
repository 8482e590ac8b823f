"""PRED (paper §4): T frames in → a latent chunked into T+L parts → T+L frames decoded.

Shapes: B batch, T input frames (`hist`), L predicted frames (`pred`), Z per-step latent.
"""

from __future__ import annotations

import dataclasses

from jaml.learners.learner import Learner, LearnerConfig
from jaml.learners.vae import FeedForwardVAE


@dataclasses.dataclass(frozen=True)
class PREDConfig(LearnerConfig):
    """PRED_SEQ24 by default: hist T = 8 frames in, pred L = 16 more out (window 24).

    The other reference presets (hist, pred): SEQ16 (4, 12), SEQ8 (2, 6), PARAMS_PRED (8, 24),
    SEQ2 (1, 1). Batches carry the whole window, T + L frames and actions; the learner sees the
    first T and decodes all T + L.

    static_dim: F latent entries shared by all T + L steps, decoded with each step's dynamic
    part as [f ⊕ z_t] (the reference's PARAMS_PRED_BLK_SM for the incline: F = 3, Z = 2); the
    per-step latent a penalty sees is then [f ⊕ z_t], and `encode` gives [f, z_1, …, z_{T+L}].
    static_per_step: the reference code's form of that layout: every step has its own F static
    entries (sampled, KL-weighted and decoded per step; nothing ties them), and `encode` gives
    [f_1 ⊕ z_1, …, f_{T+L} ⊕ z_{T+L}]. A penalty reads step t's own [f_t ⊕ z_t].
    """

    hist: int = 8
    pred: int = 16
    mlp_widths: tuple[int, ...] = (1024, 512)
    static_dim: int = 0
    static_per_step: bool = False

    def __post_init__(self):
        super().__post_init__()
        if self.hist < 1 or self.pred < 0:
            raise ValueError(f"PRED needs hist ≥ 1 and pred ≥ 0, got {self.hist}, {self.pred}")
        if self.static_dim < 0:
            raise ValueError(f"PRED needs static_dim ≥ 0, got {self.static_dim}")

    @property
    def static_size(self) -> int:
        return self.static_dim

    @property
    def seq_len(self) -> int:
        return self.hist + self.pred

    @property
    def latent_steps(self) -> int:
        return self.hist + self.pred

    @property
    def latent_size(self) -> int:
        if self.static_per_step:
            return self.latent_steps * (self.static_dim + self.z_step)
        return super().latent_size


def make_pred(name: str, config: PREDConfig) -> Learner:
    # The same EncoderDynamic + ConvDecoder as the VAE: the MLP sees T frames and its latent is
    # chunked into T + L per-step parts, each decoded by the shared deconv stack.
    return Learner(name, config, FeedForwardVAE(config), {"kl": config.beta})
