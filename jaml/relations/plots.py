"""Figures like the paper's: zero-level sets of learned relations (Fig. 5) and phase space (Fig. 7).

The learned manifold (g_1 ∩ … ∩ g_K) is drawn by moving points onto it (`geometry.project`); a
single relation's zero-level set as the box points where it holds (`relations.holds`). Each
figure carries a caption saying what is plotted and how well the learned manifold agrees with
the data.
"""

from __future__ import annotations

import io
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from PIL import Image

from jaml.relations.data import PADDED
from jaml.relations.geometry import project
from jaml.relations.relation_set import RelationSet, holds, tolerances_text

PROJECTION_STEPS = 30
ARROWS = 250  # per phase-space panel


def level_set_points(rs: RelationSet, low, high, key, which=None, n_points=2500, rounds=20):
    """Uniform box points where the chosen relations (all if `which` is None) hold.

    Rejection sampling in rounds of 10·n_points candidates until n_points are kept (the
    reference's visualisation filter). Returns float [M, D], M ≤ n_points.
    """
    which = list(range(rs.num_relations)) if which is None else list(which)
    low, high = jnp.asarray(low), jnp.asarray(high)
    chosen = rs.select(which)

    @jax.jit
    def candidates(key):
        tau = jax.random.uniform(key, (10 * n_points, low.shape[0]), minval=low, maxval=high)
        return tau, holds(chosen, tau)

    kept = []
    for r in range(rounds):
        tau, ok = jax.device_get(candidates(jax.random.fold_in(key, r)))
        kept.append(tau[ok])
        if sum(len(k) for k in kept) >= n_points:
            break
    return np.concatenate(kept)[:n_points]


def _box(on: np.ndarray, scale=1.0):
    """The rows' box × `scale`; a constant column's side as the fit pads it (`padded_box`)."""
    centre, half = (on.max(0) + on.min(0)) / 2, (on.max(0) - on.min(0)) / 2
    half = np.where(half > 0, half, PADDED * half.max())
    return centre - scale * half, centre + scale * half


def _one_holds(rs: RelationSet) -> str:
    """`holds`' criterion for one relation, in words."""
    if rs.distance_tolerance is None:
        return f"one |g_k| < {rs.tolerance:.3g}× its on-manifold mean"
    return f"one |g_k| / ‖∇g_k‖ < {tolerances_text(rs.distance_tolerance)}"


def _converging(rs: RelationSet) -> str:
    """`project`'s converged in words."""
    return f"every |g_k| < {rs.tolerance:.3g}× its on-manifold mean"


def _intersection(rs: RelationSet) -> str:
    return "g" + "∩g".join(str(k + 1) for k in range(rs.num_relations))


def manifold_points(rs: RelationSet, low, high, key, n_points=2000):
    """Uniform box points moved onto g_1 = … = g_K = 0; returns (points [M, D] that converged
    and stayed in the box, M / n_points)."""
    low, high = np.asarray(low), np.asarray(high)
    start = jax.random.uniform(key, (n_points, low.shape[0]), minval=low, maxval=high)
    max_step = 0.1 * float(np.linalg.norm(high - low))
    points, _, converged = project(rs, start, steps=PROJECTION_STEPS, max_step=max_step)
    points = np.asarray(points)
    ok = np.asarray(converged) & np.all((points >= low) & (points <= high), -1)
    return points[ok], float(ok.mean())


def nearest_distances(points: np.ndarray, reference: np.ndarray, chunk=512) -> np.ndarray:
    """[M]: Euclidean distance from each point to its nearest reference row."""
    out = [np.min(np.linalg.norm(points[i:i + chunk, None] - reference[None], axis=-1), 1)
           for i in range(0, len(points), chunk)]
    return np.concatenate(out) if out else np.zeros((0,))


def _caption(fig: Figure, text: str, height: float):
    FigureCanvasAgg(fig)
    fig.text(0.01, 0.01, text, fontsize=8, va="bottom", ha="left", wrap=True)
    fig.tight_layout(rect=(0, height, 1, 1))


