"""Paper Fig. 2: how well each learner's latents align with the true state, over training.

Every (env, variant) cell trains its seeds together (`jaml.stream.run.run_many`: one compiled
program, the seeds vmapped, split across the local GPUs) into OUT/ENV/VARIANT/seed_N, each run
resumable on its own. Then it writes OUT/fig2.md (final per-dimension errors on π_rand and
π_curr, with means per LD group — position, velocity, contacts, from the domains' metadata —
as the mean over seeds ± the half-width of its 90 % confidence interval), OUT/fig2.png (the
paper's layout: π_curr top row, π_rand bottom; pendulum position and velocity, HalfCheetah and
Ant aggregated over their groups; mean and 90 % band over seeds) and OUT/ENV_alignment.png (every
dimension, or every group for locomotion). fig2.md opens with the paper's findings measured
cell against cell (`fig2_claims`, Welch intervals, each marked for the side of 0 it falls on):
  (a) VAE_rpl aligns better than VAE_v0 on π_rand (the replay keeps early, diverse frames);
  (b) β-VAE is no better than VAE_rpl (β = 5 slightly worse, larger β much worse);
  (c) PRED and the sequential learners (SVAE, DSA) align velocities better than the VAEs, which
      see one frame; PRED is best on the pendulums;
  (d) on locomotion PRED beats VAE_rpl on π_curr and is second-best on π_rand.

    python -m jaml.experiments.fig2 --out runs/fig2                      # the whole grid
    python -m jaml.experiments.fig2 --out runs/fig2 --envs CartPole --variants PRED VAE_rpl
    python -m jaml.experiments.fig2 --out runs/fig2 --report-only        # figures from the runs
    python -m jaml.experiments.fig2 --out runs/fig2_bf16 --report-only --compare-with runs/fig2
        # each cell of one grid against the same cell of another (e.g. a numeric change)

Several GPUs: one process splits a cell's seeds across its local GPUs (3 + 3 on two). To run
different cells side by side instead, start one process per GPU on the same OUT (each run
directory is locked by the process that trains it; the report each process writes at its end
covers the runs finished by then, so rebuild it with --report-only when all are done):

    CUDA_VISIBLE_DEVICES=0 python -m jaml.experiments.fig2 --out runs/fig2 --envs Ant \\
        --variants PRED &
    CUDA_VISIBLE_DEVICES=1 python -m jaml.experiments.fig2 --out runs/fig2 --envs Ant \\
        --variants DSA &

Defaults are the paper's settings where they are sizes of one epoch (64 envs, a 5000-column
replay, 1024 frames per learner batch, 10 learner steps per epoch and 50 for locomotion, the
reference's regressor) and the shortest training the issue asked for: 1000 epochs on the
pendulums, 300 on locomotion (the paper trained tens of thousands). On a GPU the learners'
conv stacks run in bfloat16 by default (`LearnerConfig.compute_dtype`); the committed grid
(docs/results/fig2_runs) ran float32 with the encoder blind to the current action, so a cell
added to it takes `--learner-opt compute_dtype=float32 --learner-opt activation_dtype=float32
--learner-opt current_action=hidden`.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tyro

from jaml._options import key_values
from jaml._rundir import write_text
from jaml.configs.stream import SMOKE_CAVEAT, for_env, scaled
from jaml.experiments import _runs
from jaml.experiments._runs import cell
from jaml.experiments.fig2_grid import (
    ENVS,
    LOCOMOTION,
    PENDULUMS,
    SEEDS,
    grid_histories,
    group_value,
    ld_groups,
)

# jaml.evaluation (JAX, SciPy, Matplotlib) is imported by the functions that report: the
# command's --help imports none of them (tests/test_launch.py).

# label → (learner, learner config overrides). β = 5 was the paper's best β; β = 20 one of the
# values it found "significantly worse" (it tried 100, 20, 10, 5, 0.5).
VARIANTS = {
    "VAE_v0": ("VAE_v0", {}),
    "VAE_rpl": ("VAE_rpl", {}),
    "beta-VAE_5": ("beta-VAE", {"beta": 5.0}),
    "beta-VAE_20": ("beta-VAE", {"beta": 20.0}),
    "SVAE": ("SVAE", {}),
    "PRED": ("PRED", {}),
    "DSA": ("DSA", {}),
}
# (epochs, eval_every) per family.
SCHEDULE = {"pendulum": (1000, 100), "locomotion": (300, 50)}


def family(env: str) -> str:
    return "pendulum" if env in PENDULUMS else "locomotion"


def config_for(env: str, variant: str, seed: int, scale: dict, schedule: dict,
               learner_opt: dict | None = None, preset: str = "paper"):
    """The StreamConfig of one run of the grid; `preset` "smoke" replaces its sizes and
    schedule by `jaml.suite.SCALES["smoke"]`."""
    learner, overrides = VARIANTS[variant]
    epochs, eval_every = schedule[family(env)]
    return scaled(for_env(env, learner, {
        "seed": seed, "epochs": epochs, "eval.every": eval_every, **scale,
        **_runs.options("learner_config", {**overrides, **(learner_opt or {})})}), preset)


def run_cell(out: Path, env: str, variant: str, seeds, scale: dict, schedule: dict,
             learner_opt: dict | None = None, preset: str = "paper",
             **call_options) -> list[dict]:
    """Every seed of one (env, variant), trained together; returns their summaries.
    `call_options`: `_runs.CallOptions.run_options()` (stop_after, deadline, …)."""
    configs = [config_for(env, variant, s, scale, schedule, learner_opt, preset)
               for s in seeds]
    dirs = [out / env / variant / f"seed_{s}" for s in seeds]
    return _runs.train_seeds(f"{env} {variant}", configs, dirs, **call_options)


def final_records(history: list[dict], step: int) -> dict[str, dict]:
    """test set → the record of one run's analysis at `step`."""
    return {r["test_set"]: r for r in history if r["step"] == step}


