"""The paper's Fig. 2 findings as comparisons between cells of a grid, measured from its records.

Each finding of the paper's text (§3, "Benchmarking alignment") is written as checks on the
cells' group means: `Comparison`s, A − B on the side of 0 the paper's words put it, and
`Place`s, where a learner ranks among the cells run ("PRED performed best", "second-best").
`claims_table` measures each at the last analysis the cells' seeds share, with Welch's 90 %
interval over seeds, and marks it ✓ (resolved on the paper's side), ✗ (resolved against it) or
~ (not resolved).

Readings: the pendulums in the regressor's training-std units, as the paper plots them;
locomotion's panel (the mean of its position, velocity and contact groups) and groups as
fractions of each run's constant predictor's error (`fig2_grid.group_value`), since each run's units
come from its own replay and a mean over groups of different scales needs a common one.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaml.evaluation import intervals
from jaml.experiments import _runs
from jaml.experiments.fig2_grid import (
    LOCOMOTION,
    PENDULUMS,
    SEEDS,
    grid_histories,
    group_value,
    ld_groups,
)

BOTH = ("pi_rand", "pi_curr")
# The group the paper plots for a domain: position on the pendulums, the panel on locomotion.
PLOTTED = "plotted"


@dataclasses.dataclass(frozen=True)
class Comparison:
    """A − B of the group means on `test`, which the paper puts on the side of `sign` (+1: A's
    error is higher, −1: lower)."""

    a: str
    b: str
    test: str
    group: str
    sign: int

    def label(self) -> str:
        return f"{self.a} − {self.b}, {self.test}, {_group_label(self.group)}"


@dataclasses.dataclass(frozen=True)
class Place:
    """`variant` at `place` (1: the lowest error) among the cells run, by mean group error."""

    variant: str
    test: str
    group: str
    place: int

    def label(self) -> str:
        return f"{self.variant}'s place, {self.test}, {_group_label(self.group)}"


@dataclasses.dataclass(frozen=True)
class Claim:
    text: str
    checks: tuple[Comparison | Place, ...]
    envs: tuple[str, ...]


SEQUENCE = ("SVAE", "PRED", "DSA")
CLAIMS = (
    Claim("VAE_v0 performs poorly on π_rand; replaying frames of the initial random policy "
          "(VAE_rpl) alleviates it", (Comparison("VAE_v0", "VAE_rpl", "pi_rand", PLOTTED, +1),),
          PENDULUMS + LOCOMOTION),
    Claim("β-VAE offers no improvement over VAE_rpl; the best β (5) is slightly worse on the "
          "pendulums (~ is also no improvement)",
          tuple(Comparison("beta-VAE_5", "VAE_rpl", t, PLOTTED, +1) for t in BOTH),
          PENDULUMS + LOCOMOTION),
    Claim("the other β (here 20) do significantly worse",
          tuple(Comparison("beta-VAE_20", "VAE_rpl", t, PLOTTED, +1) for t in BOTH),
          PENDULUMS + LOCOMOTION),
    Claim("the sequential approaches SVAE, PRED, DSA offer significant gains for velocity",
          tuple(Comparison(s, "VAE_rpl", t, "velocity", -1) for s in SEQUENCE for t in BOTH),
          PENDULUMS + LOCOMOTION),
    Claim("PRED performs best on the pendulum domains",
          tuple(Place("PRED", t, g, 1) for t in BOTH for g in ("position", "velocity")),
          PENDULUMS),
    Claim("locomotion, aggregated over position, velocity and contacts: PRED outperforms "
          "VAE_rpl on π_curr, but is second-best on π_rand",
          (Comparison("PRED", "VAE_rpl", "pi_curr", "panel", -1),
           Place("PRED", "pi_rand", "panel", 2)), LOCOMOTION),
)


def claims_table(out, envs, variants) -> list[str]:
    """Markdown lines: the paper's Fig. 2 findings (`CLAIMS`) measured on the grid under OUT,
    one column per domain with runs; [] if none."""
    runs = {e: h for e in envs if (h := grid_histories(out, e, variants))}
    if not runs:
        return []
    lines = ["## The paper's findings, measured", "",
             "A − B: the difference of the two cells' group means at the last analysis both "
             "cells' seeds reached, Welch's 90 % interval over seeds. A place: where the "
             "learner's mean ranks among the cells at its last analysis (1 = lowest error), "
             "and its difference from the cell at the paper's place (or, there, from the "
             "nearest cell). ✓ resolved on the paper's side (a place: at the paper's place, "
             "the intervals to the cells beside it excluding 0), ✗ resolved against it, ~ not "
             "resolved; — a cell not run or a domain the finding is not about. With about 30 "
             "checks at 90 % per domain, a few ✓ or ✗ are expected by chance. Pendulums in "
             "training-std units, locomotion as fractions of a constant predictor's error "
             "(`jaml.experiments.fig2_claims`).", "",
             "| the paper says | check | " + " | ".join(runs) + " |",
             "|---" * (len(runs) + 2) + "|"]
    for claim in CLAIMS:
        for i, check in enumerate(claim.checks):
            entries = [_measure(env, cells, check) if env in claim.envs else "—"
                       for env, cells in runs.items()]
            lines.append(f"| {claim.text if i == 0 else ''} | {check.label()} | "
                         + " | ".join(entries) + " |")
    return [*lines, ""]


def _group_label(group: str) -> str:
    return "position (locomotion: panel)" if group == PLOTTED else group


def seed_values(env: str, histories: list[list[dict]], step: int, test: str,
                group: str) -> list[float] | str:
    """One value per seed at `step` on `test`: the group's mean error ("panel": the mean of the
    domain's group means; PLOTTED: position on the pendulums, the panel on locomotion), in the
    domain's reading; or why there is none."""
    groups = ld_groups(env)
    if group == PLOTTED:
        group = "panel" if env in LOCOMOTION else "position"
    parts = list(groups.values()) if group == "panel" else [groups[group]]
    values = []
    for history in histories:
        record = next((r for r in history if r["step"] == step and r["test_set"] == test), None)
        if record is None:
            return f"no analysis at epoch {step}"
        means = [group_value(record, dims, relative=env in LOCOMOTION) for dims in parts]
        if None in means:
            return "recorded without baselines"
        values.append(float(np.mean(means)))
    return values


