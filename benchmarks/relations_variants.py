"""Config variants of `relations.fit` side by side on 8 seeds, one single-threaded process a run.

A quick screen beside `relations_quality.py` (which runs the authors' code too): each run fits
the ellipse, the 45° block, the circle, the drag row, a noisy sphere ("sphere:STD", 4,000 rows)
or rows of the MJX incline ("incline:drawn|fixed", pools drawn here once, under runs/pools, for
machines without MuJoCo) with `relations.Config(seed=s, **variant)` and measures where 512
uniform box points land under `relations.project` at its defaults (distance to a 200,000-row
sample of the true manifold, share within 0.05; and, where a closed form knows the whole
manifold, its share within 0.05 of that), the Jacobian's rank ≥ 2 share on the data and the
quality report's statuses, off/on ratios, landing and warnings, and the fit's own log lines
(what it tried and kept). One JSON line per run on stdout, as each run ends.

    python3 benchmarks/relations_variants.py ellipse-defaults,sphere05-defaults --jobs 16
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

# Every source a screen of a default covers: its name prefix, source and Config fields.
EVERY_SOURCE = {
    "ellipse": ("ellipse", {"max_relations": 2}), "block": ("block45", {"max_relations": 2}),
    "circle": ("circle", {}), "drag": ("block-drag-range", {}),
    **{f"sphere{n}": (f"sphere:0.{n}", {}) for n in ("01", "02", "05")}}
VARIANTS = {  # name: (source, Config fields beside the seed)
    "ellipse-before": ("ellipse", {"max_relations": 2, "premine": False}),
    "ellipse-defaults": ("ellipse", {"max_relations": 2}),
    "block-before": ("block45", {"max_relations": 2, "premine": False}),
    "block-defaults": ("block45", {"max_relations": 2}),
    "ellipse-auto": ("ellipse", {}),
    # The unit circle (codimension 1): its one relation tried again from other starts while
    # its zero set has parts away from the data, or not (one attempt, as before 2026-11-29).
    "circle-defaults": ("circle", {}),
    "circle-one-attempt": ("circle", {"premine_attempts": 1}),
    # Fig. 7's bottom row, the incline drawn per row and not observed: codimension 1 too.
    "drag-defaults": ("block-drag-range", {}),
    "drag-one-attempt": ("block-drag-range", {"premine_attempts": 1}),
    # Attempts while more than 5 % of projected box points land on spurious zeros (10 %: the
    # default): a module constant, set in the worker ("module:NAME" keys).
    "ellipse-retry-5pct": ("ellipse", {"max_relations": 2,
                                       "jaml.relations.training:RETRY_SPURIOUS": 0.05}),
    "block-retry-5pct": ("block45", {"max_relations": 2,
                                     "jaml.relations.training:RETRY_SPURIOUS": 0.05}),
    "circle-retry-5pct": ("circle", {"jaml.relations.training:RETRY_SPURIOUS": 0.05}),
    "drag-retry-5pct": ("block-drag-range", {"jaml.relations.training:RETRY_SPURIOUS": 0.05}),
    # 4,000 rows of the unit sphere in R³ with Gaussian noise of this std per coordinate (a
    # first user's data).
    **{f"sphere{n}-defaults": (f"sphere:0.{n}", {}) for n in ("01", "02", "05")},
    # Retries from another start without the −log‖∇g‖ cap (as before 2026-11-29).
    "sphere02-uncapped-retry": ("sphere:0.02", {"jaml.relations.training:RETRY_GRADIENT_CAP":
                                                None}),
    # The paper's −log‖∇g‖ pushing only while ‖∇g‖ < 0.1 (the reference's floor at B = 1024).
    **{f"{name}-gradcap": (source, fields | {"gradient_cap": 0.1})
       for name, (source, fields) in EVERY_SOURCE.items()},
    # The whole fit at a smaller step (Adam's 1e-3 → 3e-4), its first starts included.
    **{f"{name}-lr3e4": (source, fields | {"learning_rate": 3e-4})
       for name, (source, fields) in EVERY_SOURCE.items()},
    # Starts not tried again for separation once they reach half the noise floor (screened
    # while off; the default since, so now the same fits as X-defaults).
    **{f"{name}-retry-floor": (source, fields | {"jaml.relations.training:RETRY_FLOOR_SHARE": 0.5})
       for name, (source, fields) in EVERY_SOURCE.items()},
    "ellipse-premine-12k": ("ellipse", {"max_relations": 2, "premine_steps": 12_500}),
    "ellipse-premine-25k": ("ellipse", {"max_relations": 2, "premine_steps": 25_000}),
    "ellipse-attempts-5": ("ellipse", {"max_relations": 2, "premine_attempts": 5}),
    "ellipse-patience-2k": ("ellipse", {"max_relations": 2, "mined_patience": 2000}),
    "ellipse-run-out": ("ellipse", {"max_relations": 2, "mined_patience": None}),
    "block-run-out": ("block45", {"max_relations": 2, "mined_patience": None}),
    # Restricted syzygies from g_2 on (the paper): its rounds against a frozen f, and f trained
    # alongside g_k.
    **{name: (source, fields | {"max_relations": 3, "independence": "syzygy",
                                "transversal_first": False})
       for name, (source, fields) in {
           "syz-rounds": ("ellipse", {}),
           "syz-joint": ("ellipse", {"syzygy_training": "joint"}),
           "syz-rounds-n05": ("ellipse", {"noise_scale": 0.05}),
           "syz-joint-n05": ("ellipse", {"syzygy_training": "joint", "noise_scale": 0.05}),
           "block-syz-rounds": ("block45", {}),
           "block-syz-joint": ("block45", {"syzygy_training": "joint"})}.items()},
    # Syzygy fits as they default now: transversality up to the data's codimension, syzygies
    # beyond it; and three relations asked of a transversality fit.
    **{name: (source, {"max_relations": 3, **fields}) for name, (source, fields) in {
        "syz-defaults": ("ellipse", {"independence": "syzygy"}),
        "syz-joint-defaults": ("ellipse", {"independence": "syzygy",
                                           "syzygy_training": "joint"}),
        "syz-defaults-n05": ("ellipse", {"independence": "syzygy", "noise_scale": 0.05}),
        "block-syz-defaults": ("block45", {"independence": "syzygy"}),
        "ellipse-3": ("ellipse", {}),
        "block-3": ("block45", {})}.items()},
    # Two relations by transversality under the paper's training noise: what syzygy mode's
    # noisy rows stand against.
    "ellipse-n05": ("ellipse", {"max_relations": 2, "noise_scale": 0.05}),
    "ellipse-n02": ("ellipse", {"max_relations": 2, "noise_scale": 0.02}),
    # Rows of the MJX GeomOnIncline env under random pushes (Fig. 9's source and its `DYNAMICS`):
    # mass and friction drawn per reset (codimension 1: the kinematic relation) or fixed (2: the
    # dynamics too).
    "incline-drawn-defaults": ("incline:drawn", {}),
    "incline-fixed-defaults": ("incline:fixed", {}),
    "incline-drawn-codim1": ("incline:drawn", {"codimension": 1}),
    # The authors' code on the same rows (`peers/aml_reference.py`, its defaults, two relations
    # by transversality, under a wall-clock budget): "reference" holds its options.
    **{f"incline-{d}-reference": (f"incline:{d}", {"reference": {"max_relations": 2,
                                                                 "budget_s": 450}})
       for d in ("drawn", "fixed")},
    # The authors' code on the codimension-1 sources, asked for the one relation each has (their
    # code does not find the codimension itself): the circle and the drag row on a pool of
    # `REFERENCE_POOL` rows drawn from jaml's source, the noisy spheres on their 4,000 rows.
    **{f"{name}-reference": (EVERY_SOURCE[name][0], {"reference": {"max_relations": 1,
                                                                   "budget_s": 300}})
       for name in ("circle", "drag", "sphere01", "sphere02", "sphere05")},
    # The same hand-over on the ellipse, whose own source theirs has (`relations_quality.py`
    # runs that): a check that rows handed over as a file train their code as its own source.
    "ellipse-rows-reference": ("ellipse", {"reference": {"max_relations": 2, "budget_s": 420}}),
}
# The unit circle in other units ("moved:SCALE:CENTRE": its rows times SCALE plus CENTRE in every
# column), jaml at its defaults and the authors' code asked for its one relation; measured in
# the unit circle's own units, as the circle's rows are.
MOVES = {"x1000": (1000.0, 0.0), "plus1000": (1.0, 1000.0), "x0.001": (0.001, 0.0),
         "plus5": (1.0, 5.0)}
VARIANTS |= {f"circle-{move}{peer}": (f"moved:{scale:g}:{centre:g}", fields)
             for move, (scale, centre) in MOVES.items()
             for peer, fields in (("", {}), ("-reference",
                                             VARIANTS["circle-reference"][1]))}
# Rows 3-6 half-sides out fitted as given (`units.FAR` before 2026-12-02) against centred.
VARIANTS |= {"block-far6": ("block45", {"max_relations": 2, "jaml.relations.units:FAR": 6.0}),
             "circle-plus5-far6": ("moved:1:5", {"jaml.relations.units:FAR": 6.0})}
REFERENCE_POOL = 131_072  # rows a sampled source hands the authors' code (the incline pools' size)
# The incline pools: drawn once with MJX (`main`, before any worker starts) and read by the
# workers as file sources, so that a machine without MuJoCo runs the fits with them carried.
POOLS = Path(__file__).resolve().parent.parent / "runs" / "pools"
THREADS = {"JAX_PLATFORMS": "cpu", "OMP_NUM_THREADS": "1",
           "XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"}


class _FitLog(logging.Handler):
    """The fit's own log lines (what it tried and kept), for the run's record."""

    def __init__(self):
        super().__init__(logging.INFO)
        self.lines = []

    def emit(self, record):
        self.lines.append(record.getMessage())


def one(source_name: str, seed: int, fields: dict, keep: str | None = None) -> dict:
    """Fit and measure one run (in this process); a field "module:NAME" sets that module
    constant first instead of a Config field. `keep`: a directory the fitted relations are
    saved to (`relations.save`)."""
    import importlib

    import jax
    import numpy as np

    for key in [k for k in fields if ":" in k]:
        module, _, name = key.partition(":")
        setattr(importlib.import_module(module), name, fields.pop(key))

    from jaml import relations, sources

    sys.path.insert(1, str(Path(__file__).resolve().parent))  # after the jaml imported
    from relations_quality import syzygy_unexplained

    source = (_noisy_sphere(source_name) or _incline_pool(source_name) or _moved(source_name)
              or sources.make(source_name))
    dense = np.asarray(source.sample(jax.random.key(99), 200_000))
    low, high = dense.min(0), dense.max(0)
    # What the landing is measured in: the source's own units, the unit circle's for a moved one.
    to_unit, measured_as = getattr(source, "to_unit", None), getattr(source, "base", source_name)
    started = time.perf_counter()
    summaries, fit_log = [], _FitLog()
    logging.getLogger("jaml.relations").addHandler(fit_log)
    logging.getLogger("jaml.relations").setLevel(logging.INFO)

    def kept(_, summary):  # a relation reported again replaces it and those after it
        summaries[summary.index - 1:] = [summary]

    reference = fields.pop("reference", None)
    peer = {}
    if reference is not None:
        rs, peer = _reference_fit(source, seed, reference, (low, high), keep)
    else:
        rs = relations.fit(source, relations.Config(seed=seed, **fields), on_relation=kept)
    fit_s = time.perf_counter() - started
    logged = list(fit_log.lines)
    if keep is not None and rs is not None and reference is None:
        relations.save(rs, keep)
    if rs is None or rs.num_relations == 0:  # the fit found none: nothing lands anywhere
        return {"seed": seed, "fit_s": fit_s, "relations": 0, "landed": 0.0, "on_truth": 0.0,
                "status": [], "off_on": [], "log": logged, **peer}
    if reference is not None:  # their relations carry no quality report: their own record
        return {"seed": seed, "fit_s": fit_s, "relations": rs.num_relations, **peer,
                **_landing(rs, measured_as, dense, low, high, seed, to_unit),
                "holds_by": _holds_by(rs, source, dense, None)}
    report = rs.quality.to_dict() if rs.quality is not None else {}
    return {"seed": seed, "fit_s": fit_s, "relations": rs.num_relations,
            "holds_by": _holds_by(rs, source, dense, report.get("landing")),
            **_landing(rs, measured_as, dense, low, high, seed, to_unit),
            "noise": report.get("noise"), "holds": report.get("holds"),
            "report_landing": report.get("landing"), "warnings": report.get("warnings"),
            "cos": report.get("independence", {}).get("median_abs_cos"),
            # A syzygy fitted after each relation: its residual as a share of mean |g_k|.
            "syzygy_unexplained": [[round(r["residual"] / max(r["g_scale"], 1e-30), 3)
                                    for r in s.syzygy_rounds] for s in summaries],
            "unexplained": syzygy_unexplained(rs, source, seed, report.get("relations", []),
                                              relations.Config(**fields).syzygy_steps),
            "status": [r["status"] for r in report.get("relations", [])],
            "off_on": [round(r["ratio"], 1) for r in report.get("relations", [])],
            "log": logged}


def _landing(rs, source_name: str, dense, low, high, seed: int, to_unit=None) -> dict:
    """Where 512 uniform points of the data's box land under `relations.project` at its
    defaults: the share within 0.05 of the data's sample, and of the truth where known; the
    Jacobian's rank ≥ 2 share on the data. `to_unit`: rows of a moved source → the unit
    circle's units, where the distances are measured."""
    import numpy as np
    from scipy.spatial import cKDTree

    from jaml import relations

    box = np.random.default_rng(seed).uniform(low, high, (512, dense.shape[1]))
    points = np.asarray(relations.project(rs, box.astype(np.float32)).points)
    ranks, _ = relations.jacobian_ranks(rs, dense[:2048].astype(np.float32))
    if to_unit is not None:
        points, dense = to_unit(points), to_unit(dense)
    distance = cKDTree(dense).query(points)[0]
    truth = _truth(source_name, points)
    out = {"landed": float(np.mean(distance < 0.05)), "rank2": float(np.mean(ranks >= 2)),
           "on_truth": None if truth is None else float(np.mean(truth < 0.05)),
           "truth_median": None if truth is None else float(np.median(truth))}
    if source_name.startswith("incline:"):  # the exact relation and the rows' reach apart
        plane, pool = _incline_truth(source_name, points, parts=True)
        out |= {"on_plane": float(np.mean(plane < 0.05)), "plane_median": float(np.median(plane)),
                "on_pool": float(np.mean(pool < 0.05))}
    return out


