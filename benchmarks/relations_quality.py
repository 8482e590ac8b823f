"""AML's quality side by side: jaml and the authors' own PyTorch code (MaksimIM/aml 300a446,
run unchanged by `peers/aml_reference.py`) on the same sources, seeds and measures.

Every (case, stack, seed) is one fit in its own single-threaded CPU process (`--jobs` at a
time) under the same wall-clock budget, measured there, and written as one JSON into `--out`
(a killed batch resumes: runs whose JSON holds a result are skipped, errors run again). Then
a table per case and stack (median / worst / best over seeds), appended with `harness.record`.

Measures, one code for both stacks (each stack's relations as a jaml `RelationSet`; the
reference's weights are loaded into one, `aml_reference.relation_set`, tested equal to its
torch networks):
  landing: 512 points uniform in the data's box (per-axis min–max of 65,536 source rows) moved
    by `relations.project(rs, pts, steps=50, max_step=0.1·diagonal, bounds=box)`; the share
    within 0.05 of the true manifold (ellipse: closed-form nearest point of the curve; block:
    the affine plane of its two exact relations) and the coverage (ellipse: share of 36 equal
    arcs of t holding a landed point; block: of 6×6 cells of the (s0, v0) box). For jaml also
    `relations.project(rs, pts)` at its defaults, as a user calls it.
  independence: on 2,048 fresh on-manifold rows, `relations.jacobian_ranks` (share of rows of
    rank ≥ 2) and the |cos| between relations' input gradients (median over rows per pair;
    the median and the largest over pairs).
  unexplained: for g_2, g_3, …, the share of mean |g_k| a restricted syzygy of the earlier
    relations, fitted afresh (`syzygy_unexplained`, at most 10,000 steps), leaves unexplained
    on fresh thickened rows: below 0.2 g_k is a copy of them (Algorithm 1's "f ≈ 0").
  per relation: steps, how it ended (done: the stopping rule; capped: the step cap; cut: the
    wall budget), the stack's own off/on ratio (jaml: fresh data; reference: its EMA) and the
    same fresh-data ratio for both; fit wall seconds (jaml's include compilation).
  block: the next-state error as `jaml.relations.plots.learned_transitions` solves it, on the
    training range and on twice it.
The budget is checked by the reference at every batch, by jaml after every compiled chunk
(500 steps; the first includes compilation), so a jaml run may pass it by that much. Rank 2 at
`jacobian_ranks`' rtol 0.1 needs ≥ 11.4° between gradients: the true plane and hyperboloid meet
at 11.3° near t = 3π/2 and score 0.89 themselves (tests/test_relations_quality.py).

On a GPU host (CPU runs only; carry the git-ignored `.aml_reference`; JAML_COMMIT names the
commit where the copied tree's git does not):

    python benchmarks/relations_quality.py --cases ellipse-2,block45-2 --seeds 0..7 --jobs 16 \\
        --budget-s 900
    python benchmarks/relations_quality.py --smoke          # 1 seed, tiny budgets, no record
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

# A CPU benchmark whatever the host: every fit on one core. Set in each child's environment,
# and in this process by `main` (before JAX loads), not at import.
THREAD_ENV = {
    "JAX_PLATFORMS": "cpu",
    "XLA_FLAGS": "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
}

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

BOX_ROWS = 65_536
LANDING_POINTS = 512
LANDING_STEPS = 50
LANDED = 0.05  # distance to the true manifold that counts as on it
CELLS = 36
RANK_ROWS = 2_048
FRESH_ROWS = 16_384
TRANSITION_ROWS = 512
BOX_KEY = 123_456  # one box for every run: it is the data's, not a seed's


@dataclasses.dataclass(frozen=True)
class Case:
    source: str  # jaml preset
    jaml: dict | None  # relations.Config overrides (seed and noise added per run)
    reference: dict | None  # aml_reference.fit arguments
    noisy: bool = False  # run at each --noise level
    note: str = ""


CASES = {
    "ellipse-2": Case("ellipse", {"max_relations": 2},
                      {"source": "Ellipse", "max_relations": 2, "max_syzygies": 0}),
    "ellipse-2-noisy": Case("ellipse", {"max_relations": 2},
                            {"source": "Ellipse", "max_relations": 2, "max_syzygies": 0},
                            noisy=True, note="the two relations by transversality, at each "
                                             "--noise level"),
    "ellipse-4": Case("ellipse", {"max_relations": 4},
                      {"source": "Ellipse", "max_relations": 4, "max_syzygies": 0}),
    "ellipse-syz": Case("ellipse", {"max_relations": 3, "independence": "syzygy",
                                    "transversal_first": False},
                        {"source": "Ellipse", "max_relations": 2, "max_syzygies": 3},
                        noisy=True,
                        note="restricted syzygies from g_2 on (the paper): jaml 3 relations, "
                             "the reference 2 (its syzygy rounds are slow: ~7 min for g1 + g2 "
                             "on one core)"),
    "ellipse-syz-now": Case("ellipse", {"max_relations": 3, "independence": "syzygy"}, None,
                            noisy=True,
                            note="jaml only, syzygy mode's defaults: transversality up to the "
                                 "data's codimension, restricted syzygies beyond it"),
    "ellipse-syz-joint": Case("ellipse", {"max_relations": 3, "independence": "syzygy",
                                          "transversal_first": False,
                                          "syzygy_training": "joint"}, None, noisy=True,
                              note="jaml only: the syzygy network trained alongside g_k "
                                   "(`syzygy_training='joint'`)"),
    "ellipse-auto": Case("ellipse", {}, None,
                         note="jaml only, Config defaults (max_relations 10): relations kept"),
    "block45-2": Case("block45", {"max_relations": 2},
                      {"source": "ConservativeBlock45Incline1D", "max_relations": 2,
                       "max_syzygies": 0}),
    "block45-2-noisy": Case("block45", {"max_relations": 2},
                            {"source": "ConservativeBlock45Incline1D", "max_relations": 2,
                             "max_syzygies": 0}, noisy=True,
                            note="the two relations by transversality, at each --noise level"),
}
STACKS = ("jaml", "reference")
SYZYGY_STEPS = 10_000  # the step cap of the fresh syzygy network `syzygy_unexplained` fits


@dataclasses.dataclass(frozen=True)
class Run:
    case: str
    stack: str
    seed: int
    noise: float = 0.0

    @property
    def label(self) -> str:
        """The case as the table names it (noise levels apart)."""
        return self.case + (f", noise {self.noise:g}" if CASES[self.case].noisy else "")

    @property
    def name(self) -> str:
        noise = f"-n{self.noise:g}" if CASES[self.case].noisy else ""
        return f"{self.case}{noise}-{self.stack}-s{self.seed}"


# ----------------------------------------------------------------------------- measures


def data_box(source) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis min and max of BOX_ROWS rows of the source."""
    import jax

    rows = np.asarray(source.sample(jax.random.key(BOX_KEY), BOX_ROWS), np.float64)
    return rows.min(0), rows.max(0)