def plot_zero_sets_3d(rs: RelationSet, on: np.ndarray, path, key=None, names=("x", "y", "z"),
                      note: str = ""):
    """Fig. 5: on-manifold data, the learned manifold (points projected onto it, the data in grey
    beside), and each relation's zero-level set; a caption in the figure. Returns the path."""
    key = jax.random.key(0) if key is None else key
    low, high = _box(on, 1.2)
    manifold, share = manifold_points(rs, low, high, key)
    singles = [
        manifold_points(rs.select([k]), low, high, jax.random.fold_in(key, k + 1))[0]
        for k in range(rs.num_relations)
    ]
    near = nearest_distances(manifold, on)
    diag = float(np.linalg.norm(high - low))
    titles = ["on-manifold data", f"{_intersection(rs)} (projected)"] + [
        f"g{k + 1} = 0" for k in range(rs.num_relations)
    ]
    ncols = len(titles)
    fig = Figure(figsize=(3.3 * ncols, 4.3))
    for i, (points, title) in enumerate(zip([on, manifold, *singles], titles, strict=True)):
        ax = fig.add_subplot(1, ncols, i + 1, projection="3d")
        if i == 1:
            ax.scatter(*on[:400].T[:3], s=0.3, c="0.7")
        if len(points):
            ax.scatter(*points.T[:3], s=4 if i == 1 else 1, c=points[:, 2], cmap="viridis")
        ax.set(xlim=(low[0], high[0]), ylim=(low[1], high[1]), zlim=(low[2], high[2]),
               xlabel=names[0], ylabel=names[1], zlabel=names[2])
        ax.set_title(f"{title}\n{len(points)} pts", fontsize=9)
    median = float(np.median(near)) if len(near) else float("nan")
    p90 = float(np.quantile(near, 0.9)) if len(near) else float("nan")
    caption = (
        f"Box: the data's range × 1.2 per axis (diagonal {diag:.2f}). Panel 2: 2,000 uniform box "
        f"points moved onto {{{_intersection(rs)} = 0}} by {PROJECTION_STEPS} damped Gauss-Newton "
        f"steps; {100 * share:.0f}% converged inside the box ({_converging(rs)}), drawn "
        "coloured by the 3rd coordinate over 400 data points (grey). "
        f"Agreement with the data: distance from a projected point to the nearest of "
        f"{len(on)} data points, median {median:.3f}, 90th percentile {p90:.3f} "
        f"({100 * median / diag:.1f}% / {100 * p90 / diag:.1f}% of the diagonal); points on the "
        "data have ≈ 0 (the data's own spacing). Other panels: each relation's zero-level "
        f"set, drawn the same way (2,000 box points projected onto g_k = 0). {note}"
    )
    _caption(fig, caption, 0.17)
    fig.subplots_adjust(top=0.9)
    _save(fig, path)
    return Path(path)


def _arrows(ax, tau: np.ndarray, title: str, limits, scale, color=True):
    """Arrows from (s0, v0) to (s1, v1) (the change after one step), `scale` × their length."""
    ax.set_title(title, fontsize=9)
    ax.set(xlim=limits[0], ylim=limits[1], xlabel="position", ylabel="velocity")
    if len(tau) == 0:
        return
    ds, dv = tau[:, 2] - tau[:, 0], tau[:, 3] - tau[:, 1]
    style = dict(angles="xy", scale_units="xy", scale=1.0, width=0.004)
    if color:
        ax.quiver(tau[:, 0], tau[:, 1], ds * scale, dv * scale, np.arctan2(dv, ds), cmap="brg",
                  alpha=0.7, **style)
    else:
        ax.quiver(tau[:, 0], tau[:, 1], ds * scale, dv * scale, color="0.75", **style)


def _arrow_scale(tau: np.ndarray, limits) -> float:
    """Arrows scaled to fit (as the paper does): the longest data arrow spans a tenth."""
    span = np.hypot(limits[0][1] - limits[0][0], limits[1][1] - limits[1][0])
    longest = np.hypot(tau[:, 2] - tau[:, 0], tau[:, 3] - tau[:, 1]).max() if len(tau) else 1
    return 0.1 * span / max(longest, 1e-9)


