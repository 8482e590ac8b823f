"""The learners' configs: what `jaml suite --learner L --help` lists, and the learner registry
(`LEARNERS`: names, config classes, defaults, builders; `default_config`, `configured`).
Importing this module imports neither JAX nor Flax; the models that read these configs live in
`jaml.learners`.
"""

from __future__ import annotations

import dataclasses
import math
import typing

if typing.TYPE_CHECKING:
    import jax

# The str fields' values, as Literal types (the command line's choices) and tuples.
# The encoder's view of the last input frame's action (`elbo.encoder_actions`).
CurrentAction = typing.Literal["observed", "hidden"]
CURRENT_ACTIONS = typing.get_args(CurrentAction)
# How the decoder's k4 s2 p1 transposed convolutions are computed (`networks.upsample2x`):
# "auto" is "phase" on the CPU, "pair" elsewhere; all stay selectable, one function.
UpsampleForm = typing.Literal["auto", "subpixel", "phase", "dilated", "pair"]
UPSAMPLE_FORMS = typing.get_args(UpsampleForm)
# The KL term's forms (`elbo.kl_to_standard_normal`).
KLForm = typing.Literal["standard", "reference"]
KL_FORMS = typing.get_args(KLForm)
# How the decoded frames' log-likelihoods combine (`LearnerConfig.frame_nll`).
FrameNLL = typing.Literal["sum", "mean"]
FRAME_NLLS = typing.get_args(FrameNLL)
# The conv stacks' dtypes, by their JAX names (`LearnerConfig.conv_dtype`); "auto" is
# "bfloat16" off the CPU and "float32" on it (`dtype_for_backend`).
ComputeDtype = typing.Literal["auto", "float32", "bfloat16"]
COMPUTE_DTYPE_NAMES = typing.get_args(ComputeDtype)


def dtype_for_backend(name: str, backend: str) -> str:
    """A compute / activation dtype name with "auto" made concrete for `backend` (JAX's name:
    "cpu", "gpu", "tpu"): bfloat16 on accelerators, where it kept the Fig. 2 cells' results
    (docs/learners.md); float32 on the CPU, where XLA's bfloat16 convolutions are slower."""
    if name != "auto":
        return name
    return "float32" if backend == "cpu" else "bfloat16"


def _jax_dtype(name: str):
    import jax  # here: the configs import no JAX

    return getattr(jax.numpy, dtype_for_backend(name, jax.default_backend()))