def _final_rows(runs: dict[str, list[list[dict]]]):
    """(variant, test set, one record per seed, epoch) of each cell at the last epoch all its
    seeds reached: a seed that went further (an unfinished call) is read there too, so a row
    never mixes epochs."""
    for variant, histories in runs.items():
        last = _runs.last_common_step(histories)
        finals = [final_records(h, last) for h in histories]
        for test_set in finals[0]:
            yield variant, test_set, [f[test_set] for f in finals if test_set in f], last


def bounds_note(labels: set[str]) -> str:
    """The line under a domain's table saying what its bound rows (`reference_rows`) are."""
    ceiling = ("*constant* (the ceiling): a constant prediction's errors on each run's rows at "
               "its cell's last epoch")
    floor = ("*true state* (the floor): the regressor's errors with the true state as the "
             "latent, at each run's first analysis of its last call (summary.json)")
    if "true state" not in labels:
        floor = "the true state's errors (the floor): not recorded by these runs"
    return (f"{ceiling}; {floor}; over every run of the domain that recorded them, in each "
            "run's own units.")


def reference_rows(directory: Path, runs: dict[str, list[list[dict]]], names: list[str]):
    """(label, test set, [{dim: error}] one per run) of a domain's bounds: the constant
    predictor's errors (the ceiling) from each cell's records at its last common epoch, and
    the true state's (the floor) from each run's summary.json "references", where recorded."""
    ceiling, floor = {}, {}
    for _, test_set, per_seed, _ in _final_rows(runs):
        ceiling.setdefault(test_set, []).extend(r["baseline"] for r in per_seed
                                                if r.get("baseline"))
    for variant in runs:
        for test_set, rows in _runs.true_state_errors(directory / variant, names).items():
            floor.setdefault(test_set, []).extend(rows)
    return [(label, test_set, per_run) for label, rows in (("constant", ceiling),
                                                           ("true state", floor))
            for test_set, per_run in rows.items() if per_run]


def extra_options(variant: str, config: dict) -> dict:
    """The learner options a cell's runs were given beyond its variant's own (--learner-opt),
    e.g. {"compute_dtype": "bfloat16"}: shown beside the cell, since they change the experiment."""
    own = VARIANTS[variant][1]
    return {k: v for k, v in config.get("learner_overrides", {}).items() if own.get(k) != v}


