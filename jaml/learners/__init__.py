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

import dataclasses

from jaml.learners.dsa import DSAConfig, make_dsa
from jaml.learners.learner import LatentPenalty, Learner, LearnerConfig, Outputs
from jaml.learners.pred import PREDConfig, make_pred
from jaml.learners.spair import SPAIRConfig, make_spair
from jaml.learners.svae import SVAEConfig, make_svae
from jaml.learners.train import (
    CPU_COMPILER_OPTIONS,
    Batch,
    TrainState,
    compiler_options,
    default_optimizer,
    init_train_state,
    make_train_step,
)
from jaml.learners.vae import VAEConfig, make_vae

# name → (config class, defaults that differ from the class's, builder)
_REGISTRY = {
    # VAE_rpl differs from VAE_v0 only in the stream's replay (`StreamConfig.keep_fraction`).
    "VAE_v0": (VAEConfig, {}, make_vae),
    "VAE_rpl": (VAEConfig, {}, make_vae),
    "beta-VAE": (VAEConfig, {"beta": 5.0}, make_vae),
    "SVAE": (SVAEConfig, {}, make_svae),
    "PRED": (PREDConfig, {}, make_pred),
    "DSA": (DSAConfig, {}, make_dsa),
    # 4×4 grid by default; make("SPAIR", ld_dim=D, grid_size=6) for the paper's 6×6 variant.
    "SPAIR": (SPAIRConfig, {}, make_spair),
}
ALL_LEARNERS = tuple(_REGISTRY)


def default_config(name: str, **overrides) -> LearnerConfig:
    """The named learner's config: reference defaults, then `overrides` (ld_dim is required)."""
    if name not in _REGISTRY:
        raise ValueError(f"unknown learner {name!r}; valid names: {', '.join(ALL_LEARNERS)}")
    cls, defaults, _ = _REGISTRY[name]
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise ValueError(f"{name}: unknown config fields {unknown}; valid: {sorted(fields)}")
    if "ld_dim" not in overrides:
        raise ValueError(f"{name}: ld_dim (the true LD-state size) is required")
    return cls(**{**defaults, **overrides})


def make(name: str, config: LearnerConfig | None = None, **overrides) -> Learner:
    """The learner `name` built from `config`, or from its defaults updated with `overrides`."""
    if config is None:
        config = default_config(name, **overrides)
    elif name not in _REGISTRY:
        raise ValueError(f"unknown learner {name!r}; valid names: {', '.join(ALL_LEARNERS)}")
    elif not isinstance(config, _REGISTRY[name][0]):
        raise ValueError(f"{name} needs a {_REGISTRY[name][0].__name__}, got "
                         f"{type(config).__name__}")
    elif overrides:
        config = config.replace(**overrides)
    return _REGISTRY[name][2](name, config)


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
