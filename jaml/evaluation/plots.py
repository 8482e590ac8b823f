"""Alignment and distortion curves over training (paper Fig. 2, 9) from a JSON-lines history.

A history is a list of records, one per (step, learner, test set, run):

    {"step": 500, "learner": "PRED", "test_set": "pi_rand", "run": 0,
     "errors": {"x": 0.21, "theta": 0.13}, "distortion": 0.42}

"errors" holds the per-dimension alignment errors by LD-state name; "distortion" (Var ρ, eq. 5)
may be None or absent. Records of several runs at one step are shown as their mean with a
90 % confidence interval of the mean (Student's t: mean ± t₀.₉₅(n−1)·s/√n, which for the
paper's 6 runs is 1.23× wider than the normal approximation), as the paper's figures show 90 %
confidence intervals over runs. Figures use matplotlib's Agg canvas; no global state is touched.
A run directory's figures (`run_figures`) are drawn on a background thread (`FigureWriter`).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from jaml._rundir import write_atomically
from jaml.evaluation.intervals import mean_interval


def history_records(step: int, learner: str, errors: Mapping[str, Sequence[float]],
                    names: Sequence[str], distortion: float | None = None,
                    run: int = 0) -> list[dict]:
    """Records for one analysis: `errors` maps test set → [D] errors, `names` the D state names."""
    records = []
    for test_set, values in errors.items():
        values = np.asarray(values, np.float64).reshape(-1)
        if values.size != len(names):
            raise ValueError(
                f"errors[{test_set!r}] has {values.size} entries but {len(names)} names were given"
            )
        records.append(
            {
                "step": int(step),
                "learner": str(learner),
                "test_set": str(test_set),
                "run": int(run),
                "errors": {n: float(v) for n, v in zip(names, values, strict=True)},
                "distortion": None if distortion is None else float(distortion),
            }
        )
    return records


def _check(history: Iterable[Mapping]) -> list[Mapping]:
    history = list(history)
    if not history:
        raise ValueError("history is empty")
    for k, rec in enumerate(history):
        missing = [key for key in ("step", "learner", "test_set") if key not in rec]
        if missing:
            raise ValueError(f"history[{k}] lacks {missing}")
    return history


def _ordered(values: Iterable) -> list:
    return list(dict.fromkeys(values))


def _curves(points: Mapping[int, list[float]]):
    steps = sorted(points)
    bands = np.array([mean_interval(points[s]) for s in steps])
    return np.asarray(steps), bands[:, 0], bands[:, 1], bands[:, 2]


def _draw_curve(ax, steps, mean, lo, hi, color: str, label: str) -> None:
    """The runs' mean as a line with its interval as a band; a lone analysis as a point with
    its interval as an error bar (a line and a band of one point draw nothing)."""
    if len(steps) > 1:
        ax.plot(steps, mean, color=color, label=label)
        ax.fill_between(steps, lo, hi, color=color, alpha=0.2, linewidth=0)
        return
    band = np.concatenate([mean - lo, hi - mean])
    ax.errorbar(steps, mean, yerr=band[:, None] if np.all(np.isfinite(band)) else None,
                color=color, label=label, marker="o", markersize=4, capsize=3, linestyle="none")


def save_figure(fig: Figure, path) -> None:
    """Draw `fig` (Agg canvas, no pyplot) to `path` atomically, through a temporary name of this
    process's own: a figure several processes redraw (an experiment's grid figure) is never left
    half-written. The format is the path's suffix (png without one)."""
    FigureCanvasAgg(fig)
    fmt = Path(path).suffix[1:] or "png"
    write_atomically(path, lambda tmp: fig.savefig(tmp, dpi=100, format=fmt))


# Largest over smallest curve mean beyond which a panel of `plot_alignment` is drawn log-scaled.
LOG_SPAN = 10.0


def _spans_decades(curves) -> bool:
    """Whether the positive means of `curves` span more than LOG_SPAN."""
    values = np.concatenate([np.asarray(c, float) for c in curves]) if curves else np.zeros(0)
    values = values[np.isfinite(values) & (values > 0)]
    return values.size > 0 and values.max() > LOG_SPAN * values.min()


# The y-axis of an alignment panel unless a caller says otherwise: errors in units of each
# dimension's training std (the alignment regressor z-scores its targets, `alignment`).
TRAIN_STD = "test error (train std)"


# The dashed curve of a panel whose records carry "baseline": the error of a prediction that
# ignores the latents (`alignment.constant_errors`), the level an error is read against.
CONSTANT = "constant predictor"
# The dotted line of a panel given a `floor`: the regressor's error from the true state itself.
FLOOR = "true state"


