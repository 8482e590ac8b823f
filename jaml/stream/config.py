"""`StreamConfig`: one learning-loop run (env, learner, policy, replay, schedule, evaluation).

Defaults follow the reference suite (suite_reference.md §3, §5) where they are not sizes; the
sizes of the paper (5000 replay columns, 10 000-row regressor sets, 100 000 epochs) are fields,
and `for_env` fills the per-domain ones from the domain family's `DomainDefaults` (rollout
length, learner steps per epoch, PPO network, sequence-learner window).
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any

from envs_mjx import config as envs_config
from jaml.learners import config as learners_config

POLICIES = ("ppo", "random")
# The reference's replay size in columns (suite_reference.md §3).
REFERENCE_REPLAY_COLUMNS = 5000
# The share of replay slots kept from the initial policy, by learner (reference §3): the paper's
# replay keeps half for every learner but VAE_v0, whose only difference from VAE_rpl it is.
REPLAY_KEEP_FRACTION = {"VAE_v0": 0.0}
DEFAULT_REPLAY_KEEP_FRACTION = 0.5
# The key of a run record's learner and env configs (`StreamConfig.record`).
RESOLVED = "resolved"


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters; defaults are the reference's pendulum settings.

    hidden: widths of the policy's and the value function's MLP hidden layers.
    learning_rate: Adam step size at the start of the run.
    lr_decay: decay the step size linearly to 0 over the run's epochs (one PPO update each).
    discounting: the discount γ.
    gae_lambda: GAE's λ; 1 (the reference) gives discounted returns bootstrapped from the value
      at the rollout's end.
    clipping_epsilon: PPO's ratio clip.
    vf_coefficient: weight of the value loss.
    entropy_cost: weight of the entropy bonus.
    max_grad_norm: global gradient-norm clip.
    num_updates: passes over each rollout.
    num_minibatches: minibatches per pass, each of whole env trajectories (must divide
      num_envs).
    normalize_observations: running mean/std normalisation of the LD-state observations.
    normalize_advantage: standardise advantages per minibatch.
    reward_scaling: multiplies rewards inside the loss.
    """

    hidden: tuple[int, ...] = (64, 64)
    learning_rate: float = 1e-4
    lr_decay: bool = True
    discounting: float = 0.99
    gae_lambda: float = 1.0
    clipping_epsilon: float = 0.2
    vf_coefficient: float = 0.5
    entropy_cost: float = 0.01
    max_grad_norm: float = 0.5
    num_updates: int = 3
    num_minibatches: int = 8
    normalize_observations: bool = True
    normalize_advantage: bool = True
    reward_scaling: float = 1.0

    def __post_init__(self):
        problems = []
        if not self.hidden or any(h < 1 for h in self.hidden):
            problems.append(f"ppo hidden must be positive widths, got {self.hidden}")
        if self.learning_rate <= 0:
            problems.append(f"ppo learning_rate must be > 0, got {self.learning_rate}")
        if not 0 < self.discounting <= 1 or not 0 <= self.gae_lambda <= 1:
            problems.append("ppo discounting must be in (0, 1] and gae_lambda in [0, 1]")
        if self.num_updates < 1 or self.num_minibatches < 1:
            problems.append("ppo num_updates and num_minibatches must be ≥ 1")
        if problems:
            raise ValueError("; ".join(problems))


