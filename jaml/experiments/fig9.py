"""Paper Fig. 9: relations learned on Geom-on-incline imposed on PRED trained on MeshOnIncline.

The sim-to-sim transfer of paper §5, under one of two recipes (`RECIPES`, docs/transfer.md):
"reference", the released code's mechanism (docs/reference/fig9.md), and "ours", the paper's loss
with our earlier choices. Steps, each resumable in OUT:
  1. OUT/relations/{trnsv,syz}: AML relations on "geom-on-incline" LD transitions
     τ = (theta, s0, v0, a0, s1, v1), with transversality (AML_trnsv) and with restricted
     syzygies (AML_syz) (`jaml.relations.run`).
  2. "ours" with several weights: OUT/pilot/w<weight>, one PRED+AML_trnsv run per weight on a
     pilot seed that is not reported; the weight with the lowest held-out *replay* error of the
     object's position is kept (OUT/choice.json). "reference" has its weight.
  3. OUT/<method>/seed_N: the learning loop on MeshOnIncline's PPO frame stream (`jaml.stream`)
     for every method of `METHODS` and seed. The learner never feeds back into PPO, so every
     method's seed N sees the same stream, and methods are compared seed by seed (paired).
  4. OUT/fig9.md and OUT/fig9.png (`fig9_report`).

    python -m jaml.experiments.fig9 --out runs/fig9 --recipe reference --methods PRED
    python -m jaml.experiments.fig9 --out runs/fig9 --recipe reference --report-only

Methods share nothing but the relations (and the chosen weight), so they run as parallel
processes, one or two per GPU; `--stop-after` splits a run over calls.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Annotated, Literal

import tyro

from jaml._rundir import write_json
from jaml.configs.relations import Config
from jaml.configs.stream import SCALES, PenaltyConfig, for_env
from jaml.experiments import _runs
from jaml.experiments._runs import read_jsonl

SOURCE, TARGET = "geom-on-incline", "MeshOnIncline"
# The objects' mass and friction, in the source's rows and in the target's envs alike.
# "drawn": the domains' defaults, drawn per reset (mass ~U(0.05, 0.5) kg, friction ~U(0.1, 0.5));
# neither is in τ, so the only relation the rows hold exactly is kinematic (s1 − s0 ≈
# dt·(v0 + v1)/2, docs/relations.md). "fixed": one mass and friction for every reset in both
# domains, so the rows also hold the dynamics relation. The paper draws friction per reset.
DYNAMICS = {
    "drawn": {},
    "fixed": {"mass_range": [0.2, 0.2], "friction_range": [0.3, 0.3]},
}
# name → (learner, relation set or None, control or None). A control imposes no penalty
# (weight 0) and keeps the reference code's extra reconstruction term on "ok" rows: the rows the
# AML_trnsv relations accept ("relations"), as many rows per batch drawn at random ("random"), or
# a fixed share of random rows ("random@p": 5 %, the PRED+AML_trnsv arm's share of ok rows,
# docs/results/fig9.md; provenance in docs/notes/experiments.md).
METHODS = {
    "PRED+AML_trnsv": ("PRED", "trnsv", None),
    "PRED+AML_syz": ("PRED", "syz", None),
    "PRED": ("PRED", None, None),
    "PRED+ok_rows": ("PRED", "trnsv", "relations"),
    "PRED+random_rows": ("PRED", "trnsv", "random"),
    "PRED+random_rows_5pct": ("PRED", "trnsv", "random@0.05"),
    "VAE_rpl": ("VAE_rpl", None, None),
    "PRED+beta_1of11": ("PRED", None, None),
}
# Learner options a method sets over the recipe's. PRED+beta_1of11 tests what the random-row
# control does: over random rows, the released 10 × NLL term adds 10 × the batch's mean NLL in
# expectation, so the control's loss is about 11 · NLL + KL, which Adam (invariant to the loss's
# scale) follows as NLL + KL / 11.
METHOD_OPTIONS = {"PRED+beta_1of11": {"beta": 1 / 11}}
PILOT = "PRED+AML_trnsv"  # the method whose pilot runs choose the weight ("ours")
# Where the relations' coordinates sit in PRED's per-step latent, placed on the slots the learner
# declares (`LearnerConfig.penalty_slots`): θ on the last static entry (the reference's θ̃), s and
# v on the dynamic entries; the action between the steps is the env's action.
COORDINATES = dict(static=("theta",), dynamic=("s", "v"))
# Relations: 3 per set as in the paper's block-on-incline figures, with budgets cut to fit the
# experiment's time (the stopping rule usually ends a relation well before them).
# Pinned to the algorithm the committed relation sets were learned with (no mining or
# refinement, all three relations trained): `jaml.configs.relations.LEGACY_FIELDS`.
_LEGACY = dict(mined_weight=0.0, refine_rounds=0, stop_when_complete=False, premine=False,
               transversal_first=False)
RELATIONS = {
    "trnsv": dict(max_relations=3, independence="transversality", max_steps=20_000, **_LEGACY),
    "syz": dict(max_relations=3, independence="syzygy", max_steps=20_000,
                syzygies_per_relation=2, syzygy_max_steps=4_000, syzygy_push_steps=4_000,
                **_LEGACY),
}
# --scale smoke: each relation a few hundred steps on a small pool, to check the pipeline.
SMOKE_RELATIONS = dict(max_relations=2, max_steps=300, pretrain_steps=100, chunk_steps=100,
                       batch_size=256, stop_patience=50, eval_batches=2, syzygy_max_steps=100,
                       syzygy_push_steps=100)
SMOKE_SOURCE = dict(pool_size=4096)
_STEPS = 2  # PRED on the incline decodes hist + pred = 2 frames


@dataclasses.dataclass(frozen=True)
class Recipe:
    """How the runs impose relations, and their learners and scale (docs/transfer.md).

    learner_options: learner config fields for every learner; pred_options: PRED's own on top.
    weights: the penalty weight, or the pilot's candidates. ok_weight: the extra NLL term on
    ok rows. all_relations: impose every relation, or only those that met the stopping rule.
    """

    name: str
    learner_options: dict
    pred_options: dict
    weights: tuple[float, ...]
    ok_weight: float
    all_relations: bool
    scale: dict


# "reference": the released code (docs/reference/fig9.md §2–3), in its float32 (the learners' GPU
# default is bfloat16, `LearnerConfig.compute_dtype`). Its loss averages the likelihood and
# the KL over the S = 2 decoded steps; ours sums them, S times the reference's loss. Adam does
# not see a loss's scale, so its 1e3 × hinge and 10 × (mean NLL of ok rows, per frame) are, in
# our units, S·1e3 × hinge and 10 × (mean NLL of ok rows, summed over frames).
RECIPES = {
    "ours": Recipe(
        "ours", {"current_action": "hidden"}, {}, (100.0, 1000.0, 10_000.0), 0.0, False,
        {"num_envs": 64, "replay.slots": 1024, "epochs": 316, "eval.every": 150,
         "eval.train": 4096, "eval.rand": 4096, "eval.curr": 1024,
         "eval.regressor_iterations": 4000}),
    "reference": Recipe(
        "reference",
        {"current_action": "observed", "kl_form": "reference", "compute_dtype": "float32",
         "activation_dtype": "float32",
         "conv_filters": (32, 64, 64, 128), "deconv_filters": (128, 64, 64, 32)},
        {"static_per_step": True}, (1e3 * _STEPS,), 10.0, True,
        # The reference's replay (5,000 → 4,992 columns at 64 envs) and regressor sizes (§6);
        # 2,000 learner epochs after the 78 that fill the replay.
        {"num_envs": 64, "replay.slots": None, "epochs": 2078, "eval.every": 200,
         "eval.train": 10_000, "eval.rand": 10_048, "eval.curr": 1024,
         "eval.regressor_iterations": 10_000}),
}


# How the runs impose relations: the weight and the ok-row term, filled per method with the
# relation set (`penalty_for`) into each run's config (`StreamConfig.penalty`).
Penalty = PenaltyConfig


def learn_relations(out: Path, progress: bool = False, dynamics: str = "drawn",
                    units: str = "env", smoke: bool = False, sets=tuple(RELATIONS)) -> dict:
    """OUT/relations/<set> for each of `sets` (`RELATIONS`): fitted (or resumed) relation sets
    on the source's rows with `dynamics` (`DYNAMICS`), in the source's `units`
    (`sources.incline_env.UNITS`); `smoke`: `SMOKE_RELATIONS` on a `SMOKE_SOURCE` pool.
    name → summary."""
    from jaml import relations
    from jaml.relations.run import run

    summaries = {}
    source = (_dynamics(dynamics) | ({"units": units} if units != "env" else {})
              | (SMOKE_SOURCE if smoke else {}))
    for name in sets:
        started = time.perf_counter()
        cfg = relations.Config(**RELATIONS[name] | (SMOKE_RELATIONS if smoke else {}))
        directory = out / "relations" / name
        finished = _finished(directory, cfg, source)
        summaries[name] = finished or run(SOURCE, cfg, directory, source_options=source or None,
                                          progress=progress)
        print(f"relations {name}: {summaries[name]['num_relations']} in "
              f"{time.perf_counter() - started:.0f}s", flush=True)
    return summaries


def _finished(directory: Path, cfg, source_options: dict) -> dict | None:
    """A relation set's summary when it finished with this config (the methods' processes then
    skip `relations.run`, which would draw the source's pool again to resume)."""
    summary, config = directory / "summary.json", directory / "config.json"
    if not (summary.exists() and config.exists()):
        return None
    expected = {"source": SOURCE}
    if source_options:
        expected["source_options"] = source_options
    done = json.loads(summary.read_text())
    recorded = json.loads(config.read_text())
    relations_cfg = recorded.pop("relations", {})
    if done["status"] in ("running", "interrupted") or recorded != json.loads(
            json.dumps(expected)) or Config.from_record(relations_cfg) != cfg:
        return None
    return done


