"""`StreamConfig`: one learning-loop run, a frozen tree of typed configs: the run's schedule, its
replay (`ReplayConfig`), analyses (`EvalConfig`), policy (`PPOConfig`), env (its
`envs_mjx.config.EnvConfig`), learner (its `jaml.configs.learners.LearnerConfig`) and the
relations imposed on the learner's latents (`PenaltyConfig`, or none).

Defaults follow the reference suite (docs/reference/suite.md §3, §5) where they are not sizes; the
sizes of the paper (5000 replay columns, 10 000-row regressor sets, 100 000 epochs) are fields,
and `for_env` fills the per-domain ones from the domain family's `DomainDefaults` (rollout
length, learner steps per epoch, PPO network, sequence-learner window); `scaled` sets a named
scale's sizes (`SCALES`). Options given as text (the command line's KEY=VALUE, a driver's
sizes) enter the tree once, by path (`StreamConfig.with_overrides`).

A `StreamConfig` may leave values to the run ("auto" dtypes, the replay's size and kept share,
the learner's ld_dim: None); `resolve` fills them once, for the env's LD-state size and the
backend, into a `RunConfig`: what the stream, the run directory and its config.json hold, with
nothing left to fill. Records written by older code are read by `jaml.configs.records`.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from typing import Any, Literal, get_args

from envs_mjx import config as envs_config
from jaml.configs import learners as learners_config

Policy = Literal["ppo", "random"]
POLICIES = get_args(Policy)
# How the alignment regressor's held-out rows are drawn (`EvalConfig.validation_split`).
ValidationSplit = Literal["slots", "leading"]
VALIDATION_SPLITS = get_args(ValidationSplit)
# The reference's replay size in columns (docs/reference/suite.md §3).
REFERENCE_REPLAY_COLUMNS = 5000
# The share of replay slots kept from the initial policy, by learner (docs/reference/suite.md §3):
# the paper's replay keeps half for every learner but VAE_v0, whose only difference from VAE_rpl
# it is.
REPLAY_KEEP_FRACTION = {"VAE_v0": 0.0}
DEFAULT_REPLAY_KEEP_FRACTION = 0.5


def _below(config, names, prefix: str, at_least: int = 1) -> list[str]:
    """One problem per field of `names` under `at_least`, named by its path."""
    return [f"{prefix}{n} must be ≥ {at_least}, got {getattr(config, n)}"
            for n in names if getattr(config, n) < at_least]


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
class ReplayConfig:
    """The frame replay (docs/reference/suite.md §3).

    slots: replay columns, a multiple of num_envs; None: the reference's 5000 rounded down to a
      multiple of num_envs (4992 at 64 envs), filled in by `resolve`.
    keep_fraction: share of slots kept from the start; None: the learner's
      (`REPLAY_KEEP_FRACTION`: VAE_v0 0, others 0.5), filled in by `resolve`.
    """

    slots: int | None = None
    keep_fraction: float | None = None

    def __post_init__(self):
        problems = []
        if self.slots is not None and self.slots < 1:
            problems.append(f"replay.slots must be ≥ 1 or None, got {self.slots}")
        if self.keep_fraction is not None and not 0 <= self.keep_fraction < 1:
            problems.append(f"replay.keep_fraction must be in [0, 1), got {self.keep_fraction}")
        if problems:
            raise ValueError("; ".join(problems))


@dataclasses.dataclass(frozen=True)
class EvalConfig:
    """The alignment analyses and their regressor (docs/reference/suite.md §5).

    every: epochs between alignment analyses and checkpoints, counted from the first analysis,
      which runs when the replay is full and the learner starts (the reference counts its
      epochs from there): with 2 fill epochs, every 50 analyses at epochs 2, 52, 102, …, the
      learner's 0th, 50th, 100th, and at the last epoch.
    train: sequences in the regressor's training set, sampled from the replay.
    rand: sequences in the π_rand test set (random policy, the same set at every analysis).
    curr: sequences in the π_curr test set (current policy; PPO runs only).
    transient: steps after reset before the test sequences are cut (reference 120).
    regressor_iterations: alignment regressor steps (reference 10 000).
    regressor_normalize: z-score the regressor's targets (errors in training-std units, the
      benchmark envs); False for the domains whose LD state is already in a fixed range
      (Incline, Rearrange, docs/reference/suite.md §5), errors then in those units. Rearrange
      needs False: its rotation blocks are fit and scored by the principal-axis error of R_trueᵀR̂.
    distortion_dims: LD-state names whose values are τ^true in the distortion ρ (paper eq. 5;
      the incline's dynamic state, position and velocity); empty means all of them.
    validation_split: how the regressor's held-out 30 % of the training rows are drawn:
      "slots" from replay columns whose frames no fit row shows (`replay.sample_split`), so
      the validation error is not the fit's error on rows it saw; "leading" as the reference
      does, the leading rows of one draw from every column (with a small replay they repeat
      fit rows' frames). Records written before the choice existed read as "leading".
    """

    every: int = 100
    train: int = 10_000
    rand: int = 10_048
    curr: int = 2_500
    transient: int = 120
    regressor_iterations: int = 10_000
    regressor_normalize: bool = True
    distortion_dims: tuple[str, ...] = ()
    validation_split: ValidationSplit = "slots"

    def __post_init__(self):
        problems = _below(self, ("every", "train", "rand", "regressor_iterations"), "eval.")
        problems += _below(self, ("curr", "transient"), "eval.", at_least=0)
        if self.validation_split not in VALIDATION_SPLITS:
            problems.append(f"eval.validation_split must be one of {VALIDATION_SPLITS}, got "
                            f"{self.validation_split!r}")
        if problems:
            raise ValueError("; ".join(problems))


@dataclasses.dataclass(frozen=True)
class PenaltyConfig:
    """Relations imposed on the learner's latents (paper eq. 4; `relations.latent_penalty`,
    docs/transfer.md), built by the stream (`stream.penalty.latent_penalty`) from these fields.

    weight, form, ok_weight, ok_rows, ok_fraction: `relations.latent_penalty`'s.
    relations: the relation set's checkpoint directory (`jaml.relations.save`).
    used: 0-based indices of the relations imposed (`RelationSet.select`); empty: all of them.
    static / dynamic: the relation coordinates placed on the learner's declared static and
      dynamic latent entries (`LatentLayout.place` on `LearnerConfig.penalty_slots`); the
      action between two steps is the env's action.
    """

    weight: float = 100.0
    form: str = "hinge"
    ok_weight: float = 0.0
    ok_rows: str = "relations"
    ok_fraction: float | None = None
    relations: str = ""
    used: tuple[int, ...] = ()
    static: tuple[str, ...] = ()
    dynamic: tuple[str, ...] = ()


@dataclasses.dataclass(frozen=True)
class StreamConfig:
    """A learning-loop run.

    env / learner: registry names (`envs_mjx.ALL_ENVS`, `jaml.learners.ALL_LEARNERS`), or your
      own learner as MODULE:FACTORY (docs/own_learner.md).
    policy: "ppo" (PPO on the true LD state) or "random" (uniform actions).
    seed: PRNG seed of the run (envs, policy, learner, replay sampling, test sets).
    num_envs: envs stepped in parallel; each epoch adds one replay column per env.
    rollout_len: steps per env per epoch (a column holds rollout_len + 1 frames).
    learner_steps: learner gradient steps per epoch once the replay is full.
    frames_per_batch: frames per learner step; the batch has frames_per_batch // L sequences.
    epochs: total epochs of the run.
    replay: the replay's size and kept share (`ReplayConfig`).
    eval: the analyses' schedule, sets and regressor (`EvalConfig`).
    ppo: PPO's hyper-parameters (`for_env` sets the network and passes per domain).
    env_config: the env's config (`envs_mjx.config`); None: the env's defaults.
    learner_config: the learner's config (`jaml.configs.learners`); None: the learner's defaults
      (your own learner's: none). Its ld_dim is the env's LD-state size: None until `resolve`
      is given it (the stream reads it from the env it builds).
    penalty: relations imposed on the learner's latents (`PenaltyConfig`); None: none.
    """

    env: str = "CartPole"
    learner: str = "VAE_rpl"
    policy: Policy = "ppo"
    seed: int = 0
    num_envs: int = 64
    rollout_len: int = 32
    learner_steps: int = 10
    frames_per_batch: int = 1024
    epochs: int = 1000
    replay: ReplayConfig = dataclasses.field(default_factory=ReplayConfig)
    eval: EvalConfig = dataclasses.field(default_factory=EvalConfig)
    ppo: PPOConfig = dataclasses.field(default_factory=PPOConfig)
    env_config: envs_config.EnvConfig | None = None
    learner_config: learners_config.LearnerConfig | None = None
    penalty: PenaltyConfig | None = None

    def __post_init__(self):
        problems = []
        if self.policy not in POLICIES:
            problems.append(f"policy must be one of {POLICIES}, got {self.policy!r}")
        problems += _below(self, ("num_envs", "rollout_len", "learner_steps",
                                  "frames_per_batch", "epochs"), "")
        slots = self.replay.slots
        if self.num_envs >= 1 and slots and slots % self.num_envs:
            multiple = max(1, slots // self.num_envs) * self.num_envs
            problems.append(f"replay.slots ({slots}) must be a multiple of num_envs "
                            f"({self.num_envs}): each epoch adds num_envs columns; make "
                            f"replay.slots a multiple (e.g. {multiple}) or change num_envs")
        if self.policy == "ppo" and self.num_envs % self.ppo.num_minibatches:
            problems.append(f"num_envs ({self.num_envs}) must split into ppo.num_minibatches "
                            f"({self.ppo.num_minibatches}); set ppo.num_minibatches to a "
                            "divisor of num_envs")
        if problems:
            raise ValueError("; ".join(problems))
        # The typed configs' defaults, and their classes checked against the names (by the
        # registries, `configured`): here, so every config holds its env's and (registry)
        # learner's configs.
        object.__setattr__(self, "env_config",
                           envs_config.configured(self.env, self.env_config))
        if ":" in self.learner:  # your own learner: its factory sets its config
            if self.learner_config is not None:
                raise ValueError(f"learner_config must be None for your own learner "
                                 f"{self.learner}: its factory sets its config")
            return
        object.__setattr__(self, "learner_config", learners_config.configured(
            self.learner, self.learner_config) if self.learner_config is not None
            else learners_config.default_config(self.learner, ld_dim=None))

    def replace(self, **changes) -> StreamConfig:
        """`dataclasses.replace`; a new env or learner name starts from its configs' defaults
        unless `changes` gives them."""
        for name in ("env", "learner"):
            if name in changes and changes[name] != getattr(self, name):
                changes.setdefault(f"{name}_config", None)
        return dataclasses.replace(self, **changes)

    def with_overrides(self, overrides: Mapping[str, Any]) -> StreamConfig:
        """This config with `overrides`: path → value, a path naming a field of the tree as the
        command line does ("seed", "eval.every", "replay.slots", "ppo.hidden",
        "learner_config.beta", "env_config.multicolor"); JSON lists become tuples. The one way
        options given as text enter the tree: a new env or learner first (its configs' defaults,
        `replace`), then the rest, checked once together; unknown paths raise, naming the valid
        fields."""
        overrides = _tuples(dict(overrides))
        names = {k: overrides.pop(k) for k in ("env", "learner") if k in overrides}
        config = self.replace(**names)
        top: dict[str, Any] = {}
        for path, value in overrides.items():
            name, *rest = path.split(".")
            _check(config, name, "")
            top[name] = (_set(top.get(name, getattr(config, name)), rest, value, f"{name}.")
                         if rest else value)
        return config.replace(**top)

    def to_dict(self) -> dict[str, Any]:
        """The tree as JSON-ready fields (a `RunConfig`'s is its config.json)."""
        d = dataclasses.asdict(self)
        return json.loads(json.dumps(d))  # tuples → lists: what a JSON round trip gives

    @classmethod
    def from_dict(cls, d: dict[str, Any]):
        """The config a `to_dict` describes (a `RunConfig`'s: a config.json of this code; older
        records are read by `jaml.configs.records.read`). Fields a record lacks take their
        defaults; fields of the learner's and env's configs the code no longer has are
        dropped."""
        d = dict(d)
        learner, env, penalty = (d.pop(k, None) for k in ("learner_config", "env_config",
                                                          "penalty"))
        parts = {name: kind(**_tuples(d.pop(name, {})))
                 for name, kind in (("replay", ReplayConfig), ("eval", EvalConfig),
                                    ("ppo", PPOConfig))}
        config = StreamConfig(**d, **parts)  # the env's and learner's default configs
        return cls(**_fields(config) | {
            "env_config": _known(config.env_config, env),
            "learner_config": _known(config.learner_config, learner),
            "penalty": None if penalty is None else PenaltyConfig(**_tuples(penalty))})


@dataclasses.dataclass(frozen=True)
class RunConfig(StreamConfig):
    """A `StreamConfig` with nothing left to the run (`resolve`): the replay's size and kept
    share, the learner's dtypes and ld_dim are concrete. What a Stream is built for, what a run
    directory claims and what its config.json holds (`to_dict`, read back by `from_dict`)."""

    def __post_init__(self):
        super().__post_init__()
        left = [name for name, value in (("replay.slots", self.replay.slots),
                                         ("replay.keep_fraction", self.replay.keep_fraction))
                if value is None]
        learner = self.learner_config
        if learner is not None:
            left += [f"learner_config.{name}" for name in ("ld_dim", "compute_dtype",
                                                            "activation_dtype")
                     if getattr(learner, name) in (None, "auto")]
        if left:
            raise ValueError(f"a RunConfig has every value filled, but {', '.join(left)} is "
                             "left to the run; make it with resolve(config, ld_dim, backend)")

    @property
    def fill_epochs(self) -> int:
        """Epochs until the replay is full and the learner starts (docs/reference/suite.md §3)."""
        return self.replay.slots // self.num_envs

def resolve(config: StreamConfig, ld_dim: int, backend: str) -> RunConfig:
    """`config` with every value it leaves to the run filled in: the replay's columns (the
    reference's 5000 rounded down to a multiple of num_envs) and kept share (the learner's,
    `REPLAY_KEEP_FRACTION`), the learner's "auto" dtypes for `backend` (JAX's name: "cpu",
    "gpu", "tpu"; `LearnerConfig.for_backend`) and its ld_dim, the env's LD-state size."""
    fields = _fields(config)
    replay = config.replay
    if replay.slots is None:
        replay = dataclasses.replace(replay, slots=max(1, REFERENCE_REPLAY_COLUMNS
                                                       // config.num_envs) * config.num_envs)
    if replay.keep_fraction is None:
        replay = dataclasses.replace(replay, keep_fraction=REPLAY_KEEP_FRACTION.get(
            config.learner, DEFAULT_REPLAY_KEEP_FRACTION))
    learner = config.learner_config
    if learner is not None:
        learner = learner.for_backend(backend).replace(ld_dim=ld_dim)
    return RunConfig(**fields | {"replay": replay, "learner_config": learner})


def resolve_runs(configs: list[StreamConfig], ld_dim: int, backend: str) -> list[RunConfig]:
    """Each of `configs` resolved (`resolve`) as a run of one program, the first's: they may
    differ only in their seeds, so one Stream trains them all (`one_program` checks)."""
    runs = []
    for config in configs:
        runs.append(resolve(config, ld_dim, backend))
        one_program(runs[-1], runs[0])
    return runs


def one_program(run: RunConfig, program: RunConfig) -> None:
    """Raises ValueError, naming the fields, where `run` differs from `program` in more than
    its seed: a Stream compiled for one serves only its own seeds."""
    if run.replace(seed=program.seed) != program:
        differ = ", ".join(changed_fields(run, program))
        raise ValueError(f"runs of one Stream differ only in their seeds; this config differs "
                         f"in {differ}: build a Stream for it (jaml.stream.build)")


def _fields(config) -> dict[str, Any]:
    """A dataclass's fields by name, as they are (not copied: `dataclasses.asdict` would)."""
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}


def _known(default, fields: dict[str, Any] | None):
    """`default` with the `fields` it has replaced (JSON lists as tuples); fields the code no
    longer has are dropped. None: `default`."""
    if default is None or fields is None:
        return default
    valid = {f.name for f in dataclasses.fields(default)}
    return dataclasses.replace(default, **_tuples({k: v for k, v in fields.items()
                                                   if k in valid}))


def _tuple(value):
    return tuple(value) if isinstance(value, list) else value


def _tuples(fields: dict[str, Any]) -> dict[str, Any]:
    return {k: _tuple(v) for k, v in fields.items()}


def _check(node, name: str, at: str) -> None:
    if not dataclasses.is_dataclass(node):
        raise ValueError(f"{at.rstrip('.')} is {node!r}, not a config with fields")
    valid = [f.name for f in dataclasses.fields(node)]
    if name not in valid:
        raise ValueError(f"unknown config field {at + name!r}; valid: "
                         f"{', '.join(at + v for v in valid)}")


def _set(node, names: list[str], value, at: str):
    """`node` (a config below the stream's) with the field at path `names` set to `value`."""
    name, *rest = names
    _check(node, name, at)
    if rest:
        value = _set(getattr(node, name), rest, value, f"{at}{name}.")
    return dataclasses.replace(node, **{name: value})


def changed_fields(config, default, *, skip=()) -> dict[str, Any]:
    """What turns the dataclass `default` into `config`: the fields that differ, less those in
    `skip`, by path: a nested config of the same type by its own fields ("eval.every"), so
    `default.with_overrides(changed_fields(config, default))` is `config`."""
    changed = {}
    for f in dataclasses.fields(config):
        new, old = getattr(config, f.name), getattr(default, f.name)
        if f.name in skip or new == old:
            continue
        if dataclasses.is_dataclass(new) and type(new) is type(old):
            changed |= {f"{f.name}.{k}": v for k, v in changed_fields(new, old).items()}
        else:
            changed[f.name] = new
    return changed


@dataclasses.dataclass(frozen=True)
class DomainDefaults:
    """One domain family's settings: StreamConfig fields (the rest keep StreamConfig's
    defaults), and by learner name the learner config fields it sets (`learners`), laid over
    the learner's defaults once (`config`)."""

    rollout_len: int
    learner_steps: int
    ppo: PPOConfig = PPOConfig()
    eval: EvalConfig = EvalConfig()
    learners: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)

    def config(self, env: str, learner: str) -> StreamConfig:
        """`env`'s StreamConfig for `learner` with this family's settings."""
        own = ":" in learner
        return StreamConfig(
            env=env, learner=learner, rollout_len=self.rollout_len,
            learner_steps=self.learner_steps, ppo=self.ppo, eval=self.eval,
            learner_config=None if own else learners_config.default_config(
                learner, ld_dim=None, **self.learners.get(learner, {})))


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
        eval=EvalConfig(regressor_normalize=False, distortion_dims=("position", "velocity")),
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
    "rearrange": dataclasses.replace(_LOCOMOTION, eval=EvalConfig(regressor_normalize=False)),
}


def for_env(env: str, learner: str = "VAE_rpl",
            overrides: Mapping[str, Any] | None = None) -> StreamConfig:
    """The reference's settings for `env`'s family (`DOMAINS`) and `learner`, then `overrides`
    (`StreamConfig.with_overrides`: "eval.every", "learner_config.hist", …), which win over
    the family's."""
    domain = DOMAINS[envs_config.family(env)]
    return domain.config(env, learner).with_overrides(overrides or {})


# Named scales, as overrides over a domain's settings (`scaled`): "smoke", the plumbing of a run
# in minutes on two CPU cores (its sets are too small for its numbers to rank encoders:
# `SMOKE_NOTE`); "small", the smallest whose numbers order a true-state, a pixel-PCA and a
# no-information encoder on π_rand and validation, within minutes on two CPU cores (measured:
# docs/usage.md, "Small runs"); "paper", the paper's (the StreamConfig defaults, `for_env`'s
# per-domain settings).
SCALES: dict[str, dict] = {
    "smoke": {"num_envs": 8, "rollout_len": 4, "replay.slots": 16, "frames_per_batch": 8,
              "learner_steps": 2, "epochs": 4, "eval.every": 2, "eval.train": 64,
              "eval.rand": 64, "eval.curr": 32, "eval.transient": 3,
              "eval.regressor_iterations": 200},
    "small": {"num_envs": 16, "rollout_len": 16, "replay.slots": 64, "frames_per_batch": 32,
              "learner_steps": 4, "epochs": 8, "eval.every": 4, "eval.train": 1024,
              "eval.rand": 1024, "eval.curr": 256, "eval.transient": 3,
              "eval.regressor_iterations": 2000},
    "paper": {},
}
# The sizes that make the analysis's sets and fit (what `scale_of` compares).
_SET_SIZES = ("num_envs", "replay.slots", "eval.train", "eval.rand", "eval.curr",
              "eval.transient", "eval.regressor_iterations")
# What the smoke scale's reports and `jaml suite --scale smoke` say beside their numbers.
SMOKE_CAVEAT = ("smoke scale: for plumbing only, its sets are too small for its numbers to rank "
                "encoders")
SMOKE_NOTE = f"{SMOKE_CAVEAT} (use the small scale, --scale small)"


def scaled(config: StreamConfig, scale: str) -> StreamConfig:
    """`config` with the sizes of `scale` ("smoke": plumbing, minutes on a CPU; "small": the
    smallest that ranks encoders, minutes on a CPU; "paper": unchanged); PPO's minibatches are
    cut to split the scale's envs, and a sequence learner's window (SVAE's 24 frames) keeps the
    rollout and batch long enough to hold one sequence (a learner of your own: one frame)."""
    if scale not in SCALES:
        raise ValueError(f"unknown scale {scale!r}; valid: {list(SCALES)}")
    changes = dict(SCALES[scale])
    if not changes:
        return config
    if changes["num_envs"] % config.ppo.num_minibatches:
        changes["ppo.num_minibatches"] = 4
    seq_len = 1 if config.learner_config is None else config.learner_config.seq_len
    changes["rollout_len"] = max(changes["rollout_len"], seq_len - 1)
    changes["frames_per_batch"] = max(changes["frames_per_batch"], seq_len)
    return config.with_overrides(changes)


def scale_of(config: StreamConfig) -> str | None:
    """The name of the `SCALES` entry whose sizes `config` has (None: none, or the paper's
    defaults changed otherwise)."""
    for name, sizes in SCALES.items():
        if sizes and config == config.with_overrides({k: sizes[k] for k in _SET_SIZES}):
            return name
    return None