@dataclasses.dataclass(frozen=True)
class LearnerConfig:
    """What every learner shares; defaults reproduce the reference (docs/reference/suite.md §4).

    ld_dim: size D of the true low-dimensional state; the per-step latent defaults to 2·D. None
      in a run's config until it is resolved: the stream sets it to its env's LD-state size.
    latent_dim: per-step latent size; None means 2·ld_dim (DSA: the dynamic part, None → D).
    beta: weight of the KL term (β-VAE; DSA weighs only the dynamic KL with it).
    mu_nl: the reference's `mu_nl=Sigmoid`: ELU on the posterior mean and a sigmoid on the
      sample before decoding.
    frame_nll: how the decoded frames' log-likelihoods combine: "sum" is the sequence ELBO of
      paper eq. 4 (log p(x_{1:S} | τ) = Σ_t log p(x_t | τ_t)), the reference's balance too (it
      averages likelihood and KL over the frames); "mean" averages the likelihood alone, which
      weighs the KL S times more per frame and collapsed the posteriors of PRED and SVAE
      (S = 24) in our runs (docs/learners.md). Same for S = 1.
    compute_dtype: "auto" (default: "bfloat16" on a GPU or TPU, "float32" on the CPU),
      "float32" or "bfloat16": the dtype of the shared conv encoder's and decoder's
      convolutions (VAEs, PRED, SVAE, DSA; not SPAIR's): mixed precision, with parameters, batch
      norms, heads, the loss and the optimizer in float32. Not in the reference (float32).
    activation_dtype: "auto" (default, as compute_dtype), "float32" or "bfloat16": the dtype of
      the conv stacks' activations between convolutions (batch-norm and ELU outputs, the
      decoder's biased transposed-convolution outputs), what `torch.autocast` stores;
      batch-norm statistics, parameters and everything after the encoder stay float32. With
      compute_dtype "bfloat16" it halves the memory traffic of those elementwise passes. Not in
      the reference. A run records both concrete (`jaml.stream.resolve`).
    current_action: "observed" (the reference code): the encoder sees the executed action of
      every input frame, the one into the first predicted frame included; "hidden": that last
      action is zeroed (`elbo.encoder_actions`).
    kl_form: "standard" KL to N(0, I), or the reference code's form (`elbo.kl_to_standard_normal`;
      learners with a standard-normal prior: VAEs, PRED, SVAE).
    upsample_form: how the conv decoder computes its transposed convolutions (`UPSAMPLE_FORMS`;
      the same function each way, a speed choice per device).
    """

    ld_dim: int | None
    latent_dim: int | None = None
    beta: float = 1.0
    learning_rate: float = 1e-4
    logvar_limit: float = 6.0
    mu_nl: bool = True
    conv_filters: tuple[int, ...] = (64, 128, 128, 256)
    conv_features: int = 128
    deconv_filters: tuple[int, ...] = (256, 128, 128, 64)
    frame_nll: FrameNLL = "sum"
    compute_dtype: ComputeDtype = "auto"
    activation_dtype: ComputeDtype = "auto"
    current_action: CurrentAction = "observed"
    kl_form: KLForm = "standard"
    upsample_form: UpsampleForm = "auto"

    def __post_init__(self):
        if self.upsample_form not in UPSAMPLE_FORMS:
            raise ValueError(f"upsample_form must be one of {list(UPSAMPLE_FORMS)}, got "
                             f"{self.upsample_form!r}")
        if self.current_action not in CURRENT_ACTIONS:
            raise ValueError(f"current_action must be one of {list(CURRENT_ACTIONS)}, got "
                             f"{self.current_action!r}")
        if self.kl_form not in KL_FORMS:
            raise ValueError(f"kl_form must be one of {list(KL_FORMS)}, got "
                             f"{self.kl_form!r}")
        for field in ("compute_dtype", "activation_dtype"):
            if getattr(self, field) not in COMPUTE_DTYPE_NAMES:
                raise ValueError(f"{field} must be one of {list(COMPUTE_DTYPE_NAMES)}, got "
                                 f"{getattr(self, field)!r}")
        if self.frame_nll not in FRAME_NLLS:
            raise ValueError(f"frame_nll must be 'sum' or 'mean', got "
                             f"{self.frame_nll!r}")
        if self.ld_dim is not None and int(self.ld_dim) < 1:
            raise ValueError(f"ld_dim must be ≥ 1, got {self.ld_dim}")
        if self.latent_dim is not None and int(self.latent_dim) < 1:
            raise ValueError(f"latent_dim must be ≥ 1 or None, got {self.latent_dim}")
        if not self.beta >= 0 or not self.learning_rate > 0 or not self.logvar_limit > 0:
            raise ValueError(f"beta must be ≥ 0, learning_rate and logvar_limit > 0; got beta "
                             f"{self.beta}, learning_rate {self.learning_rate}, logvar_limit "
                             f"{self.logvar_limit}")

    def replace(self, **changes) -> LearnerConfig:
        return dataclasses.replace(self, **changes)

    def for_backend(self, backend: str) -> LearnerConfig:
        """This config with its "auto" dtypes made concrete for `backend` (`dtype_for_backend`):
        what a run on that backend computes, and records."""
        return self.replace(**{f: dtype_for_backend(getattr(self, f), backend)
                               for f in ("compute_dtype", "activation_dtype")})

    @property
    def conv_dtype(self):
        """compute_dtype as a JAX dtype, for the conv encoder and decoder ("auto": for JAX's
        default backend)."""
        return _jax_dtype(self.compute_dtype)

    @property
    def act_dtype(self):
        """activation_dtype as a JAX dtype, for the conv encoder and decoder ("auto": as
        conv_dtype)."""
        return _jax_dtype(self.activation_dtype)

    @property
    def actions_seen(self) -> int:
        """How many of a sequence's first actions the encoder reads (`current_action`)."""
        hist = self.hist
        return hist if self.current_action == "observed" else hist - 1

    @property
    def z_step(self) -> int:
        """Per-step latent size."""
        return self.latent_dim or 2 * self.ld_dim

    # Overridden per family.
    @property
    def seq_len(self) -> int:
        """T: frames per batch sequence."""
        raise NotImplementedError

    @property
    def latent_steps(self) -> int:
        """S: latent steps, one decoded frame each (the last S frames of the sequence)."""
        raise NotImplementedError

    @property
    def static_size(self) -> int:
        """F: latent entries shared by all steps (PRED's static part; 0 for most learners)."""
        return 0

    @property
    def penalty_dim(self) -> int:
        """P: per-step size of the sampled latent handed to a latent penalty."""
        return self.static_size + self.z_step

    @property
    def latent_size(self) -> int:
        """Z: size of `encode`'s flattened posterior mean."""
        return self.static_size + self.latent_steps * self.z_step

    @property
    def penalty_slots(self) -> dict[str, tuple[int, ...]]:
        """Which entries of the per-step penalty latent (P) are static (one value per
        sequence) and which dynamic (one per step): what `relations.LatentLayout.place` puts a
        relation set's coordinates on."""
        return {"static": tuple(range(self.static_size)),
                "dynamic": tuple(range(self.static_size, self.penalty_dim))}