def converged(out: Path, relation_set: str) -> list[int]:
    """0-based indices of the relations that met the stopping rule ("done")."""
    summary = json.loads((out / "relations" / relation_set / "summary.json").read_text())
    used = [r["index"] - 1 for r in summary["relations"] if r["status"] == "done"]
    if not used:
        raise ValueError(f"no relation of {relation_set} converged; nothing to impose")
    return used


def penalty_for(out: Path, relation_set: str, penalty: Penalty, recipe: Recipe) -> Penalty:
    """`penalty` imposing a relation set on the incline PRED: its checkpoint under OUT, the
    relations the recipe imposes (all, or the converged ones), on the latent slots
    `COORDINATES` names."""
    from jaml import relations

    checkpoint = out / "relations" / relation_set / "checkpoint"
    used = (range(relations.load(checkpoint).num_relations) if recipe.all_relations
            else converged(out, relation_set))
    return dataclasses.replace(penalty, relations=str(checkpoint), used=tuple(used),
                               **COORDINATES)


def _dynamics(dynamics: str) -> dict:
    """The env (and source) overrides of a `DYNAMICS` name, as lists: what a run's JSON config
    reads back, so a resumed run's recorded options compare equal."""
    if dynamics not in DYNAMICS:
        raise ValueError(f"dynamics must be one of {sorted(DYNAMICS)}, got {dynamics!r}")
    return {k: list(v) for k, v in DYNAMICS[dynamics].items()}