def ellipse_curve(t):
    t = np.asarray(t)
    return np.stack([math.sqrt(2) * np.cos(t), 2 * np.sin(t) - 1, np.sin(t) - 1], -1)


def ellipse_nearest(points: np.ndarray, coarse: int = 3_600, fine: int = 201):
    """(distance [N], t [N]) of the nearest point of the ellipse: a grid of `coarse` values of t,
    refined on `fine` values across the best one's neighbours (t to ~2e-5 rad)."""
    points = np.asarray(points, np.float64)
    t = np.linspace(0, 2 * np.pi, coarse, endpoint=False)
    d2 = ((points[:, None, :] - ellipse_curve(t)[None]) ** 2).sum(-1)
    t0 = t[np.argmin(d2, axis=1)]
    dt = 2 * np.pi / coarse
    t = t0[:, None] + np.linspace(-dt, dt, fine)[None]
    d2 = ((points[:, None, :] - ellipse_curve(t)) ** 2).sum(-1)
    best = np.argmin(d2, axis=1)
    rows = np.arange(len(points))
    return np.sqrt(d2[rows, best]), np.mod(t[rows, best], 2 * np.pi)


def block_constant(incline=math.pi / 4, gravity=9.8) -> float:
    """c = g sin θ: the 45° block's downhill acceleration (no friction)."""
    return gravity * math.sin(incline)


def block_plane_distance(points: np.ndarray, c: float | None = None) -> np.ndarray:
    """[N] distance of τ = (s0, v0, s1, v1) to the affine plane v1 − v0 = c, s1 − s0 − v0 = c/2
    (the no-friction block after 1 s)."""
    c = block_constant() if c is None else c
    a = np.asarray([[0.0, -1.0, 0.0, 1.0], [-1.0, -1.0, 1.0, 0.0]])
    r = np.asarray(points, np.float64) @ a.T - np.asarray([c, c / 2])
    return np.sqrt(np.einsum("ni,ij,nj->n", r, np.linalg.inv(a @ a.T), r))


def on_truth(source_name: str, points: np.ndarray, low, high):
    """(distance [N] to the true manifold, cell [N] in 0..CELLS−1 or −1 outside): the ellipse's
    arc of t, or the block's (s0, v0) cell of the box (6 × 6)."""
    points = np.asarray(points, np.float64)
    finite = np.all(np.isfinite(points), -1)
    safe = np.where(finite[:, None], points, 0.0)
    if source_name == "ellipse":
        dist, t = ellipse_nearest(safe)
        cell = np.minimum((t / (2 * np.pi) * CELLS).astype(int), CELLS - 1)
    elif source_name == "block45":
        dist = block_plane_distance(safe)
        side = math.isqrt(CELLS)
        u = (safe[:, :2] - low[:2]) / (high[:2] - low[:2])
        inside = np.all((u >= 0) & (u <= 1), -1)
        ij = np.minimum((u * side).astype(int), side - 1)
        cell = np.where(inside, ij[:, 0] * side + ij[:, 1], -1)
    else:
        raise ValueError(f"no true manifold known for source {source_name!r}")
    return np.where(finite, dist, np.inf), np.where(finite, cell, -1)


