"""Unsupervised learners on 64×64 frames (paper §2.1, §4): VAE, β-VAE, SVAE, PRED, DSA, SPAIR.

    from jaml import learners
    learner = learners.make("PRED", ld_dim=4)              # any of learners.ALL_LEARNERS
    opt = learners.default_optimizer(learner)
    state = learners.init_train_state(learner, opt, key, (frames, actions))
    step = jax.jit(learners.make_train_step(learner, opt, latent_penalty=None),
                   compiler_options=learners.compiler_options())  # on the CPU: Eigen convs
    state, metrics = step(state, (frames, actions), key)    # frames uint8 [B, T, 64, 64, 3]
    z = learner.encode(state.variables, frames, actions)    # [B, learner.latent_size]
"""

from __future__ import annotations

import typing

from jaml import _lazy
from jaml.learners.config import (
    ALL_LEARNERS,
    DSAConfig,
    LearnerConfig,
    PREDConfig,
    SPAIRConfig,
    SVAEConfig,
    VAEConfig,
    default_config,
)

if typing.TYPE_CHECKING:
    from jaml.learners.learner import Learner

# name → the module:function that builds it from its config (the configs and defaults:
# `jaml.learners.config.LEARNERS`).
_BUILDERS = {
    "VAE_v0": "vae:make_vae",
    "VAE_rpl": "vae:make_vae",
    "beta-VAE": "vae:make_vae",
    "SVAE": "svae:make_svae",
    "PRED": "pred:make_pred",
    "DSA": "dsa:make_dsa",
    "SPAIR": "spair:make_spair",
}


def make(name: str, config: LearnerConfig | None = None, **overrides) -> Learner:
    """The learner `name` built from `config`, or from its defaults updated with `overrides`."""
    import importlib

    from jaml.learners.config import LEARNERS

    if config is None:
        config = default_config(name, **overrides)
    elif name not in LEARNERS:
        raise ValueError(f"unknown learner {name!r}; valid names: {', '.join(ALL_LEARNERS)}")
    elif not isinstance(config, LEARNERS[name][0]):
        raise ValueError(f"{name} needs a {LEARNERS[name][0].__name__}, got "
                         f"{type(config).__name__}")
    elif overrides:
        config = config.replace(**overrides)
    if config.ld_dim is None:
        raise ValueError(f"{name}: ld_dim is None; give the true LD-state size (a stream run sets "
                         "its env's: `jaml.stream.resolve`)")
    module, function = _BUILDERS[name].split(":")
    return getattr(importlib.import_module(f"{__name__}.{module}"), function)(name, config)


# The rest, imported from their modules on first use (PEP 562): the configs above (and so
# `jaml suite --learner L --help`) stay free of JAX and Flax, which the models import.
_EXPORTS = {
    "LatentPenalty": "learner",
    "Learner": "learner",
    "Outputs": "learner",
    "CPU_COMPILER_OPTIONS": "train",
    "Batch": "train",
    "TrainState": "train",
    "compiler_options": "train",
    "default_optimizer": "train",
    "init_train_state": "train",
    "make_train_step": "train",
}


__getattr__, __dir__ = _lazy.exports(__name__, _EXPORTS)


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
    "SPAIRConfig",
    "SVAEConfig",
    "TrainState",
    "VAEConfig",
    "compiler_options",
    "default_config",
    "default_optimizer",
    "init_train_state",
    "make",
    "make_train_step",
]
