"""Fig. 9's report: every method against PRED, seed by seed, at every analysis.

A seed's frame stream is the same for every method (the learner never feeds back into PPO), so
the difference from PRED is measured per seed and its interval is the paired one; Welch's
interval over seeds stands beside it. `stream_check` says whether the streams really matched.
The primary comparison is fixed before the runs (`PRIMARY`); everything else is secondary.
"""

from __future__ import annotations

import functools
import itertools
import json
import math
from collections import defaultdict
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from jaml._rundir import write_text
from jaml.evaluation import plots
from jaml.evaluation.intervals import mean_interval, paired_interval, welch_interval
from jaml.experiments._runs import read_jsonl, stopped_runs, true_state_errors

BASE = "PRED"
# name → (label, value of a π_rand analysis record or None)
METRICS = {
    "position": ("position error, π_rand", lambda r: r["errors"]["position"]),
    "velocity": ("velocity error, π_rand", lambda r: r["errors"]["velocity"]),
    "distortion": ("Var(ρ), π_rand (paper eq. 5)", lambda r: r.get("distortion")),
    "irregularity": ("irreg_std, π_rand (released code)",
                     lambda r: (r.get("irregularity") or {}).get("pi_rand")),
    "irregularity_replay": ("irreg_std, replay (released code)",
                            lambda r: (r.get("irregularity") or {}).get("replay")),
}
# The comparison written down before the runs: π_rand position error of the faithful
# AML_trnsv minus PRED, averaged over the analyses more than 500 learner epochs in, with the
# paired 90 % interval over seeds.
PRIMARY = dict(method="PRED+AML_trnsv", metric="position", after_learner_epochs=500)
# What the penalty adds over the reconstruction term it brings with it: each AML arm against
# each control (same ok-row term, no penalty), seed by seed.
ARMS = ("PRED+AML_trnsv", "PRED+AML_syz")
CONTROLS = ("PRED+ok_rows", "PRED+random_rows", "PRED+random_rows_5pct", "PRED+beta_1of11")
# A control against the explanation of its effect: the random-row term is, in expectation,
# 10 × the batch's NLL, i.e. PRED's loss with β = 1/11.
EXPLAINED = (("PRED+random_rows", "PRED+beta_1of11"), ("PRED+random_rows_5pct", "PRED+beta_1of11"))


def collect(out: Path, methods) -> dict[str, dict[int, list[dict]]]:
    """method → seed → its π_rand analysis records (runs a non-finite loss stopped left out)."""
    runs = {}
    for method in methods:
        directory = out / method
        stopped = stopped_runs(directory) if directory.is_dir() else {}
        seeds = {}
        for d in sorted(directory.glob("seed_*")):
            if d.name in stopped:
                continue
            records = [r for r in read_jsonl(d / "history.jsonl") if r["test_set"] == "pi_rand"]
            if records:
                seeds[int(d.name.removeprefix("seed_"))] = records
        if seeds:
            runs[method] = seeds
    return runs


def values_at(seeds: dict[int, list[dict]], metric: str) -> dict[int, dict[int, float]]:
    """step → seed → value of `metric` (records without it are skipped)."""
    get = METRICS[metric][1]
    table: dict[int, dict[int, float]] = defaultdict(dict)
    for seed, records in seeds.items():
        for r in records:
            v = get(r)
            if v is not None and math.isfinite(v):
                table[int(r["step"])][seed] = float(v)
    return table


def _late_means(seeds, metric: str, first: int) -> dict[int, float]:
    """seed → the mean of `metric` over the analyses after epoch `first` (seeds that miss one
    of those analyses are left out)."""
    table = values_at(seeds, metric)
    steps = [s for s in table if s > first]
    per_seed = defaultdict(list)
    for s in steps:
        for seed, v in table[s].items():
            per_seed[seed].append(v)
    return {seed: float(np.mean(v)) for seed, v in per_seed.items() if len(v) == len(steps)}


def primary(runs, fill_epochs: int) -> str:
    """The pre-registered comparison's line (PRIMARY)."""
    m, metric = PRIMARY["method"], PRIMARY["metric"]
    if m not in runs or BASE not in runs:
        return f"Primary comparison: not available ({m} or {BASE} has no runs)."
    first = fill_epochs + PRIMARY["after_learner_epochs"]
    means = {method: _late_means(runs[method], metric, first) for method in (m, BASE)}
    if not means[m]:
        return (f"Primary comparison: no analysis after learner epoch "
                f"{PRIMARY['after_learner_epochs']} yet.")
    d, lo, hi, n = paired_interval(means[m], means[BASE])
    return (f"**Primary comparison** ({m} − {BASE}, π_rand {metric} error averaged over the "
            f"analyses after learner epoch {PRIMARY['after_learner_epochs']}, paired 90 % "
            f"interval over {n} seeds): **{d:+.4f} [{lo:+.4f}, {hi:+.4f}]**.")