def _project_points(relations_, pts, **kwargs) -> np.ndarray:
    from jaml import relations

    # `project` returns (points, residuals[, converged]): the points come first either way.
    return np.asarray(relations.project(relations_, pts, **kwargs)[0])


def landing(relations_, source_name: str, low, high, seed: int, defaults: bool = False) -> dict:
    """Share of LANDING_POINTS uniform box points that `project` moves onto the true manifold
    (within LANDED), the coverage of the manifold by them, and their median distance;
    `relations_` a RelationSet or a callable τ [..., D] → [..., K]."""
    import inspect

    from jaml import relations

    rng = np.random.default_rng([seed, 1])
    pts = rng.uniform(low, high, (LANDING_POINTS, len(low))).astype(np.float32)
    if defaults:
        moved = _project_points(relations_, pts)
    else:
        kwargs = {"steps": LANDING_STEPS, "max_step": 0.1 * float(np.linalg.norm(high - low))}
        if "bounds" in inspect.signature(relations.project).parameters:
            kwargs["bounds"] = (low.astype(np.float32), high.astype(np.float32))
        moved = _project_points(relations_, pts, **kwargs)
    dist, cell = on_truth(source_name, moved, low, high)
    landed = dist < LANDED
    return {
        "landed": float(landed.mean()),
        "coverage": float(len(set(cell[landed & (cell >= 0)].tolist())) / CELLS),
        "median_distance": float(np.median(dist)),
        "finite": float(np.isfinite(dist).mean()),
    }


def gradient_cosines(fn, rows) -> np.ndarray:
    """[N, K, K] |cos| between the relations' input gradients at each row (0 where one is 0)."""
    import jax
    import jax.numpy as jnp

    jac = jax.jit(jax.vmap(jax.jacfwd(fn)))(jnp.asarray(rows))  # [N, K, D]
    norm = jnp.linalg.norm(jac, axis=-1, keepdims=True)
    unit = jnp.where(norm > 0, jac / jnp.where(norm > 0, norm, 1.0), 0.0)
    return np.abs(np.asarray(jnp.einsum("nkd,njd->nkj", unit, unit)))


def as_function(relations_):
    """τ [..., D] → [..., K] of a RelationSet, or the callable itself."""
    from jaml import relations

    if isinstance(relations_, relations.RelationSet):
        return lambda tau: relations.evaluate(relations_, tau)
    return relations_


def independence(relations_, rows) -> dict:
    """Rank of the Jacobian (share ≥ 2 and full) and pairwise gradient |cos| on `rows`;
    `relations_` a RelationSet or a callable τ [..., D] → [..., K]."""
    from jaml import relations

    fn = as_function(relations_)
    k = int(np.shape(fn(np.asarray(rows)[:1]))[-1])
    ranks = np.asarray(relations.jacobian_ranks(relations_, rows)[0])
    out = {"rank2": float(np.mean(ranks >= 2)), "full_rank": float(np.mean(ranks == k))}
    if k >= 2:
        cos = gradient_cosines(fn, rows)
        pairs = {f"g{i + 1}g{j + 1}": float(np.median(cos[:, i, j]))
                 for i in range(k) for j in range(i + 1, k)}
        out |= {"cos_median": float(np.median(list(pairs.values()))),
                "cos_max_pair": max(pairs.values()), "cos_pairs": pairs}
    return out


def fresh_means(relations_, source, low, high, seed: int) -> list[dict]:
    """Per relation mean |g_k| on fresh on-manifold rows and on uniform box rows."""
    import jax

    fn = jax.jit(as_function(relations_))
    on = source.sample(jax.random.key(4_000_000 + seed), FRESH_ROWS)
    off = np.random.default_rng([seed, 2]).uniform(low, high, (FRESH_ROWS, len(low)))
    g_on = np.abs(np.asarray(fn(on))).mean(0)
    g_off = np.abs(np.asarray(fn(off.astype(np.float32)))).mean(0)
    return [{"on": float(a), "off": float(b), "off_on": float(b / max(a, 1e-30))}
            for a, b in zip(g_on, g_off, strict=True)]