def _reference_fit(source, seed: int, options: dict, box, keep: str | None):
    """(RelationSet of their weights or None, their record's summary): the authors' code
    (`peers/aml_reference.py`) on the rows of a file source (of a sampled source, a pool of
    `REFERENCE_POOL` of its rows), `box` the data's (low, high)."""
    import tempfile

    sys.path.insert(1, str(Path(__file__).resolve().parent.parent))
    from benchmarks.peers import aml_reference

    out = Path(keep) if keep is not None else Path(tempfile.mkdtemp(prefix="aml-reference-"))
    path = getattr(source, "path", None)
    if path is None:  # a sampled source: one pool of its rows, the same for every seed
        import jax
        import numpy as np

        out.mkdir(parents=True, exist_ok=True)  # the pool beside their run, kept with it
        path = out / "rows.npy"
        np.save(path, np.asarray(source.sample(jax.random.key(0), REFERENCE_POOL), np.float32))
    record = aml_reference.fit(source=f"{aml_reference.ROWS}{path}", seed=seed, out=out,
                               **options)
    rs = (aml_reference.relation_set(record["npz"], bounds=box) if record["relations"]
          else None)
    return rs, {"status": [r["status"] for r in record["relations"]],
                "off_on": [round(r["off_on"], 1) for r in record["relations"]],
                "steps": [r["steps"] for r in record["relations"]],
                "cut": record["cut"], "train_error": record["train_error"]}