def _measure(env: str, cells: dict[str, list[list[dict]]], check) -> str:
    if isinstance(check, Comparison):
        return _comparison(env, cells, check)
    return _place(env, cells, check)


def _comparison(env: str, cells: dict[str, list[list[dict]]], c: Comparison) -> str:
    if c.a not in cells or c.b not in cells:
        return "—"
    step = min(_runs.last_common_step(cells[v]) for v in (c.a, c.b))
    x, y = (seed_values(env, cells[v], step, c.test, c.group) for v in (c.a, c.b))
    for v, values in ((c.a, x), (c.b, y)):
        if isinstance(values, str):
            return f"— ({v} {values})"
    return _difference(x, y, c.sign) + _short(cells, (c.a, c.b), step)


def _difference(x: list[float], y: list[float], sign: int) -> str:
    """'d [low, high] mark' for mean(x) − mean(y), marked for the side `sign` expects."""
    text, mark = _interval(x, y, sign)
    return f"{text} {mark}" if mark else text


def _interval(x: list[float], y: list[float], sign: int) -> tuple[str, str]:
    """('d [low, high]', its mark for the side `sign` expects), or (why not, '')."""
    diff, low, high = intervals.welch_interval(x, y)
    if not np.isfinite(diff):
        return "non-finite", ""
    if np.isnan(low):
        return f"{diff:+.3f} (one seed: no interval)", ""
    mark = "~" if low <= 0 <= high else ("✓" if (low > 0) == (sign > 0) else "✗")
    return f"{diff:+.3f} [{low:+.3f}, {high:+.3f}]", mark


def _short(cells, names, step) -> str:
    """' (DSA 3 seeds, epoch 128)' for what is less than a complete cell's reading."""
    notes = [f"{v} {len(cells[v])} seed{'s' * (len(cells[v]) > 1)}" for v in names
             if len(cells[v]) < len(SEEDS)]
    if any(_runs.last_common_step(cells[v]) != step for v in names):
        notes.append(f"epoch {step}")
    return f" ({', '.join(notes)})" if notes else ""


def _place(env: str, cells: dict[str, list[list[dict]]], p: Place) -> str:
    """`p.variant`'s place among the cells that reached its last analysis (the others left out
    and named), marked as the module says."""
    if p.variant not in cells:
        return "—"
    step = _runs.last_common_step(cells[p.variant])
    read = {v: seed_values(env, h, step, p.test, p.group) for v, h in cells.items()}
    if isinstance(read[p.variant], str):
        return f"— ({p.variant} {read[p.variant]})"
    values = {v: x for v, x in read.items() if not isinstance(x, str)}
    if len(values) < p.place or len(values) < 2:
        return f"— ({len(values)} cells at epoch {step})"
    order = sorted(values, key=lambda v: np.mean(values[v]))
    place = order.index(p.variant) + 1
    mine = values[p.variant]
    if place == p.place:
        # Beside it: the cell just ahead (the paper has it better) and just behind (worse).
        beside = [(order[i], +1 if i < place - 1 else -1) for i in (place - 2, place)
                  if 0 <= i < len(order)]
        intervals = {v: _interval(mine, values[v], s) for v, s in beside}
        mark = "✓" if all(m == "✓" for _, m in intervals.values()) else "~"
        other = min(intervals, key=lambda v: abs(np.mean(values[v]) - np.mean(mine)))
        diff = intervals[other][0]
    else:
        # The cell at the paper's place: the paper has the learner ahead of it (if the learner
        # ranks lower here) or behind it (if higher).
        other = order[p.place - 1]
        diff, against = _interval(mine, values[other], -1 if place > p.place else +1)
        mark = "✗" if against == "✗" else "~"
    left = sorted(set(cells) - set(values))
    return (f"{place} of {len(order)} {mark}; {p.variant} − {other} {diff}"
            + _short(cells, [p.variant, other], step)
            + (f"; not at epoch {step}: {', '.join(left)}" if left else ""))