def syzygy_unexplained(rs, source, seed: int, judged=(), steps: int | None = None) -> list:
    """For g_2, g_3, …: the share of mean |g_k| a restricted syzygy of the earlier relations,
    fitted afresh (`training.unexplained_share`: Algorithm 1's f on thickened rows, judged on fresh
    ones), leaves unexplained: near 0, g_k is a copy of them (Σ_j f_j g_j); from
    1/separation_ratio (0.2) on, new. Where `judged` (a jaml report's relations) holds the
    fit's own judgement of g_k, that is taken instead."""
    import jax

    from jaml import relations
    from jaml.relations import data, training

    cfg = relations.Config(seed=seed, syzygy_max_steps=steps)
    k_data, key = jax.random.split(jax.random.key(cfg.seed))
    batches = data.prepare(source, cfg.batch_size, cfg.noise_scale, k_data, cfg.eval_batches)
    shares = []
    for k in range(1, rs.num_relations):
        share = judged[k].get("unexplained") if k < len(judged) else None
        if share is None:
            share = training.unexplained_share(cfg, batches, rs.select(range(k)), rs.relation(k),
                                               jax.random.fold_in(key, 20_000 + k))
        shares.append(round(share, 3))
    return shares


def next_state(rs, seed: int) -> dict:
    """The block's next state solved from the relations (`plots.learned_transitions`) against
    the data's, on the training range and on twice it: median error over all starts and over
    the converged ones, and the share converged."""
    import jax

    from jaml import sources
    from jaml.relations.plots import learned_transitions

    out = {}
    for label, scale, salt in (("train", 1.0, 2_000_000), ("wide", 2.0, 3_000_000)):
        on = np.asarray(sources.make("block45", scale=scale).sample(
            jax.random.key(salt + seed), TRANSITION_ROWS))
        learned, ok = learned_transitions(rs, on)
        err = np.linalg.norm(learned[:, 2:4] - on[:, 2:4], axis=-1)
        err = np.where(np.isfinite(err), err, np.inf)
        out[f"next_err_{label}"] = float(np.median(err))
        out[f"next_err_{label}_converged"] = float(np.median(err[ok])) if ok.any() else None
        out[f"next_converged_{label}"] = float(np.mean(ok))
        out[f"next_step_{label}"] = float(np.median(np.linalg.norm(on[:, 2:4] - on[:, :2], -1)))
    return out


def measure(rs, source_name: str, seed: int, jaml_defaults: bool) -> dict:
    """Every measure of one fitted RelationSet (see the module docstring). A measure that
    raises is recorded under "measure_errors" and the others still run: a fit of many minutes
    is not lost to one."""
    import jax

    from jaml import sources

    if rs is None or rs.num_relations == 0:
        return {"relations_kept": 0}
    source = sources.make(source_name)
    low, high = data_box(source)
    started = time.perf_counter()
    rows = source.sample(jax.random.key(1_000_000 + seed), RANK_ROWS)
    out, errors = {"relations_kept": rs.num_relations}, {}
    groups = [("landing", lambda: landing(rs, source_name, low, high, seed)),
              ("independence", lambda: independence(rs, rows)),
              ("fresh", lambda: {"fresh": fresh_means(rs, source, low, high, seed)}),
              ("unexplained", lambda: {"unexplained": syzygy_unexplained(
                  rs, source, seed, steps=SYZYGY_STEPS)})]
    if jaml_defaults:
        groups.append(("at_defaults", lambda: {"at_defaults": landing(
            rs, source_name, low, high, seed, defaults=True)}))
    if source_name == "block45":
        groups.append(("next_state", lambda: next_state(rs, seed)))
    for name, group in groups:
        try:
            out |= group()
        except Exception as e:  # recorded, and the other measures go on
            errors[name] = f"{type(e).__name__}: {e}"
    if errors:
        out["measure_errors"] = errors
    out["measure_s"] = time.perf_counter() - started
    return out


# ----------------------------------------------------------------------------- fits


class _OutOfTime(Exception):
    pass


class _Keeper:
    """jaml's `Partial` hook: keeps the state of the relation in training after every compiled
    chunk (never restores), and ends the fit once the budget is spent (after keeping it)."""

    def __init__(self, deadline: float):
        self.deadline, self.k, self.state = deadline, None, None

    def holds(self, k):
        return False

    def restore(self, k, template):
        return None

    def save(self, k, state):
        self.k, self.state = k, state
        if time.perf_counter() > self.deadline:
            raise _OutOfTime

    def callback(self, phase, k, metrics):
        # Syzygy rounds and push phases keep no state here: they end where they stand.
        if phase != "relation" and time.perf_counter() > self.deadline:
            raise _OutOfTime


def _jsonable(value):
    """A report, summary dataclass or mapping as plain JSON values (arrays as lists)."""
    if hasattr(value, "to_dict"):
        value = value.to_dict()
    elif dataclasses.is_dataclass(value):
        value = dataclasses.asdict(value)
    return json.loads(json.dumps(value, default=lambda x: float(x) if np.ndim(x) == 0 else
                                 np.asarray(x).tolist()))