def _holds_by(rs, source, dense, landing) -> dict:
    """`relations.holds` by distance and by value on the same rows: the share of fresh data
    rows each accepts (recall), of 20,000 uniform points of the fit's box (off), of those
    farther than the report's landing distance from the data (far), and of fresh rows moved 1 %
    of the box diagonal in a random direction (near). By distance also with one tolerance for
    every relation ("shared": the largest distance's quantile, as fits calibrated it before
    per-relation tolerances) beside the per-relation ones, both calibrated here on the same
    4,096 rows."""
    import jax
    import numpy as np
    from scipy.spatial import cKDTree

    from jaml import relations
    from jaml.relations import quality

    fresh = np.asarray(source.sample(jax.random.key(98), 4096), np.float32)
    low, high = np.asarray(rs.low), np.asarray(rs.high)
    rng = np.random.default_rng(97)
    box = rng.uniform(low, high, (20_000, len(low))).astype(np.float32)
    far = cKDTree(dense).query(box)[0] > landing["within"] if landing else np.ones(len(box), bool)
    step = rng.normal(size=fresh.shape)
    step *= 0.01 * np.linalg.norm(high - low) / np.linalg.norm(step, axis=1, keepdims=True)
    near = (fresh + step).astype(np.float32)
    ways = {"value": {"by": "value"}}
    if rs.distance_tolerance is not None:
        calib = np.asarray(relations.distances(rs, source.sample(jax.random.key(96), 4096)))
        shared = float(np.quantile(calib.max(-1), quality.RECALL))
        ways = {"distance": {"by": "distance"},
                "per_relation": {"by": "distance",
                                 "tolerance": quality.joint_quantiles(calib, quality.RECALL)},
                "shared": {"by": "distance", "tolerance": shared}, **ways}
    out = {}
    for name, how in ways.items():
        accepted = np.asarray(relations.holds(rs, box, **how))
        out[name] = {"recall": float(np.mean(np.asarray(relations.holds(rs, fresh, **how)))),
                     "off": float(accepted.mean()),
                     "far": float(accepted[far].mean()) if far.any() else 0.0,
                     "near": float(np.mean(np.asarray(relations.holds(rs, near, **how))))}
        if "tolerance" in how:
            out[name]["tolerance"] = how["tolerance"]
    return out