def _config(learner: str, seed: int, recipe: Recipe, dynamics: str = "drawn",
            scale: dict | None = None, method: str | None = None):
    options = dict(recipe.learner_options)
    if learner == "PRED":
        options |= recipe.pred_options
    options |= METHOD_OPTIONS.get(method, {})
    return for_env(TARGET, learner, {
        "seed": seed, **_runs.options("env_config", _dynamics(dynamics)),
        **_runs.options("learner_config", options), **(scale or recipe.scale)})


def _write_json(path: Path, value) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, value)


def method_penalty(method: str, penalty: Penalty) -> Penalty:
    """The penalty a method imposes: the recipe's, or a control's (weight 0, its ok rows)."""
    control = METHODS[method][2]
    if control is None:
        return penalty
    rows, _, share = control.partition("@")
    return dataclasses.replace(penalty, weight=0.0, ok_rows=rows,
                               ok_fraction=float(share) if share else None)


def run_method(out: Path, method: str, seeds, penalty: Penalty, recipe: Recipe, *,
               run_dir=None, dynamics: str = "drawn", scale: dict | None = None,
               **call_options) -> None:
    """Every seed of one method, trained together (`run_many`: one program, seeds stacked),
    its penalty in each run's config (config.json's "penalty").
    `call_options`: `_runs.CallOptions.run_options()` (stop_after, deadline, …)."""
    learner, relation_set, _ = METHODS[method]
    imposed = (None if relation_set is None
               else penalty_for(out, relation_set, method_penalty(method, penalty), recipe))
    directories = [(run_dir or out / method) / f"seed_{seed}" for seed in seeds]
    configs = [_config(learner, seed, recipe, dynamics, scale, method).replace(penalty=imposed)
               for seed in seeds]
    _runs.train_seeds(method, configs, directories, **call_options)


def choose_weight(out: Path, weights, pilot_seed: int, form: str, recipe: Recipe,
                  dynamics: str = "drawn", scale: dict | None = None) -> Penalty:
    """The weight with the lowest held-out replay error of the object's position (pilot runs of
    PRED+AML_trnsv); the choice is written to OUT/choice.json and reused on resume."""
    choice_path = out / "choice.json"
    base = Penalty(weights[0], form, recipe.ok_weight)
    if choice_path.exists():
        recorded = json.loads(choice_path.read_text())
        if sorted(recorded["weights"]) == sorted(weights) and recorded["form"] == form:
            return dataclasses.replace(base, weight=recorded["weight"])
    scores = {}
    for w in weights:
        directory = out / "pilot" / f"w{w:g}"
        run_method(out, PILOT, [pilot_seed], dataclasses.replace(base, weight=w),
                   recipe, run_dir=directory, dynamics=dynamics, scale=scale)
        history = read_jsonl(directory / f"seed_{pilot_seed}" / "history.jsonl")
        last = max(r["step"] for r in history)
        scores[w] = next(r["validation"]["position"] for r in history if r["step"] == last)
    best = min(scores, key=scores.get)
    _write_json(choice_path, {"weights": list(weights), "form": form, "pilot_seed": pilot_seed,
                              "validation_position_error": {f"{w:g}": v
                                                            for w, v in scores.items()},
                              "weight": best})
    return dataclasses.replace(base, weight=best)


