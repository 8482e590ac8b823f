"""The paper's Fig. 2 findings as comparisons between cells of a grid, measured from its records.

Each finding of the paper's text (§3, "Benchmarking alignment") is written as differences of two
cells' group means, A − B, with the sign the paper's words imply; `claims_table` measures each
at the last analysis both cells' seeds reached (Welch's 90 % interval over seeds) and marks it
✓ (the interval excludes 0 on the paper's side), ✗ (it excludes 0 on the other side) or ~ (it
does not exclude 0). "PRED second-best on π_rand" is a ranking, reported as PRED's place among
the cells run and its difference from the cell next to it.

Readings: the pendulums in the regressor's training-std units, as the paper plots them;
locomotion's panel (the mean of its position, velocity and contact groups) and groups as
fractions of each run's constant predictor's error (`fig2.group_value`), since each run's units
come from its own replay and a mean over groups of different scales needs a common one.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaml.experiments import _runs
from jaml.experiments.fig2 import (
    LOCOMOTION,
    PENDULUMS,
    SEEDS,
    grid_histories,
    group_value,
    ld_groups,
)

BOTH = ("pi_rand", "pi_curr")
# The group the paper plots for a domain: position on the pendulums, the panel on locomotion.
PLOTTED = "position (locomotion: panel)"


@dataclasses.dataclass(frozen=True)
class Claim:
    """A finding of the paper: comparisons (A, B, test set, group) whose A − B the paper's words
    put on the side of `sign` (+1: A is worse, i.e. higher error; −1: A is better), on the
    domains of `envs`."""

    text: str
    comparisons: tuple[tuple[str, str, str, str], ...]
    sign: int
    envs: tuple[str, ...]


ALL = PENDULUMS + LOCOMOTION
SEQUENCE = ("SVAE", "PRED", "DSA")
CLAIMS = (
    Claim("VAE_v0 performs poorly on π_rand; replaying frames of the initial random policy "
          "(VAE_rpl) alleviates it", (("VAE_v0", "VAE_rpl", "pi_rand", PLOTTED),), +1, ALL),
    Claim("β-VAE offers no improvement over VAE_rpl; the best β (5) is slightly worse on the "
          "pendulums", tuple(("beta-VAE_5", "VAE_rpl", t, PLOTTED) for t in BOTH), +1, ALL),
    Claim("the other β (here 20) do significantly worse",
          tuple(("beta-VAE_20", "VAE_rpl", t, PLOTTED) for t in BOTH), +1, ALL),
    Claim("the sequential approaches SVAE, PRED, DSA offer significant gains for velocity",
          tuple((s, "VAE_rpl", t, "velocity") for s in SEQUENCE for t in BOTH), -1, ALL),
    Claim("PRED performs best on the pendulum domains (measured here against VAE_rpl and "
          "the other sequence learners)",
          tuple(("PRED", other, t, g) for other in ("VAE_rpl", "SVAE", "DSA") for t in BOTH
                for g in ("position", "velocity")), -1, PENDULUMS),
    Claim("locomotion, aggregated over position, velocity and contacts: PRED outperforms VAE_rpl "
          "on π_curr", (("PRED", "VAE_rpl", "pi_curr", "panel"),), -1, LOCOMOTION),
)
SECOND_BEST = "locomotion: PRED is second-best on π_rand (panel)"


def claims_table(out, envs, variants) -> list[str]:
    """Markdown lines: the paper's Fig. 2 findings (`CLAIMS`, then PRED's π_rand place on
    locomotion) measured on the grid under OUT, one column per domain with runs; [] if none."""
    runs = {e: h for e in envs if (h := grid_histories(out, e, variants))}
    envs = list(runs)
    if not envs:
        return []
    lines = ["## The paper's findings, measured", "",
             "A − B at the last analysis both cells' seeds reached, Welch's 90 % interval over "
             "seeds; ✓ the interval is on the paper's side of 0 (for the place: second), ✗ on "
             "the other side, ~ it contains 0; — a cell not run or a domain the finding is not "
             "about. Pendulums in training-std units, locomotion as fractions of a constant "
             "predictor's error (`jaml.experiments.fig2_claims`).", "",
             "| the paper says | A − B, test set, group | " + " | ".join(envs) + " |",
             "|---" * (len(envs) + 2) + "|"]
    for claim in CLAIMS:
        for i, (a, b, test, group) in enumerate(claim.comparisons):
            entries = [_comparison(env, runs[env], a, b, test, group, claim.sign)
                       if env in claim.envs else "—" for env in envs]
            lines.append(f"| {claim.text if i == 0 else ''} | {a} − {b}, {test}, {group} | "
                         + " | ".join(entries) + " |")
    lines.append(f"| {SECOND_BEST} | PRED's place by mean; PRED − the cell next to it | "
                 + " | ".join(_place(env, runs[env]) if env in LOCOMOTION else "—"
                              for env in envs) + " |")
    return [*lines, ""]


def _relative(env: str) -> bool:
    return env in LOCOMOTION


def seed_values(env: str, histories: list[list[dict]], step: int, test: str,
                group: str) -> list[float] | None:
    """One value per seed at `step` on `test`: the group's mean error ("panel": the mean of the
    domain's group means), in the domain's reading; None where a seed lacks the analysis or,
    read as fractions, its records lack the constant's baselines."""
    groups = ld_groups(env)
    if group == PLOTTED:
        group = "panel" if env in LOCOMOTION else "position"
    parts = list(groups.values()) if group == "panel" else [groups[group]]
    values = []
    for history in histories:
        record = next((r for r in history if r["step"] == step and r["test_set"] == test), None)
        if record is None:
            return None
        means = [group_value(record, dims, _relative(env)) for dims in parts]
        if None in means:
            return None
        values.append(float(np.mean(means)))
    return values


