"""Is the learned zero set the data's? Measured on rows kept out of training.

`assess` is the report every fit carries (`RelationSet.quality`): per relation, whether it met
the stopping rule and how well it separates held-out on-manifold rows from off-manifold ones;
whether the relations are independent (the rank of their Jacobian, the angles between their
gradients); where points of the data's box land when projected onto {g = 0} (on the data, on its
continuation past the sample's edge, or on spurious parts of the zero set away from it); and
how `holds` does on held-out rows.
"""

from __future__ import annotations

import logging

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial import cKDTree

from jaml.configs.relations import Config
from jaml.relations.geometry import independence, project
from jaml.relations.relation_set import (
    RelationSet,
    Report,
    distances,
    evaluate,
    holds,
    holds_measure,
)

log = logging.getLogger("jaml.relations")

BOX_POINTS = 512  # box points projected to see where the zero set lies
PROJECTION_STEPS = 50
LANDING_FRACTION = 0.01  # "on the data": within this share of the box diagonal, ...
LANDING_SPACING = 3.0  # ... or this many times the data sample's own spacing, if larger
RECALL = 0.99  # `holds`' tolerance: this quantile of held-out rows' largest |g_k| / on-mean
DEPENDENT_COS = 0.9  # a pair of relations whose gradients' median |cos| exceeds this: dependent
SPURIOUS = 0.1  # warn when more than this share of converged box points lands off the data
UNCONVERGED = 0.1  # warn when more than this share of projected box points reaches no zero
SPARSE = 0.1  # warn when the landing distance exceeds this share of the box diagonal
FAR_ACCEPTED = 0.1  # warn when `holds` accepts more than this share of box rows far from the data
BY_LOCAL_PCA = "by local PCA"  # where the report's data codimension came from, when estimated
# A direction across the rows scattered more than this share of the box diagonal, and more than
# BAND_RATIO times the tightest direction, is a band the rows fill, not a relation.
BAND_SCATTER = 1e-3
BAND_RATIO = 10.0
TANGENT_NEIGHBOURS = 32  # rows of the local PCA that gives the data's tangent space at a row
TANGENT_RTOL = 0.2  # its directions: singular values above this share of the largest
COVER_ROWS = 1024  # data rows whose reach by the projected box points `landing` measures
COVERAGE = 0.5  # warn when those points reach less than this share of what as many rows reach


def nearest_distances(points, reference) -> np.ndarray:
    """[M]: Euclidean distance from each point [M, D] to its nearest row of reference [R, D]
    (a k-d tree: exact, and no program to compile)."""
    return cKDTree(np.asarray(reference, np.float64)).query(np.asarray(points, np.float64))[0]


def landing_distance(reference, held_out, low, high) -> float:
    """The distance within which a projected point counts as on the data: a share of the box
    diagonal, or a multiple of how far held-out rows lie from the reference sample (a sparse
    sample of a manifold of dimension > 1 is farther apart), whichever is larger."""
    diag = float(np.linalg.norm(np.asarray(high) - np.asarray(low)))
    spacing = float(np.quantile(nearest_distances(held_out[:1024], reference), 0.95))
    return max(LANDING_FRACTION * diag, LANDING_SPACING * spacing)


def _uniform(key, n: int, low, high) -> np.ndarray:
    """[n, D] uniform points of the box, drawn by numpy from the JAX key (no program to
    compile for a draw made once)."""
    return _rng(key).uniform(low, high, (n, len(low))).astype(np.float32)


def _rng(key) -> np.random.Generator:
    return np.random.default_rng(np.asarray(jax.random.key_data(key)).ravel())


def data_codimension(rows, key, sample: int = 1024, queries: int = 256, neighbours: int = 32,
                     rtol: float = 0.2) -> int:
    """D minus the data's local dimension, by PCA of each of `queries` rows' `neighbours` nearest
    rows in a `sample` of rows [N, D]: the median count of singular values above rtol × the
    largest. The number of relations whose joint zero set can be the data (no fewer)."""
    rows = np.asarray(rows, np.float64)
    rng = _rng(key)
    sub = rows[rng.permutation(rows.shape[0])[:sample]]
    query = sub[rng.permutation(sub.shape[0])[:queries]]
    _, idx = cKDTree(sub).query(query, k=min(neighbours, sub.shape[0]))
    local = sub[idx] - sub[idx].mean(axis=1, keepdims=True)  # [Q, k, D]
    s = np.linalg.svd(local, compute_uv=False)
    dims = (s > rtol * s[:, :1]).sum(-1)
    return int(rows.shape[1] - np.median(dims))


