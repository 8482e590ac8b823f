"""`Config`: every knob of Algorithm 1; defaults from the paper (the reference where it is silent).

Derived values (the transversality weight of each objective, the syzygy step budget) are computed
by properties, not stored. `docs/relations.md` lists where a default follows the reference
implementation instead of the paper, and why.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal, get_args

Independence = Literal["transversality", "syzygy"]
Objective = Literal["paper", "reference"]
SyzygyTraining = Literal["rounds", "joint"]
INDEPENDENCE: tuple[str, ...] = get_args(Independence)
OBJECTIVES: tuple[str, ...] = get_args(Objective)
SYZYGY_TRAINING: tuple[str, ...] = get_args(SyzygyTraining)


# Fields added after runs were recorded, with the values that reproduce what those runs did
# (no mining, no refinement, every one of max_relations trained).
LEGACY_FIELDS = {"mined_weight": 0.0, "refine_rounds": 0, "stop_when_complete": False,
                 "codimension": None, "premine": False, "premine_attempts": 1,
                 "mined_patience": None, "transversal_first": False}
# Fields runs recorded that no longer exist, with the one value that meant what runs do now (a
# record with another value ran code that is gone, and is refused).
RETIRED_FIELDS = {"cut_beyond_codim": False}


@dataclasses.dataclass(frozen=True)
class Config:
    """Configuration of `relations.fit`.

    Attributes:
      max_relations: relations g_1..g_K to learn (Algorithm 1 loops k = 1, 2, …; reference: 10).
      independence: "transversality" (eq. 2) or "syzygy" (restricted syzygies, eq. 3).
      objective: "paper": d_g − log‖∇g‖ (eq. 1), −β log Π sin² (eq. 2), other terms clipped to
        twice the first (App. B.3.1). "reference": the hinged terms of the authors' code.
      seed: PRNG seed for initialisation and data.
      batch_size: on- and off-manifold rows per step (reference: 1024).
      learning_rate: Adam step size of every g_k (reference: 1e-4; 1e-3 here reaches the stopping
        rule in fewer steps, see docs/relations.md "deviations"). Prior pre-training uses it too.
      syzygy_learning_rate: Adam step size of the syzygy network f (reference: 1e-4).
      max_steps: cap on optimizer steps per relation (reference: 50 000).
      base_width: hidden width of g_1; g_k's layers have base_width·2^(k−1) units (capped).
      max_width: cap on the hidden width of every g_k.
      depth: hidden layers of every g_k.
      gradient_cap: the paper objective's −log‖∇g‖ pushes only while ‖∇g‖ is below this (None:
        always, the paper). d_g is scale-free, so past it steepening g gains nothing on the data
        and saturates tanh off it.
      transversality_weight: β of eq. 2; None picks the objective's default (paper 1e3, ref. 1).
      syzygies_per_relation: rounds S of {fit f, push g_k} per relation in syzygy mode.
      syzygy_width: hidden width of the syzygy network f.
      syzygy_max_steps: cap on f's steps per round; None ⇒ max_steps // 2 (reference).
      syzygy_push_steps: g_k steps per push round; None ⇒ max_steps // syzygies_per_relation.
      transversal_first: in syzygy mode, the relations up to the data's codimension train
        with transversality (eq. 2, which implies restricted independence, Lemma 3.1) and cut
        the data; restricted syzygies from the next one on, each such relation kept only if a
        fresh syzygy network leaves it unexplained and more projected points land on the data
        with it. False: syzygies from g_2 on (the paper).
      syzygy_training: "rounds": the paper's alternation of {fit f, push g_k away from that
        frozen f}, `syzygies_per_relation` times. "joint": f fits alongside g_k, both on the
        residual relative to |g_k|, so g_k cannot escape f by rescaling (`syzygy.py`).
      syzygy_clip: in "joint" training, the push is bounded by this × the first term.
      separation_ratio: stop when mean |g| off-manifold > ratio × on-manifold (App. B.3.1: 5).
      separation_top_fraction: the on-manifold statistic is the mean of the largest fraction of
        |g| values (reference: 0.2, stricter than the paper's plain mean, which is 1.0).
      stop_patience: a relation is done once the stopping rule holds on ≥ 90% of recent steps
        (fresh batches each), averaged over about this many steps; 1 stops on the first batch
        that passes (the reference).
      min_angle: transversality mode also waits for the mean angle between ∇g_k and earlier
        gradients to exceed this (radians; reference 0.4·π/2).
      tolerance: `project` counts τ converged when every |g_k(τ)| < tolerance × its recorded
        on-manifold mean. The starting value only: `fit` calibrates it after each relation so
        that 99 % of training rows pass (`rs.tolerance`), and `holds`' distances beside it, one
        per relation (`rs.distance_tolerance`); `rs.replace(tolerance=t)` sets another.
      noise_scale: uniform noise, as a fraction of the data box, added to on and off rows.
      mined_weight: weight of jaml's mined-rows term (0 turns mining off: the paper's
        algorithm). From the data's codimension-th relation on, box points are projected onto
        the intersection; where they converge away from the data, g_k is refined not to vanish
        (a round kept only if more projected points then land on the data).
      mine_points: box points projected per mining round (and the capacity of the mined pool).
      refine_rounds: after g_k stops, at most this many rounds of {project onto
        {g_1 = … = g_k = 0}, mine the points landing away from the data, train g_k on}.
      premine: before the codimension-th relation trains (transversality), mine the earlier
        relations' zero set (box points projected onto it, kept where they land away from the
        data): g_k is trained from its first step not to vanish there. If it then separates
        less than `separation_ratio`, it is trained again without them.
      premine_clip: while g_k trains on pre-mined rows, their term is bounded by this × the
        first term (elsewhere 2×, like the paper's other terms).
      premine_steps: step budget of that pre-mined training (None ⇒ max_steps): its mined rows
        rarely all clear, so it usually runs to the budget; less is faster, at some landing.
      premine_attempts: trainings of the codimension-th relation (pre-mined where there is an
        earlier zero set) at most, each from another initialisation, while more than a tenth
        of the projected box points land away from the data (or it separates less than
        separation_ratio, or than half what an exact relation reaches on noisy rows); the one
        landing most is kept. Where none separates, the same starts train again with
        −log‖∇g‖ capped, then at a smaller step, before the relation is dropped. A relation
        below the codimension that ends capped separating less than that gets as many starts,
        then the same last resorts, and the one separating most is kept. Where every start of
        the codimension-th relation still lands more than a tenth away, the fit runs once more
        with the relations below the codimension from another start; the set landing more is
        kept. 1 turns all of these off.
      mined_patience: a training on mined rows ends once g_k separates and the share of
        mined rows it clears has not risen for this many steps (None: it runs until they clear
        or to its budget).
      codimension: D minus the data manifold's dimension; None estimates it by local PCA.
        Mining and refining start at the codimension-th relation (before it, the intersection
        is meant to be larger than the data).
      stop_when_complete: stop adding relations once (almost) no projected box point lands
        away from the data: the zero set is the data's, and its codimension is found.
      pretrain_steps: supervised steps towards a prior heuristic, when `fit` is given priors.
      chunk_steps: optimizer steps per compiled `lax.scan` call (logging / progress granularity).
      eval_batches: batches of fresh data used to record on/off means after each relation.
    """

    max_relations: int = 10
    independence: Independence = "transversality"
    objective: Objective = "paper"
    seed: int = 0
    batch_size: int = 1024
    learning_rate: float = 1e-3
    syzygy_learning_rate: float = 1e-4
    max_steps: int = 50_000
    base_width: int = 4
    max_width: int = 256
    depth: int = 3
    gradient_cap: float | None = None
    transversality_weight: float | None = None
    syzygies_per_relation: int = 3
    syzygy_width: int = 32
    syzygy_max_steps: int | None = None
    syzygy_push_steps: int | None = None
    syzygy_training: SyzygyTraining = "rounds"
    transversal_first: bool = True
    syzygy_clip: float = 20.0
    separation_ratio: float = 5.0
    separation_top_fraction: float = 0.2
    min_angle: float = 0.4 * math.pi / 2
    stop_patience: int = 250
    tolerance: float = 1.5
    noise_scale: float = 0.0
    mined_weight: float = 1.0
    mine_points: int = 512
    refine_rounds: int = 2
    premine: bool = True
    premine_clip: float = 20.0
    premine_steps: int | None = None
    premine_attempts: int = 3
    mined_patience: int | None = 4000
    codimension: int | None = None
    stop_when_complete: bool = True
    pretrain_steps: int = 2_000
    chunk_steps: int = 500
    eval_batches: int = 16

    def __post_init__(self):
        problems = []
        if self.independence not in INDEPENDENCE:
            problems.append(
                f"independence must be one of {INDEPENDENCE}, got {self.independence!r}"
            )
        if self.syzygy_training not in SYZYGY_TRAINING:
            problems.append(f"syzygy_training must be one of {SYZYGY_TRAINING}, got "
                            f"{self.syzygy_training!r}")
        if self.objective not in OBJECTIVES:
            problems.append(f"objective must be one of {OBJECTIVES}, got {self.objective!r}")
        positive_ints = (
            "max_relations",
            "batch_size",
            "max_steps",
            "base_width",
            "max_width",
            "depth",
            "syzygy_width",
            "chunk_steps",
            "eval_batches",
            "stop_patience",
            "mine_points",
            "premine_attempts",
        )
        for name in positive_ints:
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                problems.append(f"{name} must be a positive integer, got {value!r}")
        for name in ("syzygies_per_relation", "pretrain_steps", "seed", "refine_rounds"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                problems.append(f"{name} must be a non-negative integer, got {value!r}")
        for name in ("syzygy_max_steps", "syzygy_push_steps", "codimension", "premine_steps",
                     "mined_patience"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, int) or value < 1):
                problems.append(f"{name} must be None or a positive integer, got {value!r}")
        if isinstance(self.batch_size, int) and self.batch_size < 2:
            problems.append(f"batch_size must be at least 2, got {self.batch_size}")
        positive_floats = ("learning_rate", "syzygy_learning_rate", "separation_ratio", "tolerance",
                           "premine_clip", "syzygy_clip")
        for name in positive_floats:
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                problems.append(f"{name} must be a positive finite number, got {value!r}")
        if self.gradient_cap is not None and not (
                isinstance(self.gradient_cap, int | float) and math.isfinite(self.gradient_cap)
                and self.gradient_cap > 0):
            problems.append(f"gradient_cap must be None or a positive number, got "
                            f"{self.gradient_cap!r}")
        if self.transversality_weight is not None and not (
            math.isfinite(self.transversality_weight) and self.transversality_weight >= 0
        ):
            problems.append(f"transversality_weight must be ≥ 0, got {self.transversality_weight}")
        if not 0.0 < self.separation_top_fraction <= 1.0:
            problems.append(
                f"separation_top_fraction must lie in (0, 1], got {self.separation_top_fraction}"
            )
        if not 0.0 <= self.min_angle <= math.pi / 2:
            problems.append(f"min_angle must lie in [0, π/2], got {self.min_angle}")
        if not (isinstance(self.mined_weight, int | float) and math.isfinite(self.mined_weight)
                and self.mined_weight >= 0):
            problems.append(f"mined_weight must be ≥ 0, got {self.mined_weight!r}")
        if not (math.isfinite(self.noise_scale) and self.noise_scale >= 0):
            problems.append(f"noise_scale must be ≥ 0, got {self.noise_scale}")
        if (
            isinstance(self.max_width, int)
            and isinstance(self.base_width, int)
            and (self.max_width < self.base_width)
        ):
            problems.append(f"max_width ({self.max_width}) < base_width ({self.base_width})")
        if self.independence == "syzygy" and self.syzygies_per_relation < 1:
            problems.append("independence='syzygy' needs syzygies_per_relation ≥ 1")
        if problems:
            raise ValueError("invalid relations.Config: " + "; ".join(problems))

    @property
    def beta(self) -> float:
        """The transversality weight in use: the paper's 1e3 or the reference's 1."""
        if self.transversality_weight is not None:
            return self.transversality_weight
        return 1e3 if self.objective == "paper" else 1.0

    @property
    def syzygy_steps(self) -> int:
        return self.syzygy_max_steps or max(self.max_steps // 2, 1)

    @property
    def push_steps(self) -> int:
        return self.syzygy_push_steps or max(
            self.max_steps // max(self.syzygies_per_relation, 1), 1
        )

    def replace(self, **changes) -> Config:
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_record(cls, values: dict) -> Config:
        """A config as a run recorded it: fields added since read as what that run did, retired
        fields at their one remaining value dropped."""
        kept = {k: v for k, v in values.items()
                if not (k in RETIRED_FIELDS and v == RETIRED_FIELDS[k])}
        return cls.from_dict(LEGACY_FIELDS | kept)

    @classmethod
    def from_dict(cls, values: dict) -> Config:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"unknown relations.Config fields: {unknown}")
        return cls(**values)