@dataclasses.dataclass(frozen=True)
class SingleFrameConfig(LearnerConfig):
    """Learners that see one frame and decode it (VAE, SPAIR): hist = T = S = 1."""

    @property
    def hist(self) -> int:
        return 1

    @property
    def seq_len(self) -> int:
        return 1

    @property
    def latent_steps(self) -> int:
        return 1


@dataclasses.dataclass(frozen=True)
class RecurrentConfig(LearnerConfig):
    """Learners that encode all `hist` frames with an RNN and keep one latent per frame.

    min_hist: the fewest frames the model can work with (a class constant, not a field).
    """

    hist: int = 24
    rnn_hidden: int = 512
    min_hist: typing.ClassVar[int] = 1

    def __post_init__(self):
        super().__post_init__()
        if self.hist < self.min_hist:
            raise ValueError(f"{type(self).__name__} needs hist ≥ {self.min_hist}, got {self.hist}")

    @property
    def seq_len(self) -> int:
        return self.hist

    @property
    def latent_steps(self) -> int:
        return self.hist


@dataclasses.dataclass(frozen=True)
class VAEConfig(SingleFrameConfig):
    """VAE on single frames (PARAMS_VAE: hist 1, past 1, pred 0; latent 2·D).

    VAE_v0 and VAE_rpl differ in the stream's replay alone (`jaml.stream.resolve`: 0
    and 0.5); β-VAE defaults to β = 5, the best of the paper's {100, 20, 10, 5, 0.5}.
    """

    mlp_widths: tuple[int, ...] = (1024, 512)


@dataclasses.dataclass(frozen=True)
class SVAEConfig(RecurrentConfig):
    """SVAE_SEQ24 by default (hist = past = 24, pred 0); SEQ16 / SEQ8 / PARAMS_SVAE: 16 / 8 / 32."""


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