def learned_transitions(rs: RelationSet, on: np.ndarray):
    """The learned next state for each row's start: (s1, v1) solved from g_1 = … = g_K = 0 with
    (s0, v0) held (`project` with free coordinates). Returns (rows [N, D], converged [N])."""
    on = np.asarray(on)
    start = on.copy()
    # Start the search from the data's mean change (the same for every row).
    start[:, 2:4] = on[:, 0:2] + np.mean(on[:, 2:4] - on[:, 0:2], axis=0)
    free = np.zeros(on.shape[-1], bool)
    free[2:4] = True
    max_step = 0.1 * float(np.linalg.norm(on.max(0) - on.min(0)))
    points, _, converged = project(rs, start, steps=PROJECTION_STEPS, free=free,
                                   max_step=max_step)
    return np.asarray(points), np.asarray(converged)


def plot_phase_space(rs: RelationSet, on_by_range: dict, path, key=None, note: str = ""):
    """Fig. 7: per range (training, wider), on-manifold arrows, the learned manifold's arrows
    (next state solved from the relations for the data's starts, the data's in grey beneath),
    and each relation's zero-level set; a caption in the figure. τ = (s0, v0, s1, v1, …)."""
    key = jax.random.key(0) if key is None else key
    ncols = 2 + rs.num_relations
    fig = Figure(figsize=(3.3 * ncols, 3.3 * len(on_by_range) + 1.0))
    axes = fig.subplots(len(on_by_range), ncols, squeeze=False)
    lines = []
    for row, (label, on) in enumerate(on_by_range.items()):
        on = np.asarray(on)[:ARROWS]
        low, high = _box(np.asarray(on_by_range[label]))
        limits = ((low[0], high[0]), (low[1], high[1]))
        scale = _arrow_scale(on, limits)
        learned, ok = learned_transitions(rs, on)
        err = np.linalg.norm(learned[:, 2:4] - on[:, 2:4], axis=-1)
        step = np.linalg.norm(on[:, 2:4] - on[:, 0:2], axis=-1)
        k = jax.random.fold_in(key, row)
        singles = [
            level_set_points(rs, low, high, jax.random.fold_in(k, j + 1), which=[j])[:ARROWS]
            for j in range(rs.num_relations)
        ]
        _arrows(axes[row, 0], on, f"on-manifold, {label}", limits, scale)
        _arrows(axes[row, 1], on, "", limits, scale, color=False)
        _arrows(axes[row, 1], learned[ok], f"{_intersection(rs)} (solved), {label}\n"
                f"{ok.sum()}/{len(on)} converged", limits, scale)
        for j, pts in enumerate(singles):
            _arrows(axes[row, 2 + j], pts, f"g{j + 1} = 0, {label}\n{len(pts)} pts", limits,
                    scale)
        lines.append(
            f"{label}: error of the solved next state (s1, v1) against the data's, median "
            f"{np.median(err):.3f} over all {len(on)} starts, "
            + (f"{np.median(err[ok]):.3f} over the converged ({np.quantile(err[ok], 0.9):.3f} "
               "90th percentile)" if ok.any() else "none converged")
            + f"; median true change {np.median(step):.3f}."
        )
    caption = (
        "Arrows: (s0, v0) → (s1, v1), the change in position and velocity after 1 s, scaled to "
        "fit (the same scale within a row). Column 2: for each data row's start (s0, v0) the "
        f"next state solved from {{{_intersection(rs)} = 0}} ({PROJECTION_STEPS} damped "
        "Gauss-Newton steps on (s1, v1) only, from (s0, v0) + the data's mean change); "
        f"'converged': {_converging(rs)}. The data's own arrows in grey beneath: agreement "
        f"means coloured arrows covering grey ones. Other columns: box points where "
        f"{_one_holds(rs)}.\n"
        + "\n".join(lines)
        + (f"\n{note}" if note else "")
    )
    _caption(fig, caption, 0.9 / (3.3 * len(on_by_range) + 1.0) + 0.02 * len(lines))
    _save(fig, path)
    return Path(path)


def _save(fig: Figure, path) -> None:
    """Renders with the Agg canvas (no pyplot, no global backend) and writes a 256-colour PNG
    (a third of the RGBA file's size, for figures kept in the repository)."""
    FigureCanvasAgg(fig)
    buffer = io.BytesIO()
    fig.savefig(buffer, dpi=80)
    buffer.seek(0)
    image = Image.open(buffer).convert("RGB")
    image.quantize(256, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