def late_table(runs, fill_epochs: int) -> list[str]:
    """Secondary: the primary's average (analyses after learner epoch 500) for every method and
    metric, Δ from PRED with its paired 90 % interval."""
    others = [m for m in runs if m != BASE]
    if BASE not in runs or not others:
        return []
    first = fill_epochs + PRIMARY["after_learner_epochs"]
    lines = [f"**Averaged over the analyses after learner epoch "
             f"{PRIMARY['after_learner_epochs']}** (the primary's average for every method "
             "and metric; secondary but for the primary's cell): method − PRED, paired 90 % "
             "interval.", "",
             "| method − PRED | " + " | ".join(METRICS[m][0] for m in METRICS) + " |",
             "|---" * (len(METRICS) + 1) + "|"]
    base = {metric: _late_means(runs[BASE], metric, first) for metric in METRICS}
    rows = []
    for m in others:
        cells = []
        for metric in METRICS:
            a = _late_means(runs[m], metric, first)
            cells.append(_paired(a, base[metric]) if set(a) & set(base[metric]) else "")
        if any(cells):
            rows.append(f"| {m} | " + " | ".join(cells) + " |")
    return lines + rows if rows else []


def _paired(values: dict[int, float], base: dict[int, float]) -> str:
    """`d [lo, hi]`, the paired difference and its 90 % interval, bold when it excludes 0."""
    d, lo, hi, _ = paired_interval(values, base)
    mark = "**" if lo > 0 or hi < 0 else ""
    return f"{mark}{d:+.4f} [{lo:+.4f}, {hi:+.4f}]{mark}"


def metric_table(runs, metric: str) -> list[str]:
    """Per analysis step: each method's mean and, for the others, Δ from PRED (paired, and
    Welch's)."""
    methods = list(runs)
    tables = {m: values_at(runs[m], metric) for m in methods}
    steps = sorted(set().union(*(t.keys() for t in tables.values())))
    head = "| epoch | " + " | ".join(methods) + " |"
    lines = [f"**{METRICS[metric][0]}**: mean over seeds; for each method, Δ = method − PRED "
             "with its paired 90 % interval, then Welch's.", "", head,
             "|---" * (len(methods) + 1) + "|"]
    for step in steps:
        cells = []
        for m in methods:
            vals = tables[m].get(step, {})
            if not vals:
                cells.append("")
                continue
            text = f"{np.mean(list(vals.values())):.4f} ({len(vals)})"
            base = tables.get(BASE, {}).get(step, {})
            if m != BASE and base:
                _, wlo, whi = welch_interval(list(vals.values()), list(base.values()))
                text += f"<br>Δ {_paired(vals, base)}<br>W [{wlo:+.4f}, {whi:+.4f}]"
            cells.append(text)
        lines.append(f"| {step} | " + " | ".join(cells) + " |")
    return lines


def contrast_table(runs, step: int | None = None) -> list[str]:
    """Each AML arm − each control, every metric, paired 90 % intervals, at the last analysis
    every run reached (or `step`)."""
    pairs = [(a, c) for a, c in (*itertools.product(ARMS, CONTROLS), *EXPLAINED)
             if a in runs and c in runs]
    if not pairs:
        return []
    tables = {m: {metric: values_at(runs[m], metric) for metric in METRICS} for m in runs}
    if step is None:
        common = set.intersection(*(set(tables[m]["position"]) for pair in pairs for m in pair))
        if not common:
            return []
        step = max(common)
    lines = [f"**Penalty against its controls** at epoch {step}: arm − control, paired 90 % "
             "interval (the ok-row and random-row controls keep the arm's reconstruction term "
             "on ok rows and drop the penalty; β = 1/11 is PRED weighted as the random-row "
             "term weighs it in expectation, and is also set against the random-row "
             "controls).", "",
             "| arm − control | " + " | ".join(METRICS[m][0] for m in METRICS) + " |",
             "|---" * (len(METRICS) + 1) + "|"]
    for arm, control in pairs:
        cells = []
        for metric in METRICS:
            a, c = tables[arm][metric].get(step, {}), tables[control][metric].get(step, {})
            if not a or not c:
                cells.append("")
                continue
            cells.append(_paired(a, c))
        lines.append(f"| {arm} − {control} | " + " | ".join(cells) + " |")
    return lines