@dataclasses.dataclass(frozen=True)
class DSAConfig(RecurrentConfig):
    """DSA_SEQ24 by default: static F = D and dynamic Z = D per step (2·D in all), hist 24.

    latent_dim is the dynamic size (None → ld_dim); static_dim None → ld_dim. β weighs only
    the dynamic KL: loss = −(recon − (KL_f + β Σ_t KL_z)).
    """

    static_dim: int | None = None
    prior_hidden: int = 512
    min_hist: typing.ClassVar[int] = 2  # its static encoder sees half the frames

    def __post_init__(self):
        super().__post_init__()
        if self.kl_form != "standard":
            raise ValueError(f"DSA's KLs are to learned priors: kl_form must be 'standard', got "
                             f"{self.kl_form!r}")

    @property
    def z_step(self) -> int:
        return self.latent_dim or self.ld_dim

    @property
    def f_size(self) -> int:
        return self.static_dim or self.ld_dim

    @property
    def static_size(self) -> int:
        return self.f_size


# SPAIR's per-cell layout (`jaml.learners.spair`).
WHERE = 4  # per cell: x, y offset of the box centre in its cell; x, y size (pre-sigmoid)
# Per cell in `encode` / the penalty latent: where (4), presence (1), depth (1), then what (K).
CELL_FIXED = WHERE + 2