def grid_status(out: Path, envs, variants, seeds: int = len(SEEDS)) -> list[str]:
    """Markdown lines: per cell, its seeds found under OUT and the epoch all of them reached,
    against the epochs their configs schedule: what a grid run over several sessions has left.
    A cell is complete with at least `seeds` seeds at their last epoch."""
    lines = ["| domain | " + " | ".join(variants) + " |", "|---" * (len(variants) + 1) + "|"]
    complete = 0
    for env in envs:
        row = []
        for variant in variants:
            directory = out / env / variant
            histories = _runs.seed_histories(directory)
            stopped = len(_runs.stopped_runs(directory))
            note = f" (+{stopped} stopped: non-finite loss)" if stopped else ""
            if not histories:
                row.append("—" + note)
                continue
            config = _runs.cell_config(directory)
            scheduled = config["epochs"]
            reached = _runs.last_common_step(histories)
            done = len(histories) >= seeds and reached == scheduled
            complete += done
            extra = extra_options(variant, config)
            row.append(f"{len(histories)} × {reached}"
                       + ("" if reached == scheduled else f" of {scheduled}")
                       + (" ✓" if done else "")
                       + (f" ({', '.join(f'{k}={v}' for k, v in extra.items())})"
                          if extra else "") + note)
        lines.append(f"| {env} | " + " | ".join(row) + " |")
    total = len(envs) * len(variants)
    return [f"Cells: seeds × the epoch they all reached; ✓ = {seeds} seeds at their last epoch; "
            "in brackets the learner options given beyond the variant's, and seeds stopped by a "
            "non-finite loss (not counted, not read). "
            f"{complete} of {total} complete.", "", *lines, ""]


# The y-axis of a locomotion panel: its values are fractions of each run's constant predictor's
# error (`group_value`), the scale on which the report compares cells.
OF_CONSTANT = "error / a constant's error"


def panels(env: str) -> dict[str, list[list[str]]]:
    """Fig. 2's panels of `env`: title → its groups' dims. A panel's value is the mean over its
    groups of each group's mean error (pendulums: position and velocity apart, in training-std
    units; locomotion: one panel over position, velocity and contacts, as the paper aggregates
    them, each group as a fraction of its run's constant predictor's error)."""
    groups = ld_groups(env)
    if env in PENDULUMS:
        return {f"{env} {g}": [dims] for g, dims in groups.items()}
    return {f"{env} (pos, vel, contacts)": list(groups.values())}


def panel_ylabels(envs) -> dict[str, str]:
    """Panel title → y-axis label for `plots.plot_alignment`: locomotion's are OF_CONSTANT."""
    return {title: OF_CONSTANT for env in envs if env in LOCOMOTION for title in panels(env)}


def has_baselines(histories: list[list[dict]]) -> bool:
    """Whether every record of every seed carries a constant predictor's errors (runs
    analysed before the analysis kept them do not): a locomotion cell is drawn only then, so
    that its curves come from all its seeds, as its rows in the tables do."""
    return all(r.get("baseline") for h in histories for r in h)


def figure_records(grid: dict[str, dict[str, list[list[dict]]]]) -> list[dict]:
    """History records of `grid` (env → `grid_histories`) re-keyed for the paper's layout:
    errors = {panel: value}, baseline = {panel: the constant predictor's value} where the
    record has one (`_panel_baseline`), learner = the variant's label, π_curr first (the top
    row).

    Locomotion panels read each group as a fraction of its run's constant predictor's error,
    as the report's tables and findings do: each run's raw errors are in units of its own
    replay's spread (`group_value`), so raw curves of two cells are not on one scale. A
    locomotion cell without baselines (`has_baselines`) is left out; the report names it."""
    records = []
    for env, runs in grid.items():
        relative = env in LOCOMOTION
        for variant, histories in runs.items():
            if relative and not has_baselines(histories):
                continue
            for h in histories:
                for r in h:
                    values = {title: float(np.mean([group_value(r, dims, relative)
                                                    for dims in groups]))
                              for title, groups in panels(env).items()}
                    record = {k: v for k, v in r.items() if k != "baseline"}
                    constants = {title: _panel_baseline(r, groups, relative)
                                 for title, groups in panels(env).items()}
                    if any(v is not None for v in constants.values()):
                        record["baseline"] = {t: v for t, v in constants.items() if v is not None}
                    records.append(record | {"errors": values, "learner": variant})
    return sorted(records, key=lambda r: r["test_set"] != "pi_curr")


def group_records(env: str, histories: dict[str, list[list[dict]]]) -> list[dict]:
    """A locomotion domain's records re-keyed for its per-group figure: errors = {group: its
    fraction of the run's constant predictor's error}, baseline = 1 for each group (the
    constant on its own scale), learner = the variant's label; cells without baselines
    (`has_baselines`) left out."""
    groups = ld_groups(env)
    return [r | {"errors": {g: group_value(r, dims, relative=True) for g, dims in groups.items()},
                 "baseline": dict.fromkeys(groups, 1.0), "learner": variant}
            for variant, hs in histories.items() if has_baselines(hs) for h in hs for r in h]


