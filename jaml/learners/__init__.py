"""Unsupervised learners on 64×64 frames (paper §2.1, §4): VAE, β-VAE, SVAE, PRED, DSA, SPAIR.

    from jaml import learners
    learner = learners.make("PRED", ld_dim=4)  # learners.ALL_LEARNERS, or "MODULE:FACTORY"
    opt = learners.default_optimizer(learner)
    state = learners.init_train_state(learner, opt, key, (frames, actions))
    step = jax.jit(learners.make_train_step(learner, opt, latent_penalty=None),
                   compiler_options=learners.compiler_options())  # on the CPU: Eigen convs
    state, metrics = step(state, (frames, actions), key)    # frames uint8 [B, T, 64, 64, 3]
    z = learner.encode(state.variables, frames, actions)    # [B, learner.latent_size]
"""

from __future__ import annotations

import pkgutil

from jaml.configs.learners import (
    ALL_LEARNERS,
    DSAConfig,
    LearnerConfig,
    PREDConfig,
    RecurrentConfig,
    SingleFrameConfig,
    SPAIRConfig,
    SVAEConfig,
    VAEConfig,
    configured,
    default_config,
    registered,
)
from jaml.learners.learner import LatentPenalty, Learner, Outputs
from jaml.learners.own import own_learner
from jaml.learners.train import (
    CPU_COMPILER_OPTIONS,
    Batch,
    TrainState,
    compiler_options,
    default_optimizer,
    init_train_state,
    make_train_step,
)


def make(name: str, config: LearnerConfig | None = None, **overrides) -> Learner:
    """The learner `name` built from `config`, or from its defaults updated with `overrides`
    (`jaml.configs.learners.configured`), by its registered builder (`LEARNERS`); a name
    "MODULE:FACTORY" is a learner of your own, `FACTORY(ld_dim=D)` (`jaml.learners.own`), whose
    config is its factory's."""
    if ":" in name:
        if config is not None or set(overrides) != {"ld_dim"}:
            raise ValueError(f"learner {name!r}: a learner of your own makes its own config "
                             "from ld_dim alone; give make(name, ld_dim=D)")
        return own_learner(name, overrides["ld_dim"])
    config = configured(name, config, **overrides)
    if config.ld_dim is None:
        raise ValueError(f"{name}: ld_dim is None; give the true LD-state size (a stream run sets "
                         "its env's: `jaml.stream.resolve`)")
    return pkgutil.resolve_name(registered(name)[2])(name, config)


__all__ = [
    "ALL_LEARNERS",
    "CPU_COMPILER_OPTIONS",
    "Batch",
    "DSAConfig",
    "LatentPenalty",
    "Learner",
    "LearnerConfig",
    "Outputs",
    "PREDConfig",
    "RecurrentConfig",
    "SPAIRConfig",
    "SVAEConfig",
    "SingleFrameConfig",
    "TrainState",
    "VAEConfig",
    "compiler_options",
    "default_config",
    "default_optimizer",
    "init_train_state",
    "make",
    "make_train_step",
]