@dataclasses.dataclass(frozen=True)
class StreamConfig:
    """A learning-loop run.

    env / learner: registry names (`envs_mjx.ALL_ENVS`, `jaml.learners.ALL_LEARNERS`).
    policy: "ppo" (PPO on the true LD state) or "random" (uniform actions).
    seed: PRNG seed of the run (envs, policy, learner, replay sampling, test sets).
    num_envs: envs stepped in parallel; each epoch adds one replay column per env.
    rollout_len: steps per env per epoch (a column holds rollout_len + 1 frames).
    replay_slots: replay columns, a multiple of num_envs; None (default): the reference's 5000
      rounded down to a multiple of num_envs (4992 at 64 envs), see `replay_columns`.
    replay_keep_fraction: share of slots kept from the start; None (default): the learner's
      (`REPLAY_KEEP_FRACTION`: VAE_v0 0, others 0.5), see `keep_fraction`.
    learner_steps: learner gradient steps per epoch once the replay is full.
    frames_per_batch: frames per learner step; the batch has frames_per_batch // L sequences.
    epochs: total epochs of the run.
    eval_every: epochs between alignment analyses and checkpoints (the first analysis runs when
      the replay is full and the learner starts).
    eval_train: sequences in the regressor's training set, sampled from the replay.
    eval_rand: sequences in the π_rand test set (random policy, the same set at every analysis).
    eval_curr: sequences in the π_curr test set (current policy; PPO runs only).
    eval_transient: steps after reset before the test sequences are cut (reference 120).
    regressor_iterations: alignment regressor steps (reference 10 000).
    regressor_normalize: z-score the regressor's targets (errors in training-std units, the
      benchmark envs); False for the domains whose LD state is already in a fixed range
      (Incline, Rearrange, reference §5), errors then in those units. Rearrange needs False:
      its rotation blocks are fit and scored by the principal-axis error of R_trueᵀR̂.
    distortion_dims: LD-state names whose values are τ^true in the distortion ρ (paper eq. 5;
      the incline's dynamic state, position and velocity); empty means all of them.
    ppo: PPO's hyper-parameters (`for_env` sets the network and passes per domain).
    learner_overrides: learner config fields (e.g. beta, hist); `learner_config` applies them.
    env_overrides: env config fields (e.g. multicolor); `env_config` applies them.
    """

    env: str = "CartPole"
    learner: str = "VAE_rpl"
    policy: str = "ppo"
    seed: int = 0
    num_envs: int = 64
    rollout_len: int = 32
    replay_slots: int | None = None
    replay_keep_fraction: float | None = None
    learner_steps: int = 10
    frames_per_batch: int = 1024
    epochs: int = 1000
    eval_every: int = 100
    eval_train: int = 10_000
    eval_rand: int = 10_048
    eval_curr: int = 2_500
    eval_transient: int = 120
    regressor_iterations: int = 10_000
    regressor_normalize: bool = True
    distortion_dims: tuple[str, ...] = ()
    ppo: PPOConfig = dataclasses.field(default_factory=PPOConfig)
    learner_overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    env_overrides: dict[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        problems = []
        if self.policy not in POLICIES:
            problems.append(f"policy must be one of {POLICIES}, got {self.policy!r}")
        for name in ("num_envs", "rollout_len", "learner_steps",
                     "frames_per_batch", "epochs", "eval_every", "eval_train", "eval_rand",
                     "regressor_iterations"):
            if getattr(self, name) < 1:
                problems.append(f"{name} must be ≥ 1, got {getattr(self, name)}")
        if self.replay_slots is not None and self.replay_slots < 1:
            problems.append(f"replay_slots must be ≥ 1 or None, got {self.replay_slots}")
        if self.eval_curr < 0 or self.eval_transient < 0:
            problems.append("eval_curr and eval_transient must be ≥ 0")
        if self.num_envs >= 1 and self.replay_slots and self.replay_slots % self.num_envs:
            problems.append(
                f"replay_slots ({self.replay_slots}) must be a multiple of num_envs "
                f"({self.num_envs}): each epoch adds num_envs columns"
            )
        if self.replay_keep_fraction is not None and not 0 <= self.replay_keep_fraction < 1:
            problems.append(f"replay_keep_fraction must be in [0, 1), got "
                            f"{self.replay_keep_fraction}")
        if self.policy == "ppo" and self.num_envs % self.ppo.num_minibatches:
            problems.append(f"num_envs ({self.num_envs}) must split into ppo.num_minibatches "
                            f"({self.ppo.num_minibatches})")
        if problems:
            raise ValueError("; ".join(problems))

    def replace(self, **changes) -> StreamConfig:
        return dataclasses.replace(self, **changes)

    @property
    def replay_columns(self) -> int:
        """The replay's column count: replay_slots, or the reference's 5000 rounded down to a
        multiple of num_envs (each epoch adds one column per env)."""
        if self.replay_slots is not None:
            return self.replay_slots
        return max(1, REFERENCE_REPLAY_COLUMNS // self.num_envs) * self.num_envs

    @property
    def keep_fraction(self) -> float:
        """The replay's kept share: replay_keep_fraction, or the learner's default."""
        if self.replay_keep_fraction is not None:
            return self.replay_keep_fraction
        return REPLAY_KEEP_FRACTION.get(self.learner, DEFAULT_REPLAY_KEEP_FRACTION)

    @property
    def fill_epochs(self) -> int:
        """Epochs until the replay is full and the learner starts (reference §3)."""
        return self.replay_columns // self.num_envs

    def resolved(self) -> StreamConfig:
        """This config with the defaults that depend on other fields filled in (the replay's
        columns and kept share): what a run records, so its config.json reads without rules."""
        return self.replace(replay_slots=self.replay_columns,
                            replay_keep_fraction=self.keep_fraction)

    def learner_config(self, ld_dim: int) -> learners_config.LearnerConfig:
        """The learner's config: its defaults, then `learner_overrides` (a registry learner;
        `ld_dim` is the env's LD-state size, which the stream reads from the env)."""
        return learners_config.default_config(self.learner, ld_dim=ld_dim,
                                              **self.learner_overrides)

    def env_config(self) -> envs_config.EnvConfig:
        """The env's config: its defaults, then `env_overrides`."""
        return envs_config.configured(self.env, **self.env_overrides)

    def with_configs(self, learner: learners_config.LearnerConfig | None = None,
                     env: envs_config.EnvConfig | None = None) -> StreamConfig:
        """This config with the options typed learner and env configs hold (the command line's
        --learner-config.* / --env-config.*): their fields that differ from the defaults, and
        those this config's overrides name, become learner_overrides / env_overrides (the
        learner's ld_dim is the env's, not an option). None leaves that part's overrides."""
        changes = {}
        if learner is not None:
            default = learners_config.default_config(self.learner, ld_dim=learner.ld_dim)
            changes["learner_overrides"] = changed_fields(
                learner, default, keep=self.learner_overrides, skip=("ld_dim",))
        if env is not None:
            changes["env_overrides"] = changed_fields(
                env, envs_config.default_config(self.env), keep=self.env_overrides)
        return self.replace(**changes)

    def record(self, learner=None, env=None) -> dict[str, Any]:
        """A run's config.json: the resolved config's fields and, under "resolved", the configs
        of the learner and the env the run built (`learner`, `env`: dataclasses; what is not
        one, say your own learner's config, is left out), whole."""
        parts = {name: json.loads(json.dumps(dataclasses.asdict(c)))
                 for name, c in (("learner", learner), ("env", env))
                 if dataclasses.is_dataclass(c) and not isinstance(c, type)}
        return self.resolved().to_dict() | ({RESOLVED: parts} if parts else {})

    def program_key(self) -> str:
        """The resolved config without its seed, as canonical JSON: what the compiled loop
        depends on (the seed only picks the run's keys)."""
        return json.dumps(self.resolved().replace(seed=0).to_dict(), sort_keys=True)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        return json.loads(json.dumps(d))  # tuples → lists: what a JSON round trip gives

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StreamConfig:
        """The config a `to_dict` or `record` (a run's config.json, resolved or as older runs
        wrote it) describes."""
        d = dict(d)
        d.pop(RESOLVED, None)
        ppo = d.pop("ppo", {})
        ppo = PPOConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in ppo.items()})
        if "distortion_dims" in d:
            d["distortion_dims"] = tuple(d["distortion_dims"])
        return cls(ppo=ppo, **d)