def _noisy_sphere(source_name: str):
    """"sphere:STD": 4,000 rows of the unit sphere in R³ plus Gaussian noise of that std per
    coordinate (the same rows for every seed), as a file source; None for other names."""
    if not source_name.startswith("sphere:"):
        return None
    import tempfile

    import numpy as np

    from jaml import sources

    rng = np.random.default_rng(7)
    rows = rng.normal(size=(4000, 3))
    rows /= np.linalg.norm(rows, axis=1, keepdims=True)
    rows += float(source_name.partition(":")[2]) * rng.normal(size=rows.shape)
    path = Path(tempfile.mkdtemp()) / "sphere.npy"
    np.save(path, rows.astype(np.float32))
    return sources.make(str(path))


class _MovedCircle:
    """The unit circle's rows times `scale` plus `centre` (every column); `to_unit` maps rows
    back."""

    base = "circle"

    def __init__(self, scale: float, centre: float):
        from jaml import sources

        self.circle, self.scale, self.centre = sources.make("circle"), scale, centre
        self.dim_names = self.circle.dim_names

    def sample(self, key, n: int):
        return self.circle.sample(key, n) * self.scale + self.centre

    def to_unit(self, rows):
        import numpy as np

        return (np.asarray(rows, np.float64) - self.centre) / self.scale


