"""Figures like the paper's: zero-level sets of learned relations (Fig. 5) and phase space (Fig. 7).

A relation's zero-level set is drawn as the box points where |g_k| is within tolerance × its
recorded on-manifold mean; the learned manifold (g_1 ∩ … ∩ g_K) as the points where all are.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from jaml.relations.relation_set import RelationSet, evaluate


def level_set_points(rs: RelationSet, low, high, key, which=None, n_points=2500, rounds=20):
    """Uniform box points where the chosen relations (all if `which` is None) hold.

    Rejection sampling in rounds of 10·n_points candidates until n_points are kept (the
    reference's visualisation filter). Returns float [M, D], M ≤ n_points.
    """
    which = list(range(rs.num_relations)) if which is None else list(which)
    low, high = jnp.asarray(low), jnp.asarray(high)
    limit = rs.tolerance * rs.on_means[jnp.asarray(which)]

    @jax.jit
    def candidates(key):
        tau = jax.random.uniform(key, (10 * n_points, low.shape[0]), minval=low, maxval=high)
        return tau, jnp.all(jnp.abs(evaluate(rs, tau)[..., jnp.asarray(which)]) < limit, axis=-1)

    kept = []
    for r in range(rounds):
        tau, ok = jax.device_get(candidates(jax.random.fold_in(key, r)))
        kept.append(tau[ok])
        if sum(len(k) for k in kept) >= n_points:
            break
    return np.concatenate(kept)[:n_points]


def _box(on: np.ndarray, scale=1.0):
    centre, half = (on.max(0) + on.min(0)) / 2, (on.max(0) - on.min(0)) / 2
    return centre - scale * half, centre + scale * half


def _titles(rs: RelationSet):
    return ["g" + "∩g".join(str(k + 1) for k in range(rs.num_relations))] + [
        f"g{k + 1} = 0" for k in range(rs.num_relations)
    ]


def plot_zero_sets_3d(rs: RelationSet, on: np.ndarray, path, key=None, names=("x", "y", "z")):
    """Fig. 5: on-manifold data, the learned intersection, and each relation's zero-level set."""
    key = jax.random.key(0) if key is None else key
    low, high = _box(on, 1.2)
    sets = [level_set_points(rs, low, high, key)] + [
        level_set_points(rs, low, high, jax.random.fold_in(key, k + 1), which=[k])
        for k in range(rs.num_relations)
    ]
    titles = ["on-manifold data", *_titles(rs)]
    fig = Figure(figsize=(4 * len(titles), 4.2))
    for i, (points, title) in enumerate(zip([on, *sets], titles, strict=True)):
        ax = fig.add_subplot(1, len(titles), i + 1, projection="3d")
        if len(points):
            ax.scatter(
                points[:, 0], points[:, 1], points[:, 2], s=1, c=points[:, 2], cmap="viridis"
            )
        ax.set(
            xlim=(low[0], high[0]),
            ylim=(low[1], high[1]),
            zlim=(low[2], high[2]),
            xlabel=names[0],
            ylabel=names[1],
            zlabel=names[2],
        )
        ax.set_title(f"{title} ({len(points)} pts)")
    _save(fig, path)
    return Path(path)


def _arrows(ax, tau: np.ndarray, title: str, limits):
    """Arrows from (s0, v0) to (s1, v1): the change in position and velocity after one step."""
    ax.set_title(f"{title} ({len(tau)} pts)")
    ax.set(xlim=limits[0], ylim=limits[1], xlabel="position", ylabel="velocity")
    if len(tau) == 0:
        return
    tau = tau[:600]
    ds, dv = tau[:, 2] - tau[:, 0], tau[:, 3] - tau[:, 1]
    # Scale arrows to fit (as the paper does): the longest one spans a tenth of the axes.
    span = np.hypot((limits[0][1] - limits[0][0]), (limits[1][1] - limits[1][0]))
    scale = 0.1 * span / max(np.hypot(ds, dv).max(), 1e-9)
    ax.quiver(
        tau[:, 0],
        tau[:, 1],
        ds * scale,
        dv * scale,
        np.arctan2(dv, ds),
        cmap="brg",
        angles="xy",
        scale_units="xy",
        scale=1.0,
        width=0.004,
        alpha=0.6,
    )


def plot_phase_space(rs: RelationSet, on_by_range: dict, path, key=None):
    """Fig. 7: per range (training, wider), on-manifold arrows, the learned intersection, and
    each relation's zero-level set. τ must be (s0, v0, s1, v1, …) time-major rows."""
    key = jax.random.key(0) if key is None else key
    ncols = 2 + rs.num_relations
    fig = Figure(figsize=(3.6 * ncols, 3.4 * len(on_by_range)))
    axes = fig.subplots(len(on_by_range), ncols, squeeze=False)
    for row, (label, on) in enumerate(on_by_range.items()):
        low, high = _box(np.asarray(on))
        limits = ((low[0], high[0]), (low[1], high[1]))
        k = jax.random.fold_in(key, row)
        sets = [level_set_points(rs, low, high, k)] + [
            level_set_points(rs, low, high, jax.random.fold_in(k, j + 1), which=[j])
            for j in range(rs.num_relations)
        ]
        titles = [f"on-manifold, {label}"] + [f"{t}, {label}" for t in _titles(rs)]
        for col, (tau, title) in enumerate(zip([np.asarray(on), *sets], titles, strict=True)):
            _arrows(axes[row, col], tau, title, limits)
    _save(fig, path)
    return Path(path)


def _save(fig: Figure, path) -> None:
    """Renders with the Agg canvas (no pyplot, no global backend) and writes the file."""
    FigureCanvasAgg(fig)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