def _common_step(*cells: list[list[dict]]) -> int:
    return min(_runs.last_common_step(h) for h in cells)


def _comparison(env, runs, a, b, test, group, sign) -> str:
    if a not in runs or b not in runs:
        return "—"
    step = _common_step(runs[a], runs[b])
    x, y = (seed_values(env, runs[v], step, test, group) for v in (a, b))
    if x is None or y is None:
        return "— (no common analysis)"
    diff, low, high = _runs.welch_interval(x, y)
    if np.isnan(low):
        return f"{diff:+.3f} (one seed)"
    mark = "~" if low <= 0 <= high else ("✓" if (low > 0) == (sign > 0) else "✗")
    return f"{diff:+.3f} [{low:+.3f}, {high:+.3f}] {mark}" + _short(runs, (a, b), step)


def _short(runs, cells, step) -> str:
    """' (DSA 3 seeds, epoch 128)' for what is less than a complete cell's reading."""
    notes = [f"{v} {len(runs[v])} seeds" for v in cells if len(runs[v]) < len(SEEDS)]
    if any(_runs.last_common_step(runs[v]) != step for v in cells):
        notes.append(f"epoch {step}")
    return f" ({', '.join(notes)})" if notes else ""


def _place(env, runs) -> str:
    """PRED's place among the cells by mean π_rand panel, and its difference from the cell just
    ahead of it (or, first, the one just behind)."""
    if "PRED" not in runs or len(runs) < 2:
        return "—"
    step = _common_step(*runs.values())
    values = {v: seed_values(env, h, step, "pi_rand", "panel") for v, h in runs.items()}
    values = {v: x for v, x in values.items() if x is not None}
    if "PRED" not in values or len(values) < 2:
        return "— (no common analysis)"
    order = sorted(values, key=lambda v: np.mean(values[v]))
    place = order.index("PRED")
    neighbour = order[place - 1] if place else order[1]
    diff, low, high = _runs.welch_interval(values["PRED"], values[neighbour])
    return (f"{place + 1} of {len(order)}{' ✓' if place == 1 else ''}; PRED − {neighbour} "
            f"{diff:+.3f} [{low:+.3f}, {high:+.3f}]" + _short(runs, list(runs), step))