def _panel_baseline(record: dict, groups: list[list[str]], relative: bool) -> float | None:
    """A constant predictor's error on a panel's scale: 1 where the panel reads fractions of
    it, else the mean over the panel's groups of its mean over each group's dims; None where
    the record lacks one of them."""
    baseline = record.get("baseline") or {}
    if not all(d in baseline for dims in groups for d in dims):
        return None
    if relative:
        return 1.0
    return float(np.mean([np.mean([baseline[d] for d in dims]) for dims in groups]))


def report(out: Path, envs, variants) -> str:
    """fig2.md and the figures from every run under OUT; returns the markdown."""
    from jaml.evaluation import plots
    from jaml.experiments import fig2_claims

    lines = ["# Fig. 2: alignment error (lower is better)", "",
             "Pendulums in training-std units; HalfCheetah and Ant's figures as fractions of "
             "each run's constant predictor's error (their first tables raw, their second as "
             "fractions).", "",
             *grid_status(out, envs, variants),
             *fig2_claims.claims_table(out, envs, variants),
             "Several seeds: mean ± the half-width of its 90 % confidence interval, at the last",
             "epoch all of a cell's seeds reached.", ""]
    grid = {env: grid_histories(out, env, variants) for env in envs}
    smoke = False
    for env, runs in grid.items():
        if not runs:
            continue
        names = list(next(iter(runs.values()))[0][0]["errors"])
        config_path = next((out / env / next(iter(runs))).glob("seed_*/config.json"))
        config = _runs.settings(json.loads(config_path.read_text()))
        smoke |= _runs.scale_of(config) == "smoke"
        settings = {k: config.get(k) for k in (*_runs.SIZES, "epochs", "eval_every",
                                               "learner_steps", "frames_per_batch")}
        groups = ld_groups(env)
        show = names if len(names) <= 8 else []  # locomotion: group means only
        lines += [f"## {env}", "", f"Settings: {json.dumps(settings)}", "",
                  "| variant | test set | " + " | ".join([*show, *(f"{g} mean" for g in groups)])
                  + " | epoch | seeds |",
                  "|---" * (len(show) + len(groups) + 4) + "|"]
        for variant, test_set, per_seed, last in _final_rows(runs):
            dims = [[r["errors"][n] for r in per_seed] for n in show]
            means = [[group_value(r, dims_of) for r in per_seed] for dims_of in groups.values()]
            lines.append(f"| {variant} | {test_set} | "
                         + " | ".join(cell(v) for v in (*dims, *means))
                         + f" | {last} | {len(per_seed)} |")
        bounds = reference_rows(out / env, runs, names)
        for label, test_set, per_run in bounds:
            dims = [[v[n] for v in per_run] for n in show]
            means = [[float(np.mean([v[d] for d in dims_of])) for v in per_run]
                     for dims_of in groups.values()]
            lines.append(f"| *{label}* | {test_set} | "
                         + " | ".join(cell(v) for v in (*dims, *means))
                         + f" | — | {len(per_run)} |")
        if bounds:
            lines += ["", bounds_note({label for label, _, _ in bounds})]
        lines += ["", *_relative_table(env, groups, runs), ""]
        if env in LOCOMOTION:  # per group, on the tables' scale (fractions of the constant)
            left_out = [v for v, hs in runs.items() if not has_baselines(hs)]
            if left_out:
                lines += [f"Not in the {env} figures (records without a constant predictor's "
                          f"errors): {', '.join(left_out)}.", ""]
            by_group = group_records(env, runs)
            if by_group:
                plots.plot_alignment(by_group, out / f"{env}_alignment.png",
                                     ylabels=dict.fromkeys(groups, OF_CONSTANT))
            else:  # no stale figure of an earlier report in other units
                (out / f"{env}_alignment.png").unlink(missing_ok=True)
        else:  # every LD dimension, training-std units
            plots.plot_alignment(
                [r | {"learner": v} for v, hs in runs.items() for h in hs for r in h],
                out / f"{env}_alignment.png")
    if smoke:  # --scale smoke: said first, as the suite's smoke runs say it
        lines[2:2] = [f"Note: {SMOKE_CAVEAT}.", ""]
    records = figure_records(grid)
    if records:
        plots.plot_alignment(records, out / "fig2.png", ylabels=panel_ylabels(envs))
        lines += ["![Fig. 2](fig2.png)", ""]
    else:
        (out / "fig2.png").unlink(missing_ok=True)
    text = "\n".join(lines) + "\n"
    write_text(out / "fig2.md", text)
    return text


