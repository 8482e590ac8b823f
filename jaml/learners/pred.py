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
    """

    hist: int = 8
    pred: int = 16
    mlp_widths: tuple[int, ...] = (1024, 512)

    def __post_init__(self):
        super().__post_init__()
        if self.hist < 1 or self.pred < 0:
            raise ValueError(f"PRED needs hist ≥ 1 and pred ≥ 0, got {self.hist}, {self.pred}")

    @property
    def seq_len(self) -> int:
        return self.hist + self.pred

    @property
    def latent_steps(self) -> int:
        return self.hist + self.pred


def make_pred(name: str, config: PREDConfig) -> Learner:
    # The same EncoderDynamic + ConvDecoder as the VAE: the MLP sees T frames and its latent is
    # chunked into T + L per-step parts, each decoded by the shared deconv stack.
    return Learner(name, config, FeedForwardVAE(config), {"kl": config.beta})