def _constant_curve(history: list, test_set: str, dims: Sequence[str]):
    """(steps, mean over records of the mean over `dims` of "baseline"), or None."""
    points = defaultdict(list)
    for r in history:
        base = r.get("baseline") or {}
        if r["test_set"] == test_set and all(d in base for d in dims):
            points[int(r["step"])].append(float(np.mean([base[d] for d in dims])))
    if not points:
        return None
    steps = sorted(points)
    return np.asarray(steps), np.asarray([np.mean(points[s]) for s in steps])


def plot_alignment(history: Iterable[Mapping], path,
                   groups: Mapping[str, Sequence[str]] | None = None,
                   ylabels: Mapping[str, str] | None = None,
                   floor: Mapping[str, Mapping[str, float]] | None = None) -> Figure:
    """`alignment_figure` written to `path` (`save_figure`); returns the figure."""
    fig = alignment_figure(history, groups, ylabels, floor)
    save_figure(fig, path)
    return fig


def alignment_figure(history: Iterable[Mapping],
                     groups: Mapping[str, Sequence[str]] | None = None,
                     ylabels: Mapping[str, str] | None = None,
                     floor: Mapping[str, Mapping[str, float]] | None = None) -> Figure:
    """Alignment error vs epoch (a record's "step": the epochs completed): one row per test
    set, one column per dimension (lines carry the per-step means).

    groups: optional panel title → state names; the panel shows the mean error over those names
    (the paper aggregates position / velocity / contacts this way for the locomotion domains).

    ylabels: optional panel title → its y-axis label (default TRAIN_STD), for panels whose
    values are in other units; a label is drawn on a row's first panel and on every panel whose
    label differs from its left neighbour's.

    A panel whose curves span more than LOG_SPAN (largest over smallest mean) is drawn on a log
    axis, "(log)" in its title: one learner that forgets (errors of 5 and more) would otherwise
    flatten the others' curves near 0.1 into one line. Records with "baseline" (a constant
    predictor's errors, `jaml.stream.run`'s history) add a dashed grey curve of it. `floor`
    (test set → state name → error; a run's true-state reference row, `summary.json`'s
    "references") adds a dotted grey line: what the regressor reaches from the state itself.
    """
    history = [r for r in _check(history) if r.get("errors")]
    if not history:
        raise ValueError("history has no records with alignment errors")
    if groups is None:
        names = _ordered(n for r in history for n in r["errors"])
        groups = {n: [n] for n in names}
    elif not groups or any(not dims for dims in groups.values()):
        raise ValueError("groups must map each panel title to at least one state name")
    test_sets = _ordered(r["test_set"] for r in history)
    learners = _ordered(r["learner"] for r in history)
    fig = Figure(figsize=(3.6 * len(groups), 2.8 * len(test_sets)), layout="constrained")
    axes = fig.subplots(len(test_sets), len(groups), squeeze=False)
    colors = {name: f"C{k % 10}" for k, name in enumerate(learners)}
    labels = [(ylabels or {}).get(title, TRAIN_STD) for title in groups]
    for row, test_set in enumerate(test_sets):
        for col, (title, dims) in enumerate(groups.items()):
            ax = axes[row, col]
            drawn = []
            for learner in learners:
                points = defaultdict(list)
                for r in history:
                    if r["learner"] == learner and r["test_set"] == test_set:
                        vals = [r["errors"][d] for d in dims if d in r["errors"]]
                        if len(vals) == len(dims):
                            points[int(r["step"])].append(float(np.mean(vals)))
                if not points:
                    continue
                curve = _curves(points)
                _draw_curve(ax, *curve, colors[learner], learner)
                drawn.append(curve[1])
            constant = _constant_curve(history, test_set, dims)
            if constant is not None:
                ax.plot(*constant, color="0.45", linestyle="--", linewidth=1, label=CONSTANT,
                        marker="_" if len(constant[0]) == 1 else None, markersize=12)
                drawn.append(constant[1])
            below = (floor or {}).get(test_set, {})
            if all(d in below for d in dims):
                level = float(np.mean([below[d] for d in dims]))
                # Not in the log rule's span: a floor near 0 would put every panel on a log axis.
                ax.axhline(level, color="0.45", linestyle=":", linewidth=1, label=FLOOR)
            log = _spans_decades(drawn)
            ax.set_title(f"{title} ({test_set})" + (" (log)" if log else ""), fontsize=9)
            ax.set_xlabel("epoch")
            if col == 0 or labels[col] != labels[col - 1]:
                ax.set_ylabel(labels[col])
            if log:
                ax.set_yscale("log")
            else:
                ax.set_ylim(bottom=0.0)
    # Every learner in the legend, also one absent from the first panel (a grid whose first
    # domain has fewer cells than a later one).
    handles = [Line2D([], [], color=colors[n], label=n) for n in learners]
    if any(r.get("baseline") for r in history):
        handles.append(Line2D([], [], color="0.45", linestyle="--", linewidth=1, label=CONSTANT))
    if floor:
        handles.append(Line2D([], [], color="0.45", linestyle=":", linewidth=1, label=FLOOR))
    axes[0, 0].legend(handles=handles, fontsize=8)
    return fig