def changed_fields(config, default, *, keep=(), skip=()) -> dict[str, Any]:
    """What turns the dataclass `default` into `config`: the fields that differ, and those named
    in `keep`, less those in `skip` (the inverse of `dataclasses.replace`)."""
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)
            if f.name not in skip and (f.name in keep or getattr(config, f.name)
                                       != getattr(default, f.name))}


def recorded_env_options(record: dict[str, Any]) -> dict[str, Any]:
    """The env config fields a run's config.json gives: its resolved env config (the fields the
    env's config still has), or an older record's env_overrides."""
    resolved = record.get(RESOLVED, {}).get("env")
    if resolved is None:
        return dict(record.get("env_overrides", {}))
    valid = {f.name for f in dataclasses.fields(envs_config.default_config(record["env"]))}
    return {k: v for k, v in resolved.items() if k in valid}


@dataclasses.dataclass(frozen=True)
class DomainDefaults:
    """One domain family's settings: StreamConfig fields (the rest keep StreamConfig's
    defaults), and by learner name the learner config fields it sets (`learners`)."""

    rollout_len: int
    learner_steps: int
    ppo: PPOConfig = PPOConfig()
    regressor_normalize: bool = True
    distortion_dims: tuple[str, ...] = ()
    learners: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)

    def stream_fields(self) -> dict[str, Any]:
        """The StreamConfig fields this family sets."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name != "learners"}


# The reference's small-block presets' numerics (PARAMS_PRED_BLK_SM, PARAMS_VAE_BLK_SM): no
# output sigmoid, log-variances clipped at ±20.
_SMALL_BLOCK = {"mu_nl": False, "logvar_limit": 20.0}
_LOCOMOTION = DomainDefaults(
    rollout_len=64, learner_steps=50,
    ppo=PPOConfig(hidden=(256, 256), num_updates=50, num_minibatches=4),
    learners={"PRED": {"hist": 4, "pred": 12}, "SVAE": {"hist": 16}, "DSA": {"hist": 16}})
# family (`envs_mjx.config.FAMILIES`, each domain's `EnvConfig.family`) → its settings.
DOMAINS: dict[str, DomainDefaults] = {
    # Rollout 32, 10 learner steps per epoch, PPO MLP 64 with 3 × 8 minibatches, sequence
    # learners on 24-frame windows (the learners' defaults).
    "pendulum": DomainDefaults(rollout_len=32, learner_steps=10),
    # Rollout 64, 50 learner steps, PPO MLP 256 with 50 passes × 4 minibatches, 16-frame
    # windows (SEQ16: PRED 4 in, 12 predicted).
    "locomotion": _LOCOMOTION,
    # Rollout 10 (the reference forces it), SVAE/DSA 8-frame windows, and the small-block
    # presets: PRED sees 1 frame and predicts 1 with a static part of 3 and 2 dynamic entries
    # per step, the VAEs a 5-entry latent; alignment in the LD state's own units and the
    # distortion on position and velocity.
    "incline": DomainDefaults(
        rollout_len=10, learner_steps=10,
        ppo=PPOConfig(hidden=(256, 256), num_updates=10, num_minibatches=4),
        regressor_normalize=False, distortion_dims=("position", "velocity"),
        learners={
            "PRED": {"hist": 1, "pred": 1, "static_dim": 3, "latent_dim": 2, **_SMALL_BLOCK},
            "VAE_v0": {"latent_dim": 5, **_SMALL_BLOCK},
            "VAE_rpl": {"latent_dim": 5, **_SMALL_BLOCK},
            "beta-VAE": {"latent_dim": 5, **_SMALL_BLOCK},
            "SVAE": {"hist": 8},
            "DSA": {"hist": 8},
        }),
    # Locomotion's, with the LD targets used as is (its positions are normalised, its rotation
    # blocks scored by the principal-axis error).
    "rearrange": dataclasses.replace(_LOCOMOTION, regressor_normalize=False),
}


def for_env(env: str, learner: str = "VAE_rpl", **overrides) -> StreamConfig:
    """The reference's settings for `env`'s family (`DOMAINS`), then `overrides`; a
    `learner_overrides` among them is laid over the family's for `learner`."""
    domain = DOMAINS[envs_config.family(env)]
    learner_overrides = {**domain.learners.get(learner, {}),
                         **overrides.pop("learner_overrides", {})}
    return StreamConfig(env=env, learner=learner, **{**domain.stream_fields(), **overrides},
                        learner_overrides=learner_overrides)