def fit_jaml(run: Run, budget_s: float | None) -> tuple[object, dict]:
    """(RelationSet, run record) of jaml's fit; on the budget, the relations finished and the
    one in training (status "cut", fresh-data means)."""
    import jax

    from jaml import relations, sources
    from jaml.relations.networks import relation_width

    case = CASES[run.case]
    cfg = relations.Config(seed=run.seed, noise_scale=run.noise, **case.jaml)
    source = sources.make(case.source)
    summaries, done = [], []
    started = time.perf_counter()
    keeper = _Keeper(started + (math.inf if budget_s is None else budget_s))

    def kept(rs, summary):  # a fit that trains its first relations again reports them again
        done.append(rs)
        summaries[summary.index - 1:] = [summary]

    try:
        rs = relations.fit(source, cfg, callback=keeper.callback, partial=keeper,
                           on_relation=kept)
        cut = False
    except _OutOfTime:
        rs, cut = (done[-1] if done else None), True
    wall = time.perf_counter() - started
    records = []
    for s in summaries:
        rec = _jsonable(s)
        rec.pop("codimension", None)
        rec["off_on"] = rec["off_mean"] / max(rec["on_mean"], 1e-30)
        records.append(rec)
    k = rs.num_relations if rs is not None else 0
    if cut and keeper.state is not None and keeper.k == k:
        # The relation in training, kept as it stood: its means on fresh data.
        low, high = data_box(source)
        if rs is None:
            rs = relations.RelationSet.empty(len(low), cfg.depth, cfg.tolerance)
            if hasattr(rs, "low"):
                rs = rs.replace(low=tuple(map(float, low)), high=tuple(map(float, high)))
        width = relation_width(k, cfg.base_width, cfg.max_width)
        params = jax.device_get(keeper.state.params)
        grown = rs.append(params, 1.0, 1.0, width)
        fresh = fresh_means(grown, source, low, high, run.seed)[-1]
        rs = rs.append(params, fresh["on"], fresh["off"], width)
        records.append({"index": k + 1, "width": width, "steps": int(keeper.state.step),
                        "seconds": wall - sum(r["seconds"] for r in records), "status": "cut",
                        "on_mean": fresh["on"], "off_mean": fresh["off"],
                        "off_on": fresh["off_on"]})
    quality = getattr(rs, "quality", None)
    return rs, {
        "config": cfg.to_dict(),
        "wall_s": wall,
        "cut": cut,
        "steps": sum(r["steps"] for r in records),
        "relations": records,
        "quality": None if quality is None else _jsonable(quality),
    }


def fit_reference(run: Run, budget_s: float | None, out: Path) -> tuple[object, dict]:
    """(RelationSet of their weights, run record) of the authors' fit (peers/aml_reference)."""
    from benchmarks.peers import aml_reference
    from jaml import sources

    case = CASES[run.case]
    record = aml_reference.fit(seed=run.seed, noise_scale=run.noise, budget_s=budget_s,
                               out=out / "reference" / run.name, **case.reference)
    rs = None
    if record["relations"]:
        box = data_box(sources.make(case.source))
        rs = aml_reference.relation_set(record["npz"], bounds=box)
    return rs, record


def run_one(run: Run, budget_s: float | None, out: Path) -> dict:
    """Fit and measure one run (in this process); returns its JSON record."""
    import jax

    started = time.perf_counter()
    if run.stack == "jaml":
        rs, record = fit_jaml(run, budget_s)
    else:
        rs, record = fit_reference(run, budget_s, out)
    record |= measure(rs, CASES[run.case].source, run.seed, jaml_defaults=run.stack == "jaml")
    return {**dataclasses.asdict(run), "name": run.name, "label": run.label,
            "budget_s": budget_s, **record, "process_s": time.perf_counter() - started,
            "jax": jax.__version__, "device": str(jax.devices()[0]),
            "xla_flags": os.environ.get("XLA_FLAGS", "")}


def _worker(spec: str, budget_s: float | None, out: Path) -> int:
    run = Run(**json.loads(spec))
    if run.stack == "reference":
        import torch

        torch.set_num_threads(1)
    record = run_one(run, budget_s, out)
    path = out / f"{run.name}.json"
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(record, indent=1, default=float))
    tmp.replace(path)
    print(summary_line(record), flush=True)
    return 0


# ----------------------------------------------------------------------------- batch