def _relative_table(env: str, groups: dict[str, list[str]],
                    runs: dict[str, list[list[dict]]]) -> list[str]:
    """Markdown lines: each cell's group means at its last common epoch as fractions of a
    constant predictor's error (`group_value`), mean ± 90 % half-width over seeds; "—" for cells
    recorded without baselines."""
    lines = [f"{env}, group means as a fraction of a constant predictor's error (1 = the "
             "latents tell the regressor nothing):", "",
             "| variant | test set | " + " | ".join(groups) + " | epoch | seeds |",
             "|---" * (len(groups) + 4) + "|"]
    for variant, test_set, per_seed, last in _final_rows(runs):
        values = [[group_value(r, dims, relative=True) for r in per_seed]
                  for dims in groups.values()]
        lines.append(f"| {variant} | {test_set} | "
                     + " | ".join("—" if None in v else cell(v) for v in values)
                     + f" | {last} | {len(per_seed)} |")
    return lines


def _group_means(env: str, histories: list[list[dict]],
                 relative: bool = False) -> dict[tuple, list[float]]:
    """(step, test set, group) → one value per seed: the seed's mean error over the group (or
    its fraction of a constant predictor's, `group_value`)."""
    groups = ld_groups(env)
    values: dict[tuple, list[float]] = {}
    for history in histories:
        for r in history:
            for group, dims in groups.items():
                value = group_value(r, dims, relative)
                if value is not None:
                    values.setdefault((r["step"], r["test_set"], group), []).append(value)
    return values


def compare(out: Path, other: Path, envs, variants, relative: bool = False) -> str:
    """Markdown: every (env, variant) cell under both OUT and OTHER, group means of OUT minus
    OTHER with Welch's 90 % interval at their last common analysis, at how many of their
    common analyses that interval excludes 0 (a difference the seeds resolve), and one interval
    for the later half of training: each seed's mean over the common analyses after half the
    last one's epoch (a seed that is low at one analysis is low at the next, so the count's
    resolutions come in runs; this is one test a row). `relative`: each group mean as a
    fraction of its run's constant predictor's (`group_value`), where the two grids' runs have
    different streams and so different units."""
    from jaml.evaluation import intervals

    units = ("as a fraction of each run's constant predictor's error" if relative
             else "training-std units")
    lines = [f"## {out.name} − {other.name}, cell by cell ({units})", "",
             f"Group means ({units}) over the seeds of each grid; Welch's 90 % "
             "interval for the difference; `resolved`: analyses (of those both have) whose "
             "interval excludes 0; `later half`: each seed's mean over the analyses (of those "
             "both have) after half the last one's epoch, the difference and its Welch 90 % "
             "interval over seeds.", "",
             f"| cell | test set | group | epoch | {out.name} | {other.name} | difference "
             "[90 % interval] | resolved | later half [90 % interval] |", "|---" * 9 + "|"]
    unscored = []  # cells in both grids with no analysis every seed of both can be read at
    for env in envs:
        mine, theirs = grid_histories(out, env, variants), grid_histories(other, env, variants)
        for variant in (v for v in variants if v in mine and v in theirs):
            a = _group_means(env, mine[variant], relative)
            b = _group_means(env, theirs[variant], relative)
            common = sorted(k for k in a if k in b and len(a[k]) == len(mine[variant])
                            and len(b[k]) == len(theirs[variant]))
            if not common:
                unscored.append(f"{env} · {variant}")
                continue
            last = max(k[0] for k in common)
            for key in (k for k in common if k[0] == last):
                diff, low, high = intervals.welch_interval(a[key], b[key])
                same = [k for k in common if k[1:] == key[1:]]
                resolved = sum(not (lo <= 0 <= hi) for _, lo, hi in
                               (intervals.welch_interval(a[k], b[k]) for k in same))
                # Each seed has every common analysis once, in the grid's order: lists align.
                later = [k for k in same if 2 * k[0] > last or k[0] == last]
                late, late_low, late_high = intervals.welch_interval(
                    np.mean([a[k] for k in later], axis=0), np.mean([b[k] for k in later], axis=0))
                lines.append(f"| {env} · {variant} | {key[1]} | {key[2]} | {last} | "
                             f"{np.mean(a[key]):.3f} | {np.mean(b[key]):.3f} | "
                             f"{diff:+.3f} [{low:+.3f}, {high:+.3f}] | {resolved} of {len(same)} | "
                             f"{late:+.3f} [{late_low:+.3f}, {late_high:+.3f}] |")
    if unscored:
        why = " (runs recorded without baselines)" if relative else ""
        lines += ["", f"In both grids but not compared{why}: {', '.join(unscored)}."]
    return "\n".join(lines) + "\n"