@dataclasses.dataclass(frozen=True)
class SPAIRConfig(SingleFrameConfig):
    """SPAIR on single frames (seq_len 1, one latent step); ld_dim / latent_dim are unused.

    Defaults follow SPAIR's published configuration (auto_yolo `yolo_air_config`) where it has
    one, and our choices otherwise (docs/learners.md lists which).

    beta: the weight of every KL group against the unit-variance Gaussian −log p(x | ·) (0.1).
      With Adam, loss = nll + β·KL trains like a Gaussian likelihood of σ = √β ≈ 0.32, close to
      the weight SPAIR's per-pixel cross-entropy gives a pixel (its curvature 1/(p(1 − p)) is
      4 at p = ½, 11 at p = 0.1). At β = 1 an object's pixels were worth less than its KLs and
      the presences died on the toy task (docs/notes/learners.md, `spair_probe`).
    grid_size: G, cells per side (4; the paper's other grid is 6); any of 1..8.
    glimpse_size: side g of the object glimpse (the AML paper's 28); a multiple of 4.
    what_dim: K, appearance latent per cell (SPAIR's A = 50). bg_dim: Q, background latent.
    min_yx, max_yx: a box centre lies at cell + min_yx + (max_yx − min_yx)·σ(offset) in cell
      units, so it can reach half a cell past its own cell (SPAIR: −0.5, 1.5).
    anchor_scale: box side = anchor_scale·σ(size) as a fraction of the frame (SPAIR's anchor box
      was the whole 48×48 image: 1.0).
    hw_prior_mean / hw_prior_std: the N(μ, σ²) prior on the size logits (SPAIR: log(0.1/0.9),
      0.5: boxes of about a tenth of the anchor); the offset, what and depth logits have N(0, 1).
    count_prior_odds: final odds ρ/(1 − ρ) of the geometric count prior P(C = k) ∝ ρ^k on
      k = 0..N present objects (SPAIR: 0.0125). count_prior_odds_start: the odds at step 0
      (1e6, nearly uniform over counts); they decay by count_prior_decay ×10 in log space
      every count_prior_decay_steps steps towards the final value (SPAIR's `Exp(1e6, 0.0125,
      decay_rate=0.1, decay_steps=1000, log=True)`); count_prior_decay_steps 0 fixes the
      final value from the start.
    temperature: of the binary-concrete relaxation of presence in training (SPAIR: 1.0).
    backbone_filters: the three k4 s2 p1 convs 64 → 8; conv_features: the per-cell feature.
    lateral_widths / passthrough: the per-cell box, depth and presence MLPs (SPAIR: 100, 100)
      and the features each passes to the next one (SPAIR: 100).
    object_filters / object_hidden: the glimpse encoder's two convs and dense width (the
      decoder mirrors them). bg_hidden / bg_resolution: background MLP width and the side of
      the decoded background before its bilinear upsampling to 64×64.
    init_logvar: initial bias of every posterior log-variance head (σ ≈ 0.37 at −2): with unit
      variances the sampled boxes and presences made the early loss mostly noise.
    training_wheels_steps: SPAIR's training wheels: for the first this many training steps no
      gradient reaches the box, depth and presence posteriors (their μ, logvar and the presence
      logit are held by a stop-gradient), so that the glimpse encoder / decoder learn to draw
      what lies in the initial boxes before the boxes and presences move (SPAIR: 1000, a
      staircase `Exp(1.0, 0.0, decay_rate=0.0, decay_steps=1000, staircase=True)`); 0 turns
      them off.
    conv_filters / deconv_filters / mu_nl are not used.
    """

    beta: float = 0.1
    grid_size: int = 4
    glimpse_size: int = 28
    what_dim: int = 50
    bg_dim: int = 4
    min_yx: float = -0.5
    max_yx: float = 1.5
    anchor_scale: float = 1.0
    hw_prior_mean: float = math.log(0.1 / 0.9)
    hw_prior_std: float = 0.5
    count_prior_odds: float = 0.0125
    count_prior_odds_start: float = 1e6
    count_prior_decay_steps: int = 1000
    temperature: float = 1.0
    backbone_filters: tuple[int, ...] = (32, 64, 128)
    lateral_widths: tuple[int, ...] = (100, 100)
    passthrough: int = 100
    object_filters: tuple[int, int] = (32, 64)
    object_hidden: int = 256
    bg_hidden: int = 128
    bg_resolution: int = 16
    init_logvar: float = -2.0
    training_wheels_steps: int = 1000

    @property
    def actions_seen(self) -> int:
        return 0  # SPAIR reads the frame alone

    def __post_init__(self):
        super().__post_init__()
        checks = [
            ("grid_size", 1 <= self.grid_size <= 8, "in 1..8"),
            ("glimpse_size", self.glimpse_size >= 4 and self.glimpse_size % 4 == 0,
             "a positive multiple of 4"),
            ("what_dim", self.what_dim >= 1, "≥ 1"),
            ("bg_dim", self.bg_dim >= 1, "≥ 1"),
            ("kl_form", self.kl_form == "standard", "'standard' (its KLs have their own priors)"),
            ("max_yx", self.max_yx > self.min_yx, f"> min_yx = {self.min_yx}"),
            ("anchor_scale", 0.0 < self.anchor_scale <= 2.0, "in (0, 2]"),
            ("hw_prior_std", self.hw_prior_std > 0.0, "> 0"),
            ("count_prior_odds", self.count_prior_odds > 0.0, "> 0"),
            ("count_prior_odds_start", self.count_prior_odds_start > 0.0, "> 0"),
            ("count_prior_decay_steps", self.count_prior_decay_steps >= 0, "≥ 0"),
            ("training_wheels_steps", self.training_wheels_steps >= 0, "≥ 0"),
            ("temperature", self.temperature > 0.0, "> 0"),
            ("backbone_filters", len(self.backbone_filters) == 3, "three conv widths"),
            ("lateral_widths", len(self.lateral_widths) >= 1, "at least one width"),
            ("passthrough", self.passthrough >= 0, "≥ 0"),
            ("object_filters", len(self.object_filters) == 2, "two conv widths"),
            ("bg_resolution", 1 <= self.bg_resolution <= 64, "in 1..64"),
        ]
        for name, ok, what in checks:
            if not ok:
                raise ValueError(f"SPAIRConfig.{name} must be {what}, got {getattr(self, name)!r}")

    @property
    def cells(self) -> int:
        """N = G²."""
        return self.grid_size**2

    @property
    def program_size(self) -> int:
        """P: what a cell passes to its neighbours: σ(where) [4], what [K], depth z, presence."""
        return WHERE + self.what_dim + 2

    @property
    def penalty_dim(self) -> int:
        return self.latent_size

    @property
    def latent_size(self) -> int:
        """N·(4 + 1 + 1 + K) + Q."""
        return self.cells * (CELL_FIXED + self.what_dim) + self.bg_dim

    def count_prior_log_odds(self, step) -> jax.Array:
        """log ρ/(1 − ρ) of the count prior after `step` training steps (the annealing)."""
        import jax.numpy as jnp

        end = math.log(self.count_prior_odds)
        if self.count_prior_decay_steps == 0:
            return jnp.asarray(end, jnp.float32)
        start = math.log(self.count_prior_odds_start)
        decay = 0.1 ** (jnp.asarray(step, jnp.float32) / self.count_prior_decay_steps)
        return end + (start - end) * decay

    def training_wheels(self, step) -> jax.Array:
        """1.0 while the training wheels are on (`step` < training_wheels_steps), else 0.0."""
        import jax.numpy as jnp

        return (jnp.asarray(step, jnp.float32) < self.training_wheels_steps).astype(jnp.float32)