@dataclasses.dataclass(frozen=True)
class Args(_runs.Driver):
    """Paper Fig. 9: relations learned on geom-on-incline imposed on PRED trained on
    MeshOnIncline; relations, the weight, every method's seeds, then OUT/fig9.md and
    OUT/fig9.png (each step resumable in OUT)."""

    out: Path
    """the experiment's directory"""
    recipe: Literal[tuple(RECIPES)] = "reference"
    """reference: the released code's mechanism and scale; ours: the paper's loss with the
    earlier choices (hidden current action, shared static latent, weight by pilot)"""
    methods: tuple[Literal[tuple(METHODS)], ...] = tuple(METHODS)
    """methods to train (they share only the relations and the weight)"""
    seeds: tuple[int, ...] = tuple(range(6))
    """seeds of each method, trained together; a seed's stream is the same for every method"""
    weights: tuple[float, ...] = ()
    """penalty weight, or several for a pilot to choose from (default: the recipe's)"""
    form: Literal["hinge", "sum"] = "hinge"
    """hinge: the reference's mean_k |g_k| above its on-manifold mean; sum: the paper's
    Σ_k |g_k|"""
    pilot_seed: int = 100
    """seed of the pilot runs (not reported)"""
    dynamics: Literal[tuple(DYNAMICS)] = "drawn"
    """the objects' mass and friction in the source and the target: drawn per reset (the
    domains' defaults, the paper's) or fixed (0.2 kg, 0.3)"""
    source_units: Literal["env", "reference"] = "env"
    """units of the source's rows the relations learn from: the env's normalised LD state, or
    the released code's (distance from the episode's start, unsigned speed, force in N)"""
    report_only: bool = False
    """no training: fig9.md and fig9.png from the runs under OUT"""
    pilot_only: bool = False
    """learn the relations (and choose the weight), then stop"""
    epochs: int | None = None
    """epochs of every run (default: the recipe's)"""
    eval_every: int | None = None
    """epochs between analyses (default: the recipe's)"""
    scale: Literal["recipe", "smoke"] = "recipe"
    """smoke: a few epochs on tiny sets, to check the pipeline end to end"""
    call: Annotated[_runs.CallOptions, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=_runs.CallOptions)

    def _scale(self) -> dict:
        scale = dict(RECIPES[self.recipe].scale)
        if self.scale == "smoke":  # the suite's smoke sizes, batches and learner steps too
            scale |= SCALES["smoke"]
        return scale | {k: v for k, v in (("epochs", self.epochs),
                                          ("eval.every", self.eval_every)) if v is not None}

    def train(self) -> bool:
        recipe = RECIPES[self.recipe]
        weights = self.weights or recipe.weights
        penalty = Penalty(weights[0], self.form, recipe.ok_weight)
        sets = {METHODS[m][1] for m in self.methods} - {None}
        if sets and len(weights) > 1:
            sets.add(METHODS[PILOT][1])
        if self.pilot_only or sets:
            learn_relations(self.out, dynamics=self.dynamics, units=self.source_units,
                            smoke=self.scale == "smoke",
                            sets=tuple(RELATIONS) if self.pilot_only else sorted(sets))
            if len(weights) > 1:
                penalty = choose_weight(self.out, weights, self.pilot_seed, self.form, recipe,
                                        self.dynamics, self._scale())
            print(f"penalty: weight {penalty.weight:g}, form {penalty.form}, ok_weight "
                  f"{penalty.ok_weight:g}", flush=True)
        if self.pilot_only:
            return False
        for method in self.methods:
            run_method(self.out, method, self.seeds, penalty, recipe, dynamics=self.dynamics,
                       scale=self._scale(), **self.call.run_options())
        return True

    def report(self) -> str:
        from jaml.experiments import fig9_report

        return fig9_report.report(self.out, self.methods)


def main(argv=None) -> int:
    """`python -m jaml.experiments.fig9 ARGS` is `jaml fig9 ARGS`."""
    # This module's importable copy (run as a script, this one is __main__, whose classes
    # the command line's help rule does not read as jaml's): as `jaml fig9` has it.
    from jaml.experiments import fig9

    return _runs.main("fig9", fig9.Args, argv)


if __name__ == "__main__":
    sys.exit(main())