def _metrics(run: Path) -> list[dict]:
    return read_jsonl(run / "metrics.jsonl")


def stream_check(out: Path, methods, metrics=_metrics) -> list[str]:
    """Whether each seed's stream was the same for every method: its per-epoch episode returns
    and PPO losses (`metrics(run)`, its metrics.jsonl) compared with PRED's, bit for bit; a seed
    that differs is named with the first epoch where it does."""
    keys = ("episode_return", "ppo/total_loss")

    def stream(run: Path) -> dict[int, str]:
        return {r["epoch"]: json.dumps([r.get(k) for k in keys]) for r in metrics(run)}

    base_streams: dict[str, dict[int, str]] = {}  # PRED's, read once for every method
    lines = []
    for method in methods:
        if method == BASE:
            continue
        same, differ, missing = [], [], []
        for d in sorted((out / method).glob("seed_*")):
            if d.name not in base_streams:
                base_streams[d.name] = stream(out / BASE / d.name)
            a, b = stream(d), base_streams[d.name]
            if not (a and b):
                missing.append(d.name)
                continue
            common = sorted(a.keys() & b.keys())
            first = next((e for e in common if a[e] != b[e]), None)
            if common and first is None:
                same.append(d.name)
            else:
                differ.append(d.name if first is None else f"{d.name} from epoch {first}")
        parts = [f"{len(same)} seeds identical"]
        if differ:
            parts.append(f"differ: {', '.join(differ)}")
        if missing:
            parts.append(f"no metrics: {', '.join(missing)}")
        lines.append(f"- {method} vs {BASE}: " + "; ".join(parts))
    return lines


# The learner's per-epoch losses the report summarises between analyses (metrics.jsonl).
LOSSES = {"learner/nll": "NLL", "learner/kl": "KL", "learner/penalty": "penalty",
          "learner/ok_fraction": "ok share"}