@dataclasses.dataclass(frozen=True)
class Args(_runs.Driver):
    """Paper Fig. 2: every (env, variant) cell trains its seeds together into OUT/ENV/VARIANT/
    seed_N (each resumable), then OUT/fig2.md and the figures are written from the runs."""

    out: Path
    """the grid's directory"""
    envs: tuple[Literal[ENVS], ...] = ENVS
    """domains of the grid"""
    variants: tuple[Literal[tuple(VARIANTS)], ...] = tuple(VARIANTS)
    """learner variants (β-VAE at β 5 and 20)"""
    seeds: tuple[int, ...] = SEEDS
    """seeds of each cell, trained together"""
    learner_opt: Annotated[tuple[str, ...], tyro.conf.UseAppendAction,
                           tyro.conf.arg(metavar="KEY=VALUE")] = ()
    """a learner config field for every run (repeatable), e.g. frame_nll=mean (the reference
    code's likelihood)"""
    sizes: Annotated[_runs.Sizes, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=_runs.Sizes)
    pendulum_epochs: int = SCHEDULE["pendulum"][0]
    """epochs of CartPole and InvertedPendulum runs"""
    pendulum_eval_every: int = SCHEDULE["pendulum"][1]
    """epochs between their analyses"""
    locomotion_epochs: int = SCHEDULE["locomotion"][0]
    """epochs of HalfCheetah and Ant runs"""
    locomotion_eval_every: int = SCHEDULE["locomotion"][1]
    """epochs between their analyses"""
    call: Annotated[_runs.CallOptions, tyro.conf.arg(name="")] = dataclasses.field(
        default_factory=_runs.CallOptions)
    scale: Literal["paper", "smoke"] = "paper"
    """"smoke": every run at `jaml.suite.SCALES["smoke"]` (4 epochs, small sets: minutes on a
    CPU), replacing the size and schedule flags"""
    report_only: bool = False
    """no training: fig2.md and the figures from the runs under OUT"""
    compare_with: Annotated[tuple[Path, ...], tyro.conf.UseAppendAction] = ()
    """another grid's directory (repeatable): the report ends with each cell's difference from
    the same cell there (OUT − OTHER, Welch's 90 % interval), also written to OUT/compare.md"""

    def train(self) -> None:
        scale = self.sizes.under(self.scale)
        schedule = {f: (getattr(self, f"{f}_epochs"), getattr(self, f"{f}_eval_every"))
                    for f in SCHEDULE}
        for env in self.envs:
            for variant in self.variants:
                run_cell(self.out, env, variant, self.seeds, scale, schedule,
                         key_values(self.learner_opt), self.scale,
                         **self.call.run_options())

    def report(self) -> str:
        for other in self.compare_with:
            if not other.is_dir():
                raise FileNotFoundError(f"--compare-with {other}: no such grid directory")
        text = report(self.out, self.envs, self.variants)
        if not self.compare_with:
            return text
        table = "\n".join(compare(self.out, other, self.envs, self.variants, relative)
                          for other in self.compare_with for relative in (False, True))
        write_text(self.out / "compare.md", table)
        return text + "\n" + table


def main(argv=None) -> int:
    """`python -m jaml.experiments.fig2 ARGS` is `jaml fig2 ARGS`."""
    # This module's importable copy (run as a script, this one is __main__, whose classes
    # the command line's help rule does not read as jaml's): as `jaml fig2` has it.
    from jaml.experiments import fig2

    return _runs.main("fig2", fig2.Args, argv)


if __name__ == "__main__":
    sys.exit(main())