def separation_floor(rows, codim: int, key, low, high, top_fraction: float = 0.2,
                     sample: int = 4096, queries: int = 1024) -> dict:
    """How far the rows [N, D] scatter across the manifold they sample, and so the stopping
    statistic (mean |g| on box rows over the mean of the largest `top_fraction` of |g| on the
    data) an exact relation, |g| = distance to the manifold, can reach on them.

    Each of `queries` rows' scatter is its offset across a local quadratic fit to its
    neighbourhood (the D − codim leading local-PCA directions as coordinates, the rest
    regressed on their quadratic polynomial): curvature is fitted away, noise is not. Box
    rows' distance to the manifold is their distance to the nearest row. Returns "across"
    (that top mean over the box diagonal) and "separation" (box mean over top mean)."""
    rows = np.asarray(rows, np.float64)
    rng = _rng(key)
    sub = rows[rng.permutation(rows.shape[0])[:sample]]
    width = sub.shape[1]
    tree = cKDTree(sub)
    design, across, beta = _quadratic_patches(sub, tree, codim, queries)
    scatter = np.linalg.norm(across[:, 0] - np.einsum("mp,mpc->mc", design[:, 0], beta), axis=-1)
    top = np.sort(scatter)[::-1][: max(1, int(top_fraction * scatter.size))].mean()
    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    box = rng.uniform(low, high, (sample, width))
    off = float(tree.query(box)[0].mean())
    diag = float(np.linalg.norm(high - low))
    return {"across": float(top) / diag, "separation": off / max(float(top), 1e-12 * diag)}


def _quadratic_patches(sub, tree: cKDTree, codim: int, queries: int):
    """The local quadratic fits of the first `queries` rows' neighbourhoods in `sub` [N, D]:
    (design [M, k, P], across [M, k, codim], beta [M, P, codim]) with the D − codim leading
    local-PCA directions as coordinates and the other ones (largest first) regressed on their
    quadratic polynomial; a row is its neighbourhood's first."""
    n, width = sub.shape
    dim = max(width - codim, 0)
    terms = 1 + dim + dim * (dim + 1) // 2
    k = min(max(TANGENT_NEIGHBOURS, 3 * terms), n)
    _, idx = tree.query(sub[:queries], k=k)  # each query row is its own nearest neighbour
    patch = sub[idx]
    centred = patch - patch.mean(axis=1, keepdims=True)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    local = np.einsum("mkd,mrd->mkr", centred, vt)  # [M, k, D] in the local PCA frame
    along, across = local[..., :dim], local[..., dim:]
    upper = np.triu_indices(dim)
    quadratic = (along[..., :, None] * along[..., None, :])[..., upper[0], upper[1]]
    design = np.concatenate([np.ones_like(along[..., :1]), along, quadratic], axis=-1)
    gram = np.einsum("mkp,mkq->mpq", design, design) + 1e-12 * np.eye(terms)
    beta = np.linalg.solve(gram, np.einsum("mkp,mkc->mpc", design, across))
    return design, across, beta


def band_directions(rows, codim: int, key, sample: int = 4096, queries: int = 1024) -> dict:
    """Of the `codim` directions across the rows [N, D], those that are thin but not exact: a
    band the rows fill, not a relation they keep to. Each direction's scatter is the median
    (over `queries` neighbourhoods of a `sample` of rows) of the RMS offset along it from a
    local quadratic fit, curvature fitted away, over the box diagonal; a direction is a band
    where its scatter exceeds BAND_SCATTER and BAND_RATIO × the tightest direction's (noise
    around a manifold scatters every direction alike). Returns {"scatter": [codim] ascending,
    "bands": how many}."""
    rows = np.asarray(rows, np.float64)
    sub = rows[_rng(key).permutation(rows.shape[0])[:sample]]
    design, across, beta = _quadratic_patches(sub, cKDTree(sub), codim, queries)
    residual = across - np.einsum("mkp,mpc->mkc", design, beta)
    diag = float(np.linalg.norm(rows.max(0) - rows.min(0)))
    scatter = np.sort(np.median(np.sqrt((residual**2).mean(axis=1)), axis=0)) / max(diag, 1e-30)
    bands = (scatter > BAND_SCATTER) & (scatter > BAND_RATIO * scatter[0])
    return {"scatter": scatter.tolist(), "bands": int(bands.sum())}