def _moved(source_name: str):
    """"moved:SCALE:CENTRE": the unit circle in other units (`_MovedCircle`); None for other
    names."""
    if not source_name.startswith("moved:"):
        return None
    _, scale, centre = source_name.split(":")
    return _MovedCircle(float(scale), float(centre))


def _incline_pool(source_name: str, seed: int = 0):
    """"incline:DYNAMICS": the pool of 131,072 GeomOnIncline rows `draw_pools` wrote (`seed` 1:
    a second pool, the truth's), as a file source; None for other names."""
    if not source_name.startswith("incline:"):
        return None
    from jaml import sources

    path = POOLS / f"{source_name.partition(':')[2]}-{seed}.npy"
    if not path.exists():
        raise FileNotFoundError(f"{path}: run this script here first with MuJoCo installed "
                                "(it draws the incline pools), then carry runs/pools")
    return sources.make(str(path))


def draw_pools(names: list[str]) -> None:
    """The incline pools the variants `names` read, drawn with MJX where missing: two of each
    dynamics (the training rows, and a second draw the landing is measured against), and the
    kinematic plane's slope in the rows' units, for the machines without MJX that read them."""
    for dynamics in sorted({VARIANTS[n][0].partition(":")[2] for n in names
                            if VARIANTS[n][0].startswith("incline:")}):
        files = [POOLS / f"{dynamics}-0.npy", POOLS / f"{dynamics}-1.npy",
                 POOLS / f"{dynamics}.json"]
        if all(f.exists() for f in files):  # carried: no MJX needed
            continue
        import jax
        import numpy as np

        from envs_mjx.domains import incline
        from jaml import sources
        from jaml.experiments.fig9 import DYNAMICS

        source = sources.make("geom-on-incline", **DYNAMICS[dynamics])
        POOLS.mkdir(parents=True, exist_ok=True)
        for seed in (0, 1):
            path = POOLS / f"{dynamics}-{seed}.npy"
            if not path.exists():
                rows = source.sample(jax.random.key(seed), source.pool_size)
                np.save(path.with_suffix(".tmp.npy"), np.asarray(rows, np.float32))
                path.with_suffix(".tmp.npy").replace(path)
        slope = source.dt * incline.VELOCITY_SCALE / incline.POSITION_SCALE
        (POOLS / f"{dynamics}.json").write_text(json.dumps({"slope": slope}))