def summary_line(r: dict) -> str:
    if "error" in r:
        return f"{r['name']}: ERROR {r['error']}"
    ends = " ".join(f"g{x['index']} {x['status']} {x['steps']} steps x{x['off_on']:.1f}"
                    for x in r.get("relations", []))
    parts = [f"{r['name']}: {r['wall_s']:.0f} s{' (cut)' if r.get('cut') else ''}", ends]
    if r.get("train_error"):
        parts.append(f"their code raised {r['train_error']}")
    if "landed" in r:
        parts.append(f"landed {r['landed']:.2f} coverage {r['coverage']:.2f} "
                     f"rank2 {r['rank2']:.2f}"
                     + (f" |cos| {r['cos_median']:.3f}" if "cos_median" in r else ""))
    if "at_defaults" in r:
        parts.append(f"landed at project's defaults {r['at_defaults']['landed']:.2f}")
    if r.get("measure_errors"):
        parts.append("measure errors: " + "; ".join(f"{k}: {v}"
                                                    for k, v in r["measure_errors"].items()))
    if "next_err_train" in r:
        parts.append(f"next-state error {r['next_err_train']:.3f} (train) "
                     f"{r['next_err_wide']:.3f} (2x)")
    return "; ".join(parts)


def plan(cases, stacks, seeds, noises, skip=()) -> list[Run]:
    runs = []
    for case in cases:
        spec = CASES[case]
        for stack in stacks:
            if (spec.jaml if stack == "jaml" else spec.reference) is None or (
                    f"{case}/{stack}" in skip):
                continue
            for noise in (noises if spec.noisy else (0.0,)):
                runs.extend(Run(case, stack, seed, float(noise)) for seed in seeds)
    return runs


def _done(path: Path) -> bool:
    """A run's JSON exists and is a result (an error is run again)."""
    return path.exists() and "error" not in json.loads(path.read_text())


def launch(runs: list[Run], out: Path, jobs: int, budget_s: float | None,
           timeout_s: float) -> None:
    """Run each missing run in a child process, `jobs` at a time; a child past `timeout_s` is
    killed and its run recorded as an error."""
    (out / "logs").mkdir(parents=True, exist_ok=True)
    pending = [r for r in runs if not _done(out / f"{r.name}.json")]
    skipped = len(runs) - len(pending)
    if skipped:
        print(f"{skipped} runs already done in {out}: skipped", flush=True)
    env = {**os.environ, **THREAD_ENV}
    try:
        from benchmarks.peers import aml_reference

        env[aml_reference.CHECKOUT_ENV] = str(aml_reference.find_checkout())
    except FileNotFoundError:
        pass  # reported by the reference runs themselves
    active: dict = {}
    while pending or active:
        while pending and len(active) < jobs:
            run = pending.pop(0)
            (out / f"{run.name}.json").unlink(missing_ok=True)  # an earlier error
            log = open(out / "logs" / f"{run.name}.log", "w")  # noqa: SIM115
            cmd = [sys.executable, str(Path(__file__).resolve()), "--worker",
                   json.dumps(dataclasses.asdict(run)), "--out", str(out),
                   "--budget-s", str(budget_s or 0)]
            proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log,
                                    stderr=subprocess.STDOUT)
            active[proc.pid] = (proc, run, log, time.perf_counter())
            print(f"started {run.name} (pid {proc.pid})", flush=True)
        time.sleep(0.5)
        for pid, (proc, run, log, started) in list(active.items()):
            code = proc.poll()
            if code is None and time.perf_counter() - started > timeout_s:
                proc.kill()  # our own child, by its handle
                proc.wait()
                code = "timeout"
            if code is None:
                continue
            log.close()
            del active[pid]
            path = out / f"{run.name}.json"
            if not path.exists():
                tail = (out / "logs" / f"{run.name}.log").read_text().strip().splitlines()[-3:]
                error = {**dataclasses.asdict(run), "name": run.name, "label": run.label,
                         "error": f"exit {code}: " + " | ".join(tail)}
                path.write_text(json.dumps(error, indent=1))
            print(summary_line(json.loads(path.read_text())), flush=True)


def _stats(values, higher_is_better: bool) -> dict:
    values = [v for v in values if v is not None]
    if not values:
        return {}
    worst, best = (min, max) if higher_is_better else (max, min)
    return {"median": statistics.median(values), "worst": worst(values), "best": best(values)}


METRICS = (  # (column, how to read it from a run, higher is better)
    ("landed", lambda r: r.get("landed"), True),
    ("coverage", lambda r: r.get("coverage"), True),
    ("landed_at_defaults", lambda r: r.get("at_defaults", {}).get("landed"), True),
    ("rank2", lambda r: r.get("rank2"), True),
    ("cos_median", lambda r: r.get("cos_median"), False),
    ("cos_max_pair", lambda r: r.get("cos_max_pair"), False),
    ("min_fresh_off_on", lambda r: min((x["off_on"] for x in r.get("fresh", [])), default=None),
     True),
    ("relations_kept", lambda r: r.get("relations_kept"), True),
    ("wall_s", lambda r: r.get("wall_s"), False),
    ("next_err_train", lambda r: r.get("next_err_train"), False),
    ("next_err_wide", lambda r: r.get("next_err_wide"), False),
)