def plot_distortion(history: Iterable[Mapping], path) -> Figure:
    """`distortion_figure` written to `path` (`save_figure`); returns the figure."""
    fig = distortion_figure(history)
    save_figure(fig, path)
    return fig


def distortion_figure(history: Iterable[Mapping]) -> Figure:
    """Distortion Var(ρ) vs epoch, one curve per learner (and test set, if several).

    eq. 5's figure is +inf at an analysis where the encoder maps a pair of distinct states
    (and inputs) to one latent; such a point has no place on the curve. Where a record carries
    "distortion_trimmed" (Var ρ over the finite pairs, `distortion.distortion_trimmed`) and
    "distortion_left_out" (the pairs it leaves out), that point is drawn on a dashed curve
    whose label gives the count; a figure with nothing finite to draw says so in words."""
    history = [r for r in _check(history) if r.get("distortion") is not None]
    if not history:
        raise ValueError("history has no records with a distortion value")
    test_sets = _ordered(r["test_set"] for r in history)
    series = _ordered((r["learner"], r["test_set"]) for r in history)
    fig = Figure(figsize=(5.0, 3.5), layout="constrained")
    ax = fig.subplots()
    drawn = False
    for k, (learner, test_set) in enumerate(series):
        exact, trimmed, left_out = defaultdict(list), defaultdict(list), []
        for r in history:
            if r["learner"] == learner and r["test_set"] == test_set:
                value = float(r["distortion"])
                if np.isfinite(value):
                    exact[int(r["step"])].append(value)
                elif r.get("distortion_trimmed") is not None and np.isfinite(
                        float(r["distortion_trimmed"])):
                    trimmed[int(r["step"])].append(float(r["distortion_trimmed"]))
                    left_out.append(int(r.get("distortion_left_out") or 0))
        label = learner if len(test_sets) == 1 else f"{learner} ({test_set})"
        color = f"C{k % 10}"
        if exact:
            _draw_curve(ax, *_curves(exact), color, label)
        if trimmed:
            steps, mean, _, _ = _curves(trimmed)
            ax.plot(steps, mean, color=color, linestyle="--", marker="o", markersize=3,
                    label=f"{label}: +inf, trimmed ({min(left_out)}–{max(left_out)} "
                          "collapsed pairs left out)" if min(left_out) != max(left_out) else
                          f"{label}: +inf, trimmed ({left_out[0]} collapsed pairs left out)")
        drawn = drawn or bool(exact or trimmed)
    if not drawn:
        ax.text(0.5, 0.5, "distortion +inf at every analysis: the encoder maps distinct\n"
                "states to one latent (no trimmed figure recorded)", ha="center",
                va="center", transform=ax.transAxes, fontsize=9)
    ax.set_xlabel("epoch")
    ax.set_ylabel("distortion Var(ρ)")
    if drawn:
        ax.legend(fontsize=8)
    return fig


def run_figures(history: list[dict], out: Path, floor: dict | None = None) -> None:
    """A run directory's alignment.png (with the true state's `floor`) and distortion.png of
    `history`, in `out`: both drawn, then both written."""
    figures = {"alignment.png": alignment_figure(history, floor=floor),
               "distortion.png": distortion_figure(history)}
    for name, fig in figures.items():
        save_figure(fig, Path(out) / name)


class FigureWriter:
    """Draws the runs' figures (`run_figures`) on one background thread, so the loop's next
    epochs run while matplotlib draws (drawn in line, they held up every analysis of every
    run; docs/notes/stream.md). A run's figures are drawn from its newest history only: a
    request still queued when a newer one for the same run arrives is skipped. `wait` drains
    the queue; `check` raises the first drawing error."""

    def __init__(self):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaml-figures")
        self._newest: dict[Path, object] = {}
        self._futures: list[Future] = []

    def submit(self, out: Path, history: list[dict], floor: dict | None = None) -> None:
        token = self._newest[out] = object()

        def draw():
            if self._newest.get(out) is token:
                run_figures(history, out, floor)

        self._futures.append(self._pool.submit(draw))

    def wait(self) -> None:
        self._pool.shutdown(wait=True)

    def check(self) -> None:
        for future in self._futures:
            future.result()