def _incline_truth(source_name: str, points, parts: bool = False):
    """[N] distance of projected incline rows τ = (θ, s0, v0, a0, s1, v1) to what the env does:
    the larger of their distance to the kinematic plane s1 − s0 = dt·(v0 + v1)/2 (in the
    source's units; the rows keep to it up to the integrator's error) and of (θ, v0, a0, v1)
    to the nearest of a second pool's (the dynamics, where mass and friction are fixed; a band
    the rows fill, where they are drawn). `parts`: the two distances, (plane, pool)."""
    import numpy as np
    from scipy.spatial import cKDTree

    dynamics = source_name.partition(":")[2]
    c = json.loads((POOLS / f"{dynamics}.json").read_text())["slope"]
    points = np.asarray(points, np.float64)
    plane = np.abs(points[:, 4] - points[:, 1] - c * (points[:, 2] + points[:, 5]) / 2)
    plane /= np.sqrt(2 + c * c / 2)
    columns = [0, 2, 3, 5]
    rows = np.asarray(_incline_pool(source_name, seed=1).rows, np.float64)
    pool = cKDTree(rows[:, columns]).query(points[:, columns])[0]
    return (plane, pool) if parts else np.maximum(plane, pool)


def _truth(source_name: str, points):
    """[N] distance of projected points to the true manifold, where a closed form knows it
    (the data's sample ends at its box; the true block plane and circle do not; the drag row's
    flow, sampled densely over every incline it allows and wider starts), else None."""
    import numpy as np

    if source_name.startswith("incline:"):
        return _incline_truth(source_name, points)
    if source_name == "circle" or source_name.startswith("sphere:"):
        return np.abs(np.linalg.norm(points, axis=-1) - 1.0)
    if source_name == "block-drag-range":  # the same flow for every θ with c > 0 and wider starts
        import dataclasses
        import math

        import jax
        from scipy.spatial import cKDTree

        from jaml import sources

        wide = dataclasses.replace(sources.make(source_name), incline=(0.01, math.pi / 2),
                                   position_range=(-1.0, 2.0), velocity_range=(-2.0, 2.0))
        rows = np.asarray(wide.sample(jax.random.key(98), 2_000_000), np.float64)
        return cKDTree(rows).query(np.asarray(points, np.float64))[0]
    if source_name not in ("ellipse", "block45"):
        return None
    sys.path.insert(1, str(Path(__file__).resolve().parent))  # after the jaml imported
    from relations_quality import block_plane_distance, ellipse_nearest

    return ellipse_nearest(points)[0] if source_name == "ellipse" else block_plane_distance(points)