def losses_table(out: Path, runs, metrics=_metrics) -> list[str]:
    """Each method's learner losses per frame sequence, averaged over the epochs between
    consecutive analyses and then over seeds: what the penalty and the ok-row term do to the
    likelihood, the KL and the share of ok rows."""
    steps = sorted({int(r["step"]) for seeds in runs.values() for records in seeds.values()
                    for r in records})
    blocks = list(itertools.pairwise(steps))
    if not blocks:
        return []
    lines = ["**Learner losses** (metrics.jsonl): mean over the epochs after one analysis up to "
             "the next, then over seeds; NLL and KL per sequence; ok share the batch's share of "
             "rows that get the ok-row term.", "",
             "| method | " + " | ".join(LOSSES.values()) + " |",
             "|---|" + "---|" * len(LOSSES)]
    for method, seeds in runs.items():
        means = {key: [] for key in LOSSES}  # key → [block → seed means]
        per_seed = [metrics(out / method / f"seed_{seed}") for seed in seeds]
        for key in LOSSES:
            for lo, hi in blocks:
                values = [np.mean(v) for v in ([r[key] for r in records
                                                 if lo < r["epoch"] <= hi and key in r]
                                                for records in per_seed) if v]
                means[key].append(float(np.mean(values)) if values else None)
        cells = []
        for key in LOSSES:
            vals = means[key]
            if all(v is None for v in vals):
                cells.append("—")
                continue
            fmt = "{:.1%}" if key == "learner/ok_fraction" else "{:.1f}"
            cells.append(" → ".join("—" if v is None else fmt.format(v) for v in vals))
        lines.append(f"| {method} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append("Blocks: epochs " + ", ".join(f"{lo + 1}–{hi}" for lo, hi in blocks) + ".")
    return lines


def plot(runs, path: Path):
    """Position error, Var(ρ) and irreg_std on π_rand over epochs: each method's seed mean with
    its 90 % band; and the paired difference from PRED of the position error."""
    fig = Figure(figsize=(14, 7.5), layout="constrained")
    axes = fig.subplots(2, 2).ravel()
    for k, (method, seeds) in enumerate(runs.items()):
        for ax, metric in zip(axes[:3], ("position", "distortion", "irregularity"), strict=True):
            table = values_at(seeds, metric)
            steps = sorted(table)
            if not steps:
                continue
            bands = np.array([mean_interval(list(table[s].values())) for s in steps])
            ax.plot(steps, bands[:, 0], color=f"C{k}", label=f"{method} ({len(seeds)})")
            ax.fill_between(steps, bands[:, 1], bands[:, 2], color=f"C{k}", alpha=0.15,
                            linewidth=0)
        if method != BASE and BASE in runs:
            mine, base = values_at(seeds, "position"), values_at(runs[BASE], "position")
            steps = sorted(s for s in mine if s in base)
            diffs = np.array([paired_interval(mine[s], base[s])[:3] for s in steps])
            if len(steps):
                axes[3].plot(steps, diffs[:, 0], color=f"C{k}", label=method)
                axes[3].fill_between(steps, diffs[:, 1], diffs[:, 2], color=f"C{k}",
                                     alpha=0.15, linewidth=0)
    for ax in axes[:3]:
        if not ax.lines:
            ax.text(0.5, 0.5, "not in these runs' records", ha="center", va="center",
                    transform=ax.transAxes)
    axes[3].axhline(0.0, color="black", linewidth=0.8)
    titles = ("object position alignment error, π_rand", "distortion Var(ρ), π_rand (paper)",
              "irreg_std, π_rand (released code)", "Δ position error from PRED (paired 90 %)")
    for ax, title in zip(axes, titles, strict=True):
        ax.set_title(title)
        ax.set_xlabel("epoch")
    for ax in (axes[0], axes[3]):
        if ax.lines and any(not line.get_label().startswith("_") for line in ax.lines):
            ax.legend(fontsize=8)
    plots.save_figure(fig, path)
    return fig


def report(out: Path, methods) -> str:
    """OUT/fig9.md (and fig9.png) from the runs found; returns the markdown."""
    runs = collect(out, methods)
    if not runs:
        return "no finished runs\n"
    plot(runs, out / "fig9.png")
    metrics = functools.cache(_metrics)  # each run's metrics.jsonl read once per report
    fill = _fill_epochs(out, runs)
    lines = [primary(runs, fill), "", bounds(out, runs), ""]
    kept = any(metrics(out / method / f"seed_{seed}") for method, seeds in runs.items()
               for seed in seeds)
    if kept:
        lines += ["Streams (a seed's per-epoch episode returns and PPO losses against PRED's):",
                  *stream_check(out, runs, metrics), ""]
    else:  # runs recorded before the records kept metrics.jsonl: one line, not empty tables
        lines += ["Streams and learner losses: not in these runs' records (no metrics.jsonl).",
                  ""]
    for table in (late_table(runs, fill), contrast_table(runs)):
        if table:
            lines += [*table, ""]
    losses = losses_table(out, runs, metrics) if kept else []
    if losses:
        lines += [*losses, ""]
    for metric in METRICS:
        if any(values_at(seeds, metric) for seeds in runs.values()):
            lines += [*metric_table(runs, metric), ""]
        else:
            lines += [f"**{METRICS[metric][0]}**: not in these runs' records.", ""]
    text = "\n".join(lines)
    write_text(out / "fig9.md", text)
    return text


def bounds(out: Path, runs) -> str:
    """A line of π_rand's bounds over every run: a constant prediction's position and velocity
    errors at each run's last analysis (the ceiling), the true state's as the latent (the floor,
    summary.json's "references") where the runs recorded it."""
    def mean(rows, what):
        values = " and ".join(f"{name} {np.mean([r[name] for r in rows]):.4f}"
                              for name in ("position", "velocity"))
        return f"{values} ({len(rows)} run{'s' * (len(rows) != 1)}, {what})"

    last = [max(records, key=lambda r: r["step"]) for seeds in runs.values()
            for records in seeds.values()]
    ceiling = [r["baseline"] for r in last if r.get("baseline")]
    names = list(last[0]["errors"])
    floor = [row for method, seeds in runs.items()
             for row in true_state_errors(out / method, names).get("pi_rand", [])]
    return ("**Bounds on π_rand**, means over every run: a constant prediction's errors "
            + (mean(ceiling, "each at its last analysis") if ceiling else "not recorded")
            + " (the ceiling); the true state's as the latent "
            + (mean(floor, "each at its last call's first analysis") if floor
               else "not recorded by these runs") + " (the floor).")


def _fill_epochs(out: Path, runs) -> int:
    """Epochs that filled the replay before the learner started (the first analysis)."""
    return min(min(int(r["step"]) for r in records)
               for seeds in runs.values() for records in seeds.values())