def aggregate(records: list[dict], budget_s) -> list[dict]:
    """One row per (case label, stack): median / worst / best over seeds of every measure, and
    each seed's relations' endings."""
    groups: dict = {}
    for r in records:
        groups.setdefault((r["label"], r["stack"]), []).append(r)
    rows = []
    for (label, stack), group in sorted(groups.items()):
        group.sort(key=lambda r: r["seed"])
        ok = [r for r in group if "error" not in r]
        case = CASES[group[0]["case"]]
        row = {"case": f"{label}, budget {budget_s:g} s" if budget_s else label,
               "impl": _impl(stack, ok),
               "seeds": "/".join(str(r["seed"]) for r in group),
               "errors": len(group) - len(ok),
               "cut_runs": sum(bool(r.get("cut")) for r in ok)}
        for column, read, higher in METRICS:
            for stat, value in _stats([read(r) for r in ok], higher).items():
                row[f"{column}_{stat}"] = value
        row["per_seed_relations"] = " ".join(
            "/".join(f"{x['status']}:{x['steps']}" for x in r.get("relations", [])) or "-"
            for r in ok)
        row["per_seed_landed"] = "/".join(f"{r['landed']:.2f}" if "landed" in r else "-"
                                          for r in ok)
        if case.note:
            row["note"] = case.note
        rows.append(row)
    return rows


def _impl(stack: str, runs: list[dict]) -> str:
    if stack == "jaml":
        objective = runs[0]["config"]["objective"] if runs else "?"
        return f"jaml ({objective} objective), CPU, 1 thread per run"
    torch = runs[0].get("torch", "?") if runs else "?"
    return f"authors' PyTorch AML (MaksimIM/aml 300a446, torch {torch}), CPU, 1 thread per run"


def compact(row: dict) -> dict:
    """A row for RESULTS.md: each measure as one "median (worst, best)" cell (rows.json in the
    output folder keeps the numbers)."""
    out = {k: v for k, v in row.items()
           if not k.endswith(("_median", "_worst", "_best"))}
    for column, _, _ in METRICS:
        if f"{column}_median" in row:
            out[column] = (f"{row[f'{column}_median']:.3g} ({row[f'{column}_worst']:.3g}, "
                           f"{row[f'{column}_best']:.3g})")
    return out


def table(rows: list[dict]) -> str:
    cols = ("landed", "coverage", "landed_at_defaults", "rank2", "cos_median", "wall_s",
            "relations_kept", "next_err_train", "next_err_wide")
    lines = ["| case | impl | seeds | " + " | ".join(f"{c} med (worst, best)" for c in cols)
             + " | relations per seed (status:steps) |",
             "|" + "---|" * (len(cols) + 4)]
    for row in rows:
        cells = []
        for c in cols:
            if f"{c}_median" in row:
                cells.append(f"{row[f'{c}_median']:.3g} ({row[f'{c}_worst']:.3g}, "
                             f"{row[f'{c}_best']:.3g})")
            else:
                cells.append("")
        lines.append(f"| {row['case']} | {row['impl']} | {row['seeds']} | " + " | ".join(cells)
                     + f" | {row['per_seed_relations']} |")
    return "\n".join(lines)