def launch(name: str, seed: int, timeout_s: float, keep: str | None = None) -> dict:
    source_name, fields = VARIANTS[name]
    keep = None if keep is None else str(Path(keep) / f"{name}-{seed}")
    cmd = [sys.executable, __file__, "--worker", json.dumps([source_name, seed, fields, keep])]
    try:
        proc = subprocess.run(cmd, env=os.environ | THREADS, capture_output=True, text=True,
                              timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return {"variant": name, "seed": seed, "error": f"over {timeout_s:g} s"}
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if not lines:
        return {"variant": name, "seed": seed, "error": proc.stderr[-400:]}
    return {"variant": name, **json.loads(lines[-1])}


def plot(records_path: str, variants: list[str], out: str, metric: str = "landed") -> None:
    """Per-seed `metric` of `variants` from a records file (one JSON line a run) into `out`.

    An item is "name" or "name=legend label"; a name may carry "@tag" (records of another
    checkout renamed so). Items of one source sit side by side in a group of their own, and
    items with the same label share a colour."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaml.relations.quality import FAR_ACCEPTED  # where the quality report warns

    lines = Path(records_path).read_text().splitlines()
    records = [json.loads(line) for line in lines if line.startswith("{")]
    fig, ax = plt.subplots(figsize=(9.5, 3.6))
    groups, colours, ticks, lowest, highest = [], {}, [], 1.0, 0.0
    metrics = metric.split(",")
    for item in variants:
        name, _, label = item.partition("=")
        source = VARIANTS[name.partition("@")[0]][0]
        if source not in groups:
            groups.append(source)
        g = groups.index(source)
        label = label or name
        rows = sorted((r for r in records if r["variant"] == name), key=lambda r: r["seed"])
        within = sum(1 for other in variants[: variants.index(item)]
                     if VARIANTS[other.partition("=")[0].partition("@")[0]][0] == source)
        for m, field in enumerate(metrics):  # several metrics: side by side, labelled
            shown = f"{label} {field}" if len(metrics) > 1 else label
            colour = colours.setdefault(shown, f"C{len(colours)}")
            values = [_field(r, field) for r in rows]
            ax.plot([10 * g + r["seed"] + 0.2 * (within + m) for r in rows], values,
                    "o", color=colour, ms=4, label=shown if shown not in ticks else None)
            ticks.append(shown)
            lowest = min([lowest] + [v for v in values if v == v])
            highest = max([highest] + [v for v in values if v == v])
    ax.set_xticks([10 * g + 3.5 for g in range(len(groups))], groups)
    if metric.startswith("holds_by"):  # a share of rows accepted away from the data: low is good
        if all(m.endswith(".far") for m in metrics):  # the report's warning level
            ax.axhline(FAR_ACCEPTED, color="grey", lw=0.8, ls="--")
        ax.set(ylim=(-0.02, max(0.2, highest + 0.05)))
    else:
        ax.axhline(0.2 if metric.startswith("unexplained") else 0.9, color="grey", lw=0.8,
                   ls="--")
        ax.set(ylim=(max(0.0, int(lowest * 10) / 10 - 0.1), 1.02))
    ylabel = (YLABELS.get(metric.partition(".")[0], metric) if len(metrics) == 1
              else "share (the legend names each measure)")
    ax.set(xlabel="seeds 0–7 of each source", ylabel=ylabel)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1))  # beside the points
    fig.tight_layout()
    fig.savefig(out, dpi=110)


YLABELS = {"holds_by": "rows off the data that holds accepts",
           "on_plane": "box points within 0.05 of the kinematic plane",
           "landed": "box points landing within 0.05 of the data",
           "on_truth": "box points within 0.05 of the manifold",
           "unexplained": "share of g_k a fresh syzygy leaves unexplained"}


def _field(record: dict, metric: str) -> float:
    """A record's `metric`: a field, or a dotted path into it ("unexplained.0": item 0 of a
    list field; "holds_by.value.far": a nested key); nan where absent."""
    value = record
    for part in metric.split("."):
        if isinstance(value, list):
            value = value[int(part)] if len(value) > int(part) else None
        else:
            value = value.get(part) if isinstance(value, dict) else None
        if value is None:
            return float("nan")
    return float(value)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("variants", nargs="?", default=",".join(VARIANTS))
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--timeout-s", type=float, default=540.0)
    parser.add_argument("--plot", nargs=2, metavar=("RECORDS", "PNG"),
                        help="draw the per-seed landing of the named variants from RECORDS")
    parser.add_argument("--metric", default="landed",
                        help="the record's field --plot draws, a dotted path into it "
                             "(unexplained.0: g_2's share; holds_by.value.far); several, "
                             "comma-separated, side by side")
    parser.add_argument("--keep", help="a directory each run's fitted relations are saved "
                                       "under (VARIANT-SEED)")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.plot:
        plot(args.plot[0], args.variants.split(","), args.plot[1], args.metric)
        return
    if args.worker:
        source_name, seed, fields, keep = json.loads(args.worker)
        print(json.dumps(one(source_name, seed, fields, keep)))
        return
    names = args.variants.split(",")
    unknown = [n for n in names if n not in VARIANTS]
    if unknown:
        parser.error(f"unknown variants {unknown}; choose from {list(VARIANTS)}")
    draw_pools(names)
    runs = [(n, s) for n in names for s in range(args.seeds)]
    with ThreadPoolExecutor(args.jobs) as pool:  # each record printed as its run ends
        futures = [pool.submit(launch, *r, args.timeout_s, args.keep) for r in runs]
        for done in as_completed(futures):
            print(json.dumps(done.result()), flush=True)


if __name__ == "__main__":
    main()