def tangent_offsets(points, tree: cKDTree, nearest, dim: int | None = None) -> np.ndarray:
    """[M]: how far each point [M, D] lies off the data's tangent space at its nearest row
    (`nearest` [M], indices into the tree's rows): the part of its offset from that row's
    neighbourhood outside the neighbourhood's principal directions (local PCA): its `dim`
    leading ones (the data's dimension, where known), else those above TANGENT_RTOL × the
    largest singular value (on noisy rows the noise can pass that bar, and the tangent space
    then fills the neighbourhood)."""
    rows = tree.data
    _, idx = tree.query(rows[np.asarray(nearest)], k=min(TANGENT_NEIGHBOURS, len(rows)))
    patch = rows[idx]  # [M, k, D]
    centre = patch.mean(axis=1)
    _, sv, vt = np.linalg.svd(patch - centre[:, None], full_matrices=False)
    keep = (sv > TANGENT_RTOL * sv[:, :1]) if dim is None else np.arange(sv.shape[1]) < dim
    along = keep[..., None] * vt  # [M, r, D], unused rows zero
    offset = np.asarray(points, np.float64) - centre
    tangential = np.einsum("mrd,md->mr", along, offset)
    return np.sqrt(np.maximum((offset**2).sum(-1) - (tangential**2).sum(-1), 0.0))


def landing(relations, key, low, high, reference, within: float, n: int = BOX_POINTS,
            steps: int = PROJECTION_STEPS, tolerance: float = 1e-3,
            codim: int | None = None) -> dict:
    """Project n uniform points of the box [low, high] onto {g = 0}; where do they land?

    Returns (shares, spurious points [M, D], their distances [M]): the shares of the n points
    converged (every equation holds there) and, of those, landed, extends or spurious. A
    converged point is on the data's tangent space at its nearest reference row if within
    `LANDING_FRACTION` of the box diagonal of it (not `within`: a sparse sample widens the
    distance between rows along the data, not across it); landed if also within `within` of
    that row; extends if farther (the zero set going on past the sample's edge, as a plane
    goes on past the rows drawn of it); spurious if off the tangent space (a part of the zero
    set that is not the data's). `codim`: the data's codimension, which fixes the tangent
    space's dimension (else local PCA decides it, point by point). Also how much of the data
    the landed points reach (`coverage`): a zero set that is a few points of the data lands
    every point and reaches little of it.
    """
    low, high = np.asarray(low, np.float32), np.asarray(high, np.float32)
    start = _uniform(key, n, low, high)
    out = project(relations, start, steps=steps, bounds=(low, high), tolerance=tolerance)
    points = np.asarray(out.points, np.float64)
    tree = cKDTree(np.asarray(reference, np.float64))
    dist, nearest = tree.query(points)
    converged = np.asarray(out.converged)
    along = np.zeros_like(converged)
    if converged.any():
        across = LANDING_FRACTION * float(np.linalg.norm(high - low))
        dim = None if codim is None else max(points.shape[1] - codim, 0)
        along[converged] = tangent_offsets(points[converged], tree, nearest[converged],
                                           dim) <= across
    near = dist <= within
    spurious = converged & ~along
    landed = converged & along & near
    return {
        "points": n,
        "within": float(within),
        "converged": float(converged.mean()),
        "landed": float(landed.mean()),
        "extends": float((converged & along & ~near).mean()),
        "spurious": float(spurious.mean()),
        "median_distance": float(np.median(dist[converged])) if converged.any() else None,
        **coverage(points[landed], reference, within, n),
    }, np.asarray(out.points)[spurious], dist[spurious]