def plot(records_path: Path, out: Path, budget_s, cases: list[str], noise: float = 0.0) -> None:
    """Per-seed landing and g_2's unexplained share of each (case, stack) among `cases` whose
    runs had `budget_s` and `noise`, from a file of run records (one JSON line each) into `out`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    records = [json.loads(line) for line in records_path.read_text().splitlines()
               if line.startswith("{")]
    records = [r for r in records if r.get("case") in cases and r.get("budget_s") == budget_s
               and r.get("noise", 0.0) == noise and "error" not in r]
    groups = sorted({(r["case"], r["stack"]) for r in records},
                    key=lambda g: (cases.index(g[0]), g[1] == "jaml"))
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    panels = (("landed", "landed within 0.05 of the curve", 0.9),
              ("unexplained", "g_2 unexplained by a fresh syzygy", 0.2))
    for ax, (field, label, line) in zip(axes, panels, strict=True):
        for g, (case, stack) in enumerate(groups):
            runs = sorted((r for r in records if (r["case"], r["stack"]) == (case, stack)),
                          key=lambda r: r["seed"])
            values = [r[field] if field == "landed" else (r.get(field) or [None])[0]
                      for r in runs]
            ax.plot([g + 0.08 * (r["seed"] - 3.5) for r in runs],
                    [math.nan if v is None else v for v in values], "o", ms=4, color=f"C{g}")
        ax.axhline(line, color="grey", lw=0.8, ls="--")
        ax.set_xticks(range(len(groups)),
                      [f"{'authors' if stack == 'reference' else 'jaml'}\n{case}"
                       for case, stack in groups], fontsize=8)
        ax.set(ylim=(0, 1.02), ylabel=label)
    fig.tight_layout()
    fig.savefig(out, dpi=110)


def parse_seeds(text: str) -> list[int]:
    """'0..7' → 0–7 inclusive; '0,3,5' → those."""
    if ".." in text:
        lo, hi = text.split("..")
        return list(range(int(lo), int(hi) + 1))
    return [int(s) for s in text.split(",") if s]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description="AML's quality: jaml and the authors' PyTorch code side by side.")
    parser.add_argument("--cases", default=",".join(CASES),
                        help=f"comma-separated, of {', '.join(CASES)}")
    parser.add_argument("--stacks", default=",".join(STACKS))
    parser.add_argument("--skip", default="",
                        help="comma-separated CASE/STACK pairs not to run, e.g. ellipse-syz/jaml")
    parser.add_argument("--seeds", default="0..7", help="'0..7' or '0,1,2'")
    parser.add_argument("--noise", default="0,0.05",
                        help="noise levels of the noisy cases (--plot: the first)")
    parser.add_argument("--budget-s", type=float, default=900.0,
                        help="wall-clock budget of each fit, both stacks (0: none)")
    parser.add_argument("--jobs", type=int, default=2, help="runs at a time (one core each)")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "relations_quality")
    parser.add_argument("--smoke", action="store_true",
                        help="1 seed, 20 s budgets, into OUT/smoke, nothing recorded")
    parser.add_argument("--no-record", action="store_true", help="print only")
    parser.add_argument("--plot", nargs=2, type=Path, metavar=("RECORDS", "PNG"),
                        help="draw per-seed landing and g_2's unexplained share of --cases' "
                             "runs with --budget-s from RECORDS (a JSON line a run)")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.plot:
        plot(*args.plot, args.budget_s, args.cases.split(","), float(args.noise.split(",")[0]))
        return 0
    if "jax" not in sys.modules:  # the table's device is the runs' (CPU), on a GPU host too
        os.environ["JAX_PLATFORMS"] = "cpu"
    budget = args.budget_s or None
    if args.worker:
        return _worker(args.worker, budget, args.out)
    cases = [c for c in args.cases.split(",") if c]
    stacks = [s for s in args.stacks.split(",") if s]
    for name, known in (("case", CASES), ("stack", STACKS)):
        bad = [x for x in (cases if name == "case" else stacks) if x not in known]
        if bad:
            parser.error(f"unknown {name}(s) {bad}; choose from {list(known)}")
    skip = {x for x in args.skip.split(",") if x}
    bad = [x for x in skip if x.partition("/")[0] not in CASES or x.partition("/")[2] not in STACKS]
    if bad:
        parser.error(f"--skip {bad}: each must be CASE/STACK, e.g. ellipse-syz/jaml")
    seeds, noises = parse_seeds(args.seeds), [float(x) for x in args.noise.split(",")]
    out = args.out
    if args.smoke:
        seeds, budget, out, args.no_record = seeds[:1], 20.0, out / "smoke", True
    out.mkdir(parents=True, exist_ok=True)
    runs = plan(cases, stacks, seeds, noises, skip)
    # A child gets its budget, then time to compile and measure; past twice that it is killed.
    timeout = 2 * (budget or 3_600) + 600
    launch(runs, out, args.jobs, budget, timeout)
    records = [json.loads((out / f"{r.name}.json").read_text()) for r in runs]
    rows = aggregate(records, budget)
    text = table(rows)
    (out / "table.md").write_text(text + "\n")
    (out / "rows.json").write_text(json.dumps(rows, indent=1))
    print(text)
    if not args.no_record:
        from benchmarks import harness

        harness.record("relations_quality", [compact(row) | {"jobs": args.jobs, "budget_s": budget}
                                             for row in rows], notes=NOTES)
    return 0


NOTES = (
    "AML quality, jaml against the authors' own PyTorch code (MaksimIM/aml 300a446, run "
    "unchanged by benchmarks/peers/aml_reference.py, its data RNG seeded), same sources, seeds "
    "and measures; every fit one CPU process on one thread, same wall budget for both stacks "
    "(a run that hits it keeps its relations, the one in training flagged cut). landed: share "
    "of 512 uniform box points that relations.project (50 steps) moves to within 0.05 of the "
    "true manifold; coverage: share of 36 arcs (block: cells) reached; rank2: share of fresh "
    "on-manifold rows where the relations' Jacobian has rank ≥ 2; cos: |cos| between input "
    "gradients (median over rows, then over pairs); next_err: the block's next state solved "
    "from the relations (plots.learned_transitions), training range and twice it. Each cell: "
    "median (worst, best) over seeds. Details per run: the JSONs of --out."
)


if __name__ == "__main__":
    raise SystemExit(main())