# The learner registry: name → (config class, defaults that differ from the class's, the
# "module:function" that builds the learner from its config, which `jaml.learners.make` calls).
# The builders are named, not imported: they import JAX and Flax, and this module must not.
# VAE_rpl differs from VAE_v0 only in the stream's replay (`jaml.configs.stream.resolve`).
LEARNERS: dict[str, tuple[type[LearnerConfig], dict, str]] = {
    "VAE_v0": (VAEConfig, {}, "jaml.learners.vae:make_vae"),
    "VAE_rpl": (VAEConfig, {}, "jaml.learners.vae:make_vae"),
    "beta-VAE": (VAEConfig, {"beta": 5.0}, "jaml.learners.vae:make_vae"),
    "SVAE": (SVAEConfig, {}, "jaml.learners.svae:make_svae"),
    "PRED": (PREDConfig, {}, "jaml.learners.pred:make_pred"),
    "DSA": (DSAConfig, {}, "jaml.learners.dsa:make_dsa"),
    # 4×4 grid by default; make("SPAIR", ld_dim=D, grid_size=6) for the paper's 6×6 variant.
    "SPAIR": (SPAIRConfig, {}, "jaml.learners.spair:make_spair"),
}
ALL_LEARNERS = tuple(LEARNERS)


def registered(name: str) -> tuple[type[LearnerConfig], dict, str]:
    """The named learner's registry entry (config class, defaults, builder); an unknown name
    raises ValueError listing the valid ones."""
    if name not in LEARNERS:
        raise ValueError(f"unknown learner {name!r}; valid names: {', '.join(ALL_LEARNERS)}")
    return LEARNERS[name]


def default_config(name: str, **overrides) -> LearnerConfig:
    """The named learner's config: reference defaults, then `overrides` (ld_dim is required; None
    leaves it to the stream, which sets the env's)."""
    cls, defaults, _ = registered(name)
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise ValueError(f"{name}: unknown config fields {unknown}; valid: {sorted(fields)}")
    if "ld_dim" not in overrides:
        raise ValueError(f"{name}: ld_dim (the true LD-state size) is required")
    return cls(**{**defaults, **overrides})


def configured(name: str, config: LearnerConfig | None = None, **overrides) -> LearnerConfig:
    """The named learner's config: `default_config(name, **overrides)`, or `config` (its class
    checked against the name's) with `overrides` replaced."""
    if config is None:
        return default_config(name, **overrides)
    cls = registered(name)[0]
    if type(config) is not cls:
        raise ValueError(f"{name} needs a {cls.__name__}, got {type(config).__name__}: give "
                         f"a {cls.__name__} or None (its defaults)")
    return config.replace(**overrides) if overrides else config