def coverage(points, reference, within: float, n: int) -> dict:
    """The share of COVER_ROWS data rows (`reference`'s first) within `within` of one of
    `points` [M, D] ("coverage"), and the share that n other rows of `reference` reach
    ("coverage_of_rows": what n points spread over the data as the data is reach). `reference`
    must be in random order (a fit's rows are shuffled before they are split), or both shares
    speak of one stretch of it."""
    reference = np.asarray(reference, np.float64)
    rows = min(COVER_ROWS, len(reference) // 2)
    targets, spread = reference[:rows], reference[rows:rows + n]

    def reached(by) -> float:
        return float((cKDTree(by).query(targets)[0] <= within).mean()) if len(by) else 0.0

    return {"coverage": reached(np.asarray(points, np.float64)),
            "coverage_of_rows": reached(spread)}


def on_data(land: dict) -> float:
    """The share of projected box points on the data or on its continuation (`landing`)."""
    return land["landed"] + land.get("extends", 0.0)


def calibrated_tolerance(rs: RelationSet, held_out) -> float:
    """`holds`' tolerance by value (and `project`'s converged) under which the RECALL quantile of
    held-out rows holds: recall ≈ RECALL on fresh rows by construction."""
    return float(np.quantile(np.asarray(holds_measure(rs, held_out, "value", 1.0)), RECALL))


def distance_tolerance(rs: RelationSet, rows) -> tuple[float, ...] | None:
    """`holds`' per-relation distance tolerances calibrated on `rows` (`joint_quantiles` of
    their `distances`); None where a relation is flat at more than 1 - RECALL of the rows (no
    finite distance: `holds` then goes by value)."""
    return joint_quantiles(np.asarray(distances(rs, rows)), RECALL)


def joint_quantiles(d, recall: float) -> tuple[float, ...] | None:
    """Per-column thresholds t [K] of d [N, K] that all of a `recall` share of its rows meet:
    each column's `recall` quantile, scaled by one factor until that share of rows is below
    every threshold at once. A wide column (a fuzzy relation) keeps its width to itself rather
    than widening a narrow one's; a single column gets its quantile. None where not finite."""
    d = np.asarray(d, np.float64)
    with np.errstate(invalid="ignore"):  # quantiles between infinite distances
        scale = np.quantile(d, recall, axis=0)
    if not np.all(np.isfinite(scale)):
        return None
    scale = np.maximum(scale, np.finfo(np.float32).tiny)
    with np.errstate(invalid="ignore"):
        factor = np.quantile(np.max(d / scale, axis=-1), recall)
    if not np.isfinite(factor):
        return None
    return tuple(float(t) for t in factor * scale)


def calibrated(rs: RelationSet, rows) -> RelationSet:
    """`rs` with both tolerances calibrated on `rows`."""
    return rs.replace(tolerance=calibrated_tolerance(rs, rows),
                      distance_tolerance=distance_tolerance(rs, rows))


def assess(rs: RelationSet, key, held_out, reference, low, high, statuses=(),
           data_codim: int | None = None, data_codim_from: str = BY_LOCAL_PCA,
           noise: dict | None = None, unexplained=()) -> Report:
    """The quality report of `rs` on held-out rows [H, D]; `reference` [R, D] are training rows
    (where "on the data" is measured), `statuses` each relation's end ("done" / "capped"),
    `noise` the rows' scatter and the stopping bar (`separation_floor`, with
    "separation_ratio"), `unexplained` the share of each relation a fresh restricted syzygy
    left unexplained (None where not judged)."""
    k_box, k_off = jax.random.split(key)
    k = rs.num_relations
    held_out = jnp.asarray(held_out)
    g_on = np.abs(np.asarray(evaluate(rs, held_out)))
    off = jnp.asarray(_uniform(k_off, held_out.shape[0], np.asarray(low), np.asarray(high)))
    g_off = np.abs(np.asarray(evaluate(rs, off)))
    relations = []
    for j in range(k):
        on_mean, off_mean = float(g_on[:, j].mean()), float(g_off[:, j].mean())
        relations.append({
            "index": j + 1,
            "status": statuses[j] if j < len(statuses) else "restored",
            "on_mean": on_mean,
            "off_mean": off_mean,
            "ratio": off_mean / max(on_mean, 1e-30),
        })
        if j < len(unexplained) and unexplained[j] is not None:
            relations[-1]["unexplained"] = float(unexplained[j])
    codim, cos = independence(rs, held_out[:2048])
    upper = cos[np.triu_indices(k, 1)]
    ranks = np.asarray(codim["rank_fractions"])
    within = landing_distance(reference, held_out, low, high)
    land, _, _ = landing(rs, k_box, low, high, reference, within, codim=data_codim)
    land["box_diagonal"] = float(np.linalg.norm(np.asarray(high) - np.asarray(low)))
    holds_on = float(np.mean(np.asarray(holds(rs, held_out))))
    accepted = np.asarray(holds(rs, off))
    far = nearest_distances(off, reference) > within  # box rows off the data for landing too
    report = {
        "held_out_rows": int(held_out.shape[0]),
        "relations": relations,
        "independence": {
            "rank_fractions": codim["rank_fractions"],
            "full_rank_fraction": codim["full_rank_fraction"],
            # The codimension the relations cut: the median rank of their Jacobian.
            "codimension": int(np.searchsorted(np.cumsum(ranks), 0.5)),
            "data_codimension": data_codim,
            "data_codimension_from": data_codim_from,
            "median_abs_cos": cos.tolist(),
            "max_pair_cos": float(upper.max()) if upper.size else None,
        },
        "landing": land,
        "holds": {"tolerance": rs.tolerance, "distance_tolerance": rs.distance_tolerance,
                  "recall": holds_on,
                  "off_acceptance": float(accepted.mean()),
                  "far_acceptance": float(accepted[far].mean()) if far.any() else 0.0},
    }
    if noise is not None:
        report["noise"] = {k: float(v) for k, v in noise.items()}
    return Report(relabelled(report))


def relabelled(report: dict) -> dict:
    """`report` with its warnings and lines written again from its numbers (after they change,
    e.g. into other units)."""
    report = {**report, "warnings": _warnings(report)}
    return {**report, "lines": _lines(report)}


def _bar_out_of_reach(report: dict) -> bool:
    """Whether the rows scatter so that an exact relation cannot meet the stopping rule."""
    noise = report.get("noise")
    return noise is not None and noise["separation"] < noise["separation_ratio"]


def _band_hint(report: dict, index: int) -> str:
    """For a capped g_index the local PCA asked for (at or below its estimate of the data's
    codimension): the fix where that direction of the rows is a thin band, not a relation (the
    estimate cannot tell them apart), else ""."""
    ind = report.get("independence", {})
    codim = ind.get("data_codimension")
    estimated = ind.get("data_codimension_from") == BY_LOCAL_PCA
    if not estimated or codim is None or not 1 < index <= codim:
        return ""
    return (f"; the data's codimension {codim} is the local PCA's estimate: if the rows only "
            f"keep near a surface there (a band, not a relation), set "
            f"Config.codimension={index - 1}")


def _warnings(report: dict) -> list[str]:
    out = []
    noisy = _bar_out_of_reach(report)
    bar = report.get("noise", {}).get("separation_ratio", Config.separation_ratio)
    for r in report["relations"]:
        if r["status"] not in ("done", "restored"):  # restored: its end is not known here
            out.append(f"g{r['index']} {r['status']}: it did not meet the stopping rule "
                       f"(held-out off/on {r['ratio']:.1f}"
                       + ("; out of reach on these rows, see noise)" if noisy
                          else ")" + _band_hint(report, r["index"])))
        if "unexplained" in r and r["unexplained"] * bar < 1:  # `fit_syzygy`'s test
            out.append(f"g{r['index']} is a restricted syzygy of the earlier relations: a "
                       f"fresh syzygy network explains all but {100 * r['unexplained']:.0f}% "
                       f"of it (not new; {100 / bar:.0f}% would be)")
    cos = np.asarray(report["independence"]["median_abs_cos"])
    for i, j in zip(*np.triu_indices(len(cos), 1), strict=True):
        if cos[i, j] > DEPENDENT_COS:
            out.append(f"g{i + 1} and g{j + 1} are tangent on the data (dependent to first "
                       f"order): their gradients' median |cos| on held-out rows is "
                       f"{cos[i, j]:.2f}")
    land = report["landing"]
    if land["within"] > SPARSE * land.get("box_diagonal", np.inf):
        share = 100 * land["within"] / land["box_diagonal"]
        out.append(f"the rows are sparse for their box: a point counts as on the data within "
                   f"{land['within']:.3g} of a row, {share:.0f}% of the box diagonal, so the "
                   "landing shares are loose (more rows tighten them)")
    if land["converged"] > 0 and land["spurious"] > SPURIOUS * land["converged"]:
        out.append(f"the zero set has parts away from the data: {100 * land['spurious']:.0f}% of "
                   f"projected box points land on it farther than {land['within']:.3g} from "
                   f"the data")
    if "coverage" in land and land["coverage"] < COVERAGE * land["coverage_of_rows"]:
        out.append(f"the landed points reach {100 * land['coverage']:.0f}% of the data's rows, "
                   f"where as many of its own rows reach {100 * land['coverage_of_rows']:.0f}%: "
                   "the zero set is smaller than the data (a relation vanishes on part of it, "
                   "or two near-coincident relations cut it)")
    hold = report.get("holds", {})
    far = hold.get("far_acceptance", 0.0)
    if far > FAR_ACCEPTED:
        knob = "tolerance" if hold.get("distance_tolerance") is None else "distance_tolerance"
        out.append(f"holds accepts {100 * far:.0f}% of box rows farther than "
                   f"{land['within']:.3g} from the data: the relations stay near zero there "
                   f"(a lower `{knob}` rejects more of them, at some recall)")
    if 1 - land["converged"] > UNCONVERGED:
        out.append(f"{100 * (1 - land['converged']):.0f}% of projected box points reach no zero "
                   "of the relations: `project` leaves them where the relations cannot all "
                   "vanish (a relation level but not zero away from the data), with converged "
                   "False")
    return out


def _within(tolerances) -> str:
    """Per-relation distance tolerances in words (one number, from reports written before
    them)."""
    if not isinstance(tolerances, list | tuple):
        return f"{tolerances:.3g} of every relation's zero set"
    if len(set(tolerances)) == 1:
        return f"{tolerances[0]:.3g} of every relation's zero set"
    return ", ".join(f"{t:.3g} of g{k + 1}'s" for k, t in enumerate(tolerances)) + " zero set"


def _lines(report: dict) -> list[str]:
    rel = "; ".join(f"g{r['index']} {r['status']} off/on {r['ratio']:.1f}"
                    + (f", {100 * r['unexplained']:.0f}% unexplained by a syzygy"
                       if "unexplained" in r else "")
                    for r in report["relations"])
    ind, land, hold = report["independence"], report["landing"], report["holds"]
    lines = [
        f"quality on {report['held_out_rows']} held-out rows: {rel}",
        f"independence: rank {len(ind['median_abs_cos'])} on "
        f"{100 * ind['full_rank_fraction']:.0f}% of rows (codimension {ind['codimension']}"
        + (f"; the data's, {ind.get('data_codimension_from', BY_LOCAL_PCA)}: "
           f"{ind['data_codimension']}" if ind.get("data_codimension") is not None else "")
        + "), "
        + (f"largest pairwise median |cos| {ind['max_pair_cos']:.2f}"
           if ind["max_pair_cos"] is not None else "one relation"),
        f"projection: {100 * land['landed']:.0f}% of {land['points']} box points land on the "
        f"data (within {land['within']:.3g}), "
        + (f"{100 * land['extends']:.0f}% on its continuation past the sample's edge, "
           if land.get("extends") else "")
        + f"{100 * land['spurious']:.0f}% on spurious zeros, "
        f"{100 * (1 - land['converged']):.0f}% not converged"
        + (f"; they reach {100 * land['coverage']:.0f}% of the data's rows (as many of its "
           f"rows reach {100 * land['coverage_of_rows']:.0f}%)" if "coverage" in land else ""),
        f"holds: recall {100 * hold['recall']:.1f}% of held-out rows, accepts "
        f"{100 * hold['off_acceptance']:.1f}% of box rows"
        + (f" and {100 * hold['far_acceptance']:.1f}% of the box rows farther than "
           f"{land['within']:.3g} from the data" if "far_acceptance" in hold else "")
        + (f" (tolerance {hold['tolerance']:.3g})" if hold.get("distance_tolerance") is None
           else f" (within {_within(hold['distance_tolerance'])}, to first order)"),
    ]
    if _bar_out_of_reach(report):
        noise = report["noise"]
        lines.append(f"noise: the rows scatter {100 * noise['across']:.2g}% of the box diagonal "
                     f"across their manifold; an exact relation separates them only "
                     f"{noise['separation']:.1f}x, below the stopping bar "
                     f"({noise['separation_ratio']:g}), so a capped relation is expected")
    return lines + [f"warning: {w}" for w in report["warnings"]]


__all__ = [
    "assess",
    "band_directions",
    "calibrated",
    "calibrated_tolerance",
    "coverage",
    "data_codimension",
    "distance_tolerance",
    "joint_quantiles",
    "landing",
    "landing_distance",
    "nearest_distances",
    "on_data",
    "relabelled",
    "separation_floor",
    "tangent_offsets",
]
