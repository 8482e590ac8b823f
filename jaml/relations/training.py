"""Algorithm 1 of the paper: learn relations g_1, g_2, … one at a time, earlier ones frozen.

Each g_k trains on fresh on-manifold batches with eq. 1; with transversality (eq. 2) the angle
between ∇g_k and the frozen ∇g_j is pushed towards 90°; with restricted syzygies (eq. 3) a
network f is fitted to express g_k through g_1..g_{k−1} on off-manifold data, and g_k is pushed
away from every f fitted so far, whether or not f explained it (the paper's soft version).
Every loop is a jitted `lax.scan` (see `loop.py`).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple, Protocol

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaml.configs.relations import Config
from jaml.relations import losses, quality, syzygy
from jaml.relations import units as units_lib
from jaml.relations.data import Batches, prepare
from jaml.relations.geometry import codimension
from jaml.relations.loop import (
    CAPPED,
    CONVERGED,
    NONFINITE,
    ONCE_COMPILER_OPTIONS,
    PASS_RATE,
    STATUS_NAMES,
    LoopState,
    init_state,
    make_chunk,
    optimizer_step,
    run_until_done,
)
from jaml.relations.networks import Relation, SyzygyCoefficients, relation_width
from jaml.relations.relation_set import RelationSet
from jaml.sources.off_manifold import thicken

log = logging.getLogger("jaml.relations")

THICKENING_LEVELS = np.linspace(0.1, 2.1, 10)
RANK_ROWS = 2048  # on-manifold rows of the codimension check after each relation


@dataclasses.dataclass
class RelationSummary:
    """What happened while learning one relation (written to summary.json by the CLI)."""

    index: int
    width: int
    steps: int
    seconds: float
    status: str
    on_mean: float
    off_mean: float
    syzygies_found: int = 0
    syzygy_rounds: list = dataclasses.field(default_factory=list)
    # `geometry.codimension` of g_1..g_index on fresh on-manifold rows: do they cut index dims?
    codimension: dict = dataclasses.field(default_factory=dict)
    # `quality.landing` of g_1..g_index: where projected box points land (mining's measure).
    landing: dict = dataclasses.field(default_factory=dict)
    refined: int = 0  # refinement rounds kept (they moved more projected points onto the data)
    # Share of mean |g_k| a fresh restricted syzygy of the earlier relations leaves unexplained
    # (`unexplained_share`), for relations trained against syzygies; None where not judged.
    unexplained: float | None = None

    @property
    def ratio(self) -> float:
        return self.off_mean / max(self.on_mean, 1e-30)


Callback = Callable[[str, int, dict], None]  # (phase, relation index, metrics)


def phase_budgets(cfg: Config) -> dict[str, int]:
    """Each phase a `Callback` is called with, and its step budget: g_k's own training (the
    pre-mined one too), a syzygy network's round, g_k's push round, a refinement round."""
    return {"relation": cfg.max_steps, "syzygy": cfg.syzygy_steps, "push": cfg.push_steps,
            "refine": max(cfg.max_steps // REFINE_SHARE, 1)}


MINED_CLIP = 2.0  # the mined term at most this × the first term, like the paper's other terms


def _relation_objective(
    cfg: Config, module: Relation, earlier_modules: Sequence[Relation], num_syz: int,
    with_mined: bool = True,
    clip: float = MINED_CLIP,
):
    """The per-step loss of g_k: (params, frozen syzygy params, frozen g_j params, batches) →
    (loss, aux). The frozen relations' parameters are arguments, not constants, so the compiled
    loop depends only on their shapes (and can be compiled before g_{k−1} is learned)."""
    transversal = cfg.independence == "transversality" and len(earlier_modules) > 0
    syz_module = SyzygyCoefficients(max(len(earlier_modules), 1), cfg.syzygy_width, cfg.depth)
    B = cfg.batch_size

    def objective(params, syz_params, earlier_params, pool_count, on, off, thick, mined):
        g = lambda t: module.apply(params, t)  # noqa: E731
        pairs = zip(earlier_modules, earlier_params, strict=True)
        earlier = [(lambda t, m=m, p=p: m.apply(p, t)) for m, p in pairs]
        y_on, v = losses.input_gradients(g, on)
        y_off = g(off)
        metrics = {
            "on_mean": jnp.mean(jnp.abs(y_on)),
            "off_mean": jnp.mean(jnp.abs(y_off)),
            "grad_norm": jnp.mean(jnp.sqrt(jnp.sum(v**2, -1))),
        }
        if cfg.objective == "paper":
            first = jnp.mean(losses.distance(y_on, v))
            grad_term = losses.clip_to(
                jnp.mean(losses.log_gradient_norm(v, cfg.gradient_cap)), first)
        else:
            first = jnp.mean(losses.reference_distance_term(y_on, v, B))
            grad_term = jnp.mean(losses.reference_gradient_term(v, B))
        loss = first + grad_term
        metrics |= {"distance": first, "gradient_term": grad_term}
        # The stopping rule (`losses.separated`), its on-manifold statistic kept for below.
        on_stat = jax.lax.stop_gradient(
            losses.top_mean(jnp.abs(y_on), cfg.separation_top_fraction))
        converged = cfg.separation_ratio * on_stat < jnp.mean(jnp.abs(y_off))
        if with_mined:
            mined_term, cleared = _mined_term(cfg, g(mined[:, :-1]), mined[:, -1], on_stat,
                                              first, clip)
            has_pool = pool_count > 0
            mined_term = jnp.where(has_pool, mined_term, 0.0)
            loss = loss + cfg.mined_weight * mined_term
            metrics |= {"mined": mined_term, "mined_cleared": cleared}
            converged &= ~has_pool | (cleared >= PASS_RATE)
        if cfg.objective == "reference":
            # Reference stopping also waits for mean ‖∇g/B‖ ≥ 0.9e-4.
            converged &= metrics["grad_norm"] / B >= 0.9 * losses.REF_GRAD_FLOOR
        if transversal:
            u = jax.lax.stop_gradient(
                jnp.stack([losses.input_gradients(gj, on)[1] for gj in earlier])
            )
            if cfg.objective == "paper":
                t_term = jnp.mean(losses.log_sin_product(u, v))
            else:
                t_term = jnp.mean(losses.reference_transversality(u, v))
            angle = losses.mean_angle(u, v)
            loss = loss + cfg.beta * t_term
            metrics |= {"transversality": t_term, "angle": angle}
            converged &= angle >= cfg.min_angle
        if num_syz:
            earlier_vals = jnp.stack([gj(thick) for gj in earlier], axis=-1)
            y_thick = g(thick)
            coefficients = jax.vmap(lambda p: syz_module.apply(p, thick))(syz_params)
            residual = jnp.abs(
                jax.vmap(losses.syzygy_residual, (0, None, None))(
                    coefficients, earlier_vals, y_thick
                )
            )
            per_syzygy = jnp.mean(residual, axis=-1)  # [S]
            scale = jnp.mean(jnp.abs(y_thick))
            if cfg.objective == "paper":
                push = losses.clip_to(-jnp.mean(per_syzygy), first)  # eq. 3, clipped (App. B.3.1)
            else:  # (1/100)·max(0, 100·5·L_on − L_syz), summed over the syzygies
                ref = 100.0 * 5.0 * jax.lax.stop_gradient(first)
                push = jnp.sum(jnp.maximum(0.0, ref - per_syzygy)) / 100.0
            loss = loss + push
            still_holds = jnp.any(per_syzygy * cfg.separation_ratio < scale)
            metrics |= {"syzygy_residual": jnp.mean(per_syzygy), "syzygy_push": push}
            converged &= ~still_holds
        return loss, (metrics, converged)

    return objective


def _mined_term(cfg: Config, y_mined, distance, on_stat, first, clip: float = MINED_CLIP):
    """(loss term, share of rows cleared) on mined rows: points of the intersection so far
    away from the data, where g_k must not vanish or the intersection keeps a spurious part.

    |g_k| is pushed above a level growing with the row's distance from the data (in landing
    distances; a flat level would leave local minima of |g_k| there), the term scaled to at
    most twice the first, like the paper's other terms: vanishing on the data leads. A row is
    cleared at half its level; the stopping rule wants 90 % cleared (a mean could hide rows at
    zero).
    """
    level = cfg.separation_ratio * on_stat * distance
    y_mined = jnp.abs(y_mined)
    term = losses.clip_to(jnp.mean(losses.mined_hinge(y_mined, level)), first, clip)
    return term, jnp.mean(y_mined >= 0.5 * level)


def relation_trainer(
    cfg: Config,
    batches: Batches,
    rs: RelationSet,
    params,
    key,
    max_steps: int,
    syz_params=None,
    thickening: float = 0.0,
    pool=None,
    with_mined: bool = True,
    clip: float = MINED_CLIP,
):
    """The compiled training loop of g_{K+1} given frozen `rs`: (chunk, initial state, args).

    `pool` = (rows [C, D], count): mined points where g_{K+1} must not vanish (`mine`).

    `chunk(state, args)` runs `cfg.chunk_steps` optimizer steps in one jitted `lax.scan`. The
    data, the key, every parameter and the thickening are its arguments: one chunk serves every
    fit of the process whose config agrees on `LOOP_FIELDS`, with equal samplers and relation
    shapes (and as many syzygies).
    """
    num_syz = 0 if syz_params is None else int(jax.tree.leaves(syz_params)[0].shape[0])
    chunk = _relation_loop(_LoopConfig(cfg), batches.static(), tuple(rs.widths), rs.depth,
                           num_syz, with_mined, clip, max_steps)
    if pool is None:
        pool = empty_pool(cfg, batches.dim)
    pool_rows, pool_count = pool
    args = (batches.data, syz_params, rs.params, jnp.asarray(pool_rows),
            jnp.asarray(pool_count, jnp.int32), jnp.asarray(thickening, jnp.float32))
    return chunk, init_state(params, optax.adam(cfg.learning_rate), key), args


# The fields of a Config the relation loop reads. The rest (the seed, how many relations, their
# starts and rounds) decide what a fit does around its loops, so fits differing only there run
# one loop; tests/relations/test_sources.py holds this list to the code.
LOOP_FIELDS = ("independence", "objective", "batch_size", "learning_rate", "base_width",
               "max_width", "depth", "gradient_cap", "transversality_weight", "syzygy_width",
               "separation_ratio", "separation_top_fraction", "min_angle", "stop_patience",
               "mined_weight", "chunk_steps")


class _LoopConfig:
    """A Config as a key of compiled loops: equal where the fields the loop reads are."""

    __slots__ = ("cfg", "key")

    def __init__(self, cfg: Config, fields: tuple[str, ...] = LOOP_FIELDS):
        self.cfg, self.key = cfg, (fields, *(getattr(cfg, name) for name in fields))

    def __eq__(self, other) -> bool:
        return isinstance(other, _LoopConfig) and self.key == other.key

    def __hash__(self) -> int:
        return hash(self.key)


def _build_relation_loop(loop_cfg: _LoopConfig, batches: Batches,
                         earlier_widths: tuple[int, ...], earlier_depth: int, num_syz: int,
                         with_mined: bool, clip: float, max_steps: int):
    """`relation_trainer`'s jitted chunk, built from what it does not take as arguments."""
    cfg = loop_cfg.cfg
    k = len(earlier_widths)
    module = Relation(relation_width(k, cfg.base_width, cfg.max_width), cfg.depth)
    earlier = [Relation(w, earlier_depth) for w in earlier_widths]
    objective = _relation_objective(cfg, module, earlier, num_syz, with_mined, clip)
    optimizer = optax.adam(cfg.learning_rate)

    def draw(key, args):
        data, rows, count, thickening = args[0], args[3], args[4], args[5]
        k_on, k_off, k_thick, k_jit, k_mined = jax.random.split(key, 5)
        thick = None
        if num_syz:  # syzygy push rounds only: skip the extra batch otherwise
            thick = thicken(k_jit, batches.on(k_thick, data), data.low, data.high, thickening)
        mined = draw_mined(k_mined, rows, count, data, cfg.batch_size // MINED_SHARE)
        return batches.on(k_on, data), batches.off(k_off, data), thick, mined

    def train_step(state, batch, args):
        return optimizer_step(
            state,
            objective,
            optimizer,
            max_steps,
            args[1],
            args[2],
            args[4],
            *batch,
            patience=cfg.stop_patience,
        )

    return make_chunk(train_step, cfg.chunk_steps, draw)


# Compiled relation loops kept across fits: every start, refinement round and later fit of a
# process runs the loop its key names. On XLA:CPU each compiled loop holds hundreds of memory
# mappings, and Linux allows a process about 65,000 (docs/notes/usage.md): a few loops are kept.
_relation_loop = functools.lru_cache(maxsize=8)(_build_relation_loop)


MINED_SHARE = 4  # a step's mined rows: a quarter of its batch
MINED_JITTER = 0.01  # mined rows are jittered by this share of the box, per coordinate


def empty_pool(cfg: Config, dim: int):
    """(rows [C, D + 1], count): mined points, each with its distance to the data (in units of
    the landing distance) as a last column."""
    return np.zeros((cfg.mine_points, dim + 1), np.float32), 0


def draw_mined(key, rows, count, data, n: int):
    """[n, D + 1] mined rows drawn with replacement from the first `count` of `rows`, jittered
    (their distance column kept)."""
    k_idx, k_jit = jax.random.split(key)
    idx = jax.random.randint(k_idx, (n,), 0, jnp.maximum(count, 1))
    dim = rows.shape[-1] - 1
    jitter = (jax.random.uniform(k_jit, (n, dim)) - 0.5) * (data.high - data.low)
    picked = rows[idx]
    return jnp.concatenate([picked[:, :dim] + MINED_JITTER * jitter, picked[:, dim:]], -1)


def mine(cfg: Config, rs: RelationSet, batches: Batches, key, within: float, pool=None,
         codim: int | None = None):
    """Points of {g_1 = … = g_K = 0} away from the data: n box points projected onto the zero
    set, kept where they converged farther than `within` from the training rows. Returns the
    pool (rows [C, D], count) with earlier pool rows after the new ones, and the landing shares.
    """
    land, points, distances = quality.landing(rs, key, batches.low, batches.high,
                                              batches.dense, within, n=cfg.mine_points,
                                              codim=codim)
    found = np.concatenate([points, distances[:, None] / within], -1)
    old = pool[0][: pool[1]] if pool is not None else np.zeros((0, batches.dim + 1), np.float32)
    rows = np.concatenate([found, old])[: cfg.mine_points]
    padded = np.zeros((cfg.mine_points, batches.dim + 1), np.float32)
    padded[: len(rows)] = rows
    return (padded, len(rows)), land


def _premines(cfg: Config, k: int, codim: int) -> bool:
    """Whether g_{k+1} first trains on rows mined from the earlier relations' zero set: it is
    the codimension-th relation of a transversality fit with mining on."""
    return (cfg.premine and cfg.mined_weight > 0 and cfg.independence == "transversality"
            and k > 0 and k + 1 == codim)


def _clip(cfg: Config, k: int, codim: int) -> float:
    """The mined term's bound (× the first term) in g_{k+1}'s first training loop."""
    return cfg.premine_clip if _premines(cfg, k, codim) else MINED_CLIP


def _with_mined(cfg: Config, k: int, codim: int) -> bool:
    """Whether g_{k+1}'s loop carries the mined-rows term: mining is on, and g_{k+1} is at or
    beyond the data's codimension (before it, the intersection is meant to exceed the data)."""
    return cfg.mined_weight > 0 and k + 1 >= codim


def _fit_relation(
    cfg,
    batches: Batches,
    rs: RelationSet,
    params,
    key,
    max_steps: int,
    syz_params=None,
    thickening: float = 0.0,
    callback=None,
    phase="relation",
    partial: Partial | None = None,
    pool=None,
    budget: int | None = None,
    codim: int = 1,
    clip: float = MINED_CLIP,
):
    """Train g_{K+1} until its stopping rule holds or it has taken `max_steps` (or `budget`)
    steps; returns its loop state, `step` counting the steps taken here.

    Later rounds (refinement, other starts) run the loop the first compiled: a `budget` below
    `max_steps` starts the step counter at max_steps − budget instead of building a loop with
    another cap.
    """
    k = rs.num_relations
    chunk, state, args = relation_trainer(
        cfg, batches, rs, params, key, max_steps, syz_params, thickening, pool,
        with_mined=_with_mined(cfg, rs.num_relations, codim), clip=clip,
    )
    start = 0
    if budget is not None:
        start = max(max_steps - budget, 0)
        state = state.replace(step=jnp.asarray(start, jnp.int32))
    report = None
    if callback is not None:
        # Steps taken in this training: a budget's counter starts at `start`.
        report = lambda s, m, n: callback(phase, k, {"step": int(s.step) - start, "steps": n,  # noqa: E731
                                                     **m})
    keep = None
    if partial is not None:
        restored = partial.restore(k, state)
        if restored is not None:
            state = restored
        keep = lambda s: partial.save(k, s)  # noqa: E731
    until = None
    if pool is not None and cfg.mined_patience is not None:
        until = _Plateau(cfg.separation_ratio, max(cfg.mined_patience // cfg.chunk_steps, 1))
    final = run_until_done(chunk, state, args, report, keep, until)
    return final.replace(step=final.step - start)


class _Plateau:
    """Ends a training on mined rows once g_k separates on- from off-rows (chunk means) and the
    share of mined rows it clears has not risen by `gain` over the last `window` chunks: those
    rows rarely all clear, and the loop would otherwise run to its budget."""

    def __init__(self, ratio: float, window: int, gain: float = 0.01):
        self.ratio, self.window, self.gain, self.cleared = ratio, window, gain, []

    def __call__(self, means: dict) -> bool:
        self.cleared.append(means["mined_cleared"])
        w = self.window
        if len(self.cleared) < 2 * w or means["off_mean"] < self.ratio * means["on_mean"]:
            return False
        return max(self.cleared[-w:]) <= max(self.cleared[:-w]) + self.gain


def fit_syzygy(
    cfg: Config,
    batches: Batches,
    earlier: Sequence[Callable | tuple],
    g_k: Callable | tuple,
    key,
    thickening: float,
    callback: Callback | None = None,
    index: int = 0,
):
    """Fit a restricted syzygy: f with Σ_j f_j(τ) g_j(τ) ≈ g_k(τ) on thickened data (L1).

    The relations are frozen: functions τ [..., D] → [...], or (module, params) pairs that
    apply as `module.apply(params, τ)` (a `Relation` and its parameters: the compiled loop is
    then kept for every round and fit of the process with those shapes). Returns (f params,
    found, info): `found` says whether f explains g_k on fresh test data, i.e. its mean residual
    is below 1/separation_ratio of mean |g_k| there (the "f ≈ 0" of Algorithm 1).
    """
    earlier = [_applied(f) for f in earlier]
    g_module, g_params = _applied(g_k)
    program = _syzygy_loop(_LoopConfig(cfg, SYZYGY_LOOP_FIELDS), batches.static(),
                           tuple(m for m, _ in earlier), g_module)
    k_init, k_loop, k_test = jax.random.split(key, 3)
    params = program.module.init(k_init, jnp.zeros((1, batches.dim)))
    state = init_state(params, program.optimizer, k_loop)
    args = (batches.data, tuple(p for _, p in earlier), g_params,
            jnp.asarray(thickening, jnp.float32))
    report = None
    if callback is not None:
        report = lambda s, m, n: callback("syzygy", index, {"step": int(s.step), "steps": n, **m})  # noqa: E731
    state = run_until_done(program.chunk, state, args, report)
    # Judge on fresh test data (Algorithm 1: "if f ≠ 0 on τ_off^test").
    info = {k: float(v) for k, v in jax.device_get(program.judge(state.params, k_test,
                                                                 args)).items()}
    found = info["residual"] * cfg.separation_ratio < info["g_scale"]
    return (
        state.params,
        found,
        info | {"steps": int(state.step), "found": found, "thickening": float(thickening)},
    )


# The Config fields the syzygy loop reads (tests/relations/test_sources.py holds it to the code).
SYZYGY_LOOP_FIELDS = ("syzygy_width", "depth", "syzygy_learning_rate", "syzygy_steps",
                      "stop_patience", "chunk_steps", "separation_ratio")


class _Plain:
    """A frozen function of τ as the syzygy loop applies a relation (`apply(params, τ)`, params
    unused): its loop is compiled for it alone."""

    def __init__(self, fn: Callable):
        self.fn = fn

    def apply(self, params, tau):
        return self.fn(tau)


def _applied(relation) -> tuple:
    """(module, params) of a frozen relation given as a pair or as a function of τ."""
    if isinstance(relation, tuple):
        return relation
    return _Plain(relation), None


def _relation_pairs(rs: RelationSet) -> list[tuple]:
    """The relations of `rs` as (module, params) pairs."""
    return [(Relation(w, rs.depth), p) for w, p in zip(rs.widths, rs.params, strict=True)]


class _SyzygyProgram(NamedTuple):
    module: SyzygyCoefficients
    optimizer: optax.GradientTransformation
    chunk: Callable  # (state, args) → (state, metrics, valid), as `make_chunk`
    judge: Callable  # (f params, key, args) → metrics on fresh thickened rows


@functools.lru_cache(maxsize=8)
def _syzygy_loop(loop_cfg: _LoopConfig, batches: Batches, earlier: tuple, g_module
                 ) -> _SyzygyProgram:
    """`fit_syzygy`'s compiled loop, built from what it does not take as arguments: args are
    (data, earlier params, g_k's params, thickening)."""
    cfg = loop_cfg.cfg
    module = SyzygyCoefficients(len(earlier), cfg.syzygy_width, cfg.depth)
    optimizer = optax.adam(cfg.syzygy_learning_rate)
    min_steps = cfg.syzygy_steps // 10  # the reference's early exit waits for a tenth of the budget

    def objective(params, step, thick, args):
        earlier_vals = jnp.stack([m.apply(p, thick) for m, p in zip(earlier, args[1],
                                                                     strict=True)], axis=-1)
        y = g_module.apply(args[2], thick)
        residual = jnp.abs(losses.syzygy_residual(module.apply(params, thick), earlier_vals, y))
        loss = jnp.mean(residual)
        scale = jnp.mean(jnp.abs(y))
        holds = (loss * cfg.separation_ratio < scale) & (step >= min_steps)
        return loss, ({"residual": loss, "g_scale": scale}, holds)

    def draw(key, args):
        data = args[0]
        k_on, k_jit = jax.random.split(key)
        return thicken(k_jit, batches.on(k_on, data), data.low, data.high, args[3])

    def train_step(state, thick, args):
        return optimizer_step(
            state,
            lambda p, step, t: objective(p, step, t, args),
            optimizer,
            cfg.syzygy_steps,
            state.step,
            thick,
            patience=cfg.stop_patience,
        )

    @functools.partial(jax.jit, compiler_options=ONCE_COMPILER_OPTIONS)
    def judge(params, key, args):
        _, (metrics, _) = objective(params, jnp.asarray(min_steps), draw(key, args), args)
        return metrics

    chunk = make_chunk(train_step, min(cfg.chunk_steps, cfg.syzygy_steps), draw)
    return _SyzygyProgram(module, optimizer, chunk, judge)


def choose_thickening(cfg, batches: Batches, rs: RelationSet, key) -> float:
    """The reference's σ: the first level whose jittered rows sit > 2× as far from the earlier
    relations' zero sets (mean d_g) as on-manifold rows do, else the smallest level."""
    pairs = _relation_pairs(rs)
    mean_distance = _mean_distance_program(tuple(m for m, _ in pairs))
    params = tuple(p for _, p in pairs)
    k_on, k_jit = jax.random.split(key)
    on = batches.on(k_on, batches.data)
    base = mean_distance(params, on)
    for level in THICKENING_LEVELS:
        wide = mean_distance(params, thicken(k_jit, on, batches.low, batches.high, level))
        if float(wide) > 2.0 * float(base):
            return float(level)
    return float(THICKENING_LEVELS[0])


@functools.lru_cache(maxsize=8)
def _mean_distance_program(modules: tuple):
    """The relations' mean first-order distance d_g over rows, one compiled call."""

    @functools.partial(jax.jit, compiler_options=ONCE_COMPILER_OPTIONS)
    def mean_distance(params, tau):
        return jnp.mean(jnp.stack([
            jnp.mean(losses.distance(*losses.input_gradients(
                lambda t, m=m, p=p: m.apply(p, t), tau)))
            for m, p in zip(modules, params, strict=True)]))

    return mean_distance


def record_means(cfg, batches: Batches, module, params, key):
    """Mean |g| of g = module.apply(params, ·) over `eval_batches` fresh on- and off-manifold
    batches (App. B.3.1)."""
    means = _means_program(batches.static(), module, cfg.batch_size * cfg.eval_batches)
    on, off = jax.device_get(means(key, batches.data, params))
    return float(on), float(off)


@functools.lru_cache(maxsize=16)
def _init_program(module: Relation):
    """g_k's jitted initialisation, one per width and depth for every fit of the process."""
    return jax.jit(module.init, compiler_options=ONCE_COMPILER_OPTIONS)


@functools.lru_cache(maxsize=16)
def _means_program(batches: Batches, module, n: int):
    """One compiled call (op by op this cost seconds of dispatch on CPU), with the parameters as
    an argument rather than baked-in constants: one program per relation width and samplers,
    kept for the relation's later rounds and the process's later fits."""

    @functools.partial(jax.jit, compiler_options=ONCE_COMPILER_OPTIONS)
    def means(key, data, params):
        k_on, k_off = jax.random.split(key)
        on = jnp.mean(jnp.abs(module.apply(params, batches.on(k_on, data, n))))
        off = jnp.mean(jnp.abs(module.apply(params, batches.off(k_off, data, n))))
        return on, off

    return means


def _pretrain(cfg, batches: Batches, module, params, prior: Callable, key):
    """Supervised warm start: regress g to tanh(prior(τ)) on on- and off-manifold rows (L1)."""
    # Plain supervised regression: the relations' step size (1e-3 by default, the step the
    # warm start has always used).
    optimizer = optax.adam(cfg.learning_rate)

    def objective(p, tau):
        target = jnp.tanh(prior(tau))
        loss = jnp.mean(jnp.abs(module.apply(p, tau) - target))
        return loss, ({}, jnp.asarray(False))

    def draw(key, data):
        k_on, k_off = jax.random.split(key)
        return jnp.concatenate([batches.on(k_on, data), batches.off(k_off, data)])

    def train_step(state, tau, data):
        return optimizer_step(state, objective, optimizer, cfg.pretrain_steps, tau)

    state = init_state(params, optimizer, key)
    chunk = make_chunk(train_step, min(cfg.chunk_steps, cfg.pretrain_steps), draw)
    return run_until_done(chunk, state, batches.data).params


def _stack(trees):
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


class Partial(Protocol):
    """Where the relation in training keeps its loop state, so that an interrupted fit resumes
    mid-relation (`relations.run` keeps it in the run directory). k is 0-based."""

    def holds(self, k: int) -> bool:
        """Whether a state of relation k is kept."""

    def restore(self, k: int, template: LoopState) -> LoopState | None:
        """Relation k's kept state, shaped as `template`, or None."""

    def save(self, k: int, state: LoopState) -> None:
        """Keep relation k's state (called after every compiled chunk; may skip some)."""


def fit(
    on_manifold,
    config: Config | None = None,
    *,
    priors: Sequence[Callable | None] | None = None,
    start: RelationSet | None = None,
    callback: Callback | None = None,
    on_relation: Callable[[RelationSet, RelationSummary], None] | None = None,
    partial: Partial | None = None,
) -> RelationSet:
    """Learn relations that vanish on `on_manifold` (Algorithm 1).

    Args:
      on_manifold: rows float [N, D]; or a sampler `key -> [B, D]`; or a `jaml.sources.Source`;
        or the path of a .npy / .csv file of rows.
      config: see `Config`.
      priors: optional heuristics h_k(τ [..., D]) -> [...]: g_k is first pre-trained to output
        tanh(h_k) on- and off-manifold (end of paper §3.2), then trained as usual.
      start: relations learned earlier (e.g. a loaded checkpoint): training continues with the
        next relation.
      callback: called as (phase, k, metrics) once per compiled chunk, for logging.
      on_relation: called with the grown RelationSet and a summary after each relation. A
        fit that trains its first relations again and keeps them reports them again: a
        summary whose index came before replaces that relation and those after it.
      partial: keeps the training state of the relation in progress (`Partial`); a fit
        started again with the same data, config and `start` continues that relation from its
        kept state, step for step as if it had not stopped (syzygy rounds restart).

    Returns:
      RelationSet with up to `max_relations` relations. A relation whose loss turns non-finite
      stops with a logged error and training ends, keeping what was learned so far.
    """
    cfg = config or Config()
    key = jax.random.key(cfg.seed)
    k_data, key = jax.random.split(key)
    batches = prepare(on_manifold, cfg.batch_size, cfg.noise_scale, k_data, cfg.eval_batches)
    units = batches.units
    if start is not None:
        if start.dim != batches.dim:
            raise ValueError(f"start relations take τ of size {start.dim}, data has {batches.dim}")
        rs = units_lib.to_fit(start, units)
    else:
        rs = RelationSet.empty(batches.dim, cfg.depth, cfg.tolerance, batches.dim_names,
                               np.asarray(batches.low), np.asarray(batches.high))
    if priors is not None and not all(p is None or callable(p) for p in priors):
        raise TypeError("priors must be a sequence of callables (or None entries)")
    if not units.identity:  # the fit trains in its own units; the user sees theirs
        priors = priors and [None if p is None else _in_fit_units(p, units) for p in priors]
        on_relation = on_relation and _in_user_units(on_relation, units)

    pool = ThreadPoolExecutor(1, thread_name_prefix="jaml-compile")
    try:
        # A fresh fit pauses at the codimension where its relation lands away on every start:
        # the relations below it train again before any relation beyond it is spent on them.
        fitted = _fit_loop(cfg, batches, rs, key, priors, callback, on_relation, pool, partial,
                           pause_away=rs.num_relations == 0 and cfg.premine_attempts > 1)
        if fitted.paused:
            fitted = _below_again(cfg, batches, rs, key, priors, callback, on_relation, pool,
                                  fitted)
            fitted = _fit_loop(cfg, batches, fitted.rs, key, priors, callback, on_relation,
                               pool, partial, after=fitted)
        return units_lib.to_user(fitted.rs, units)
    finally:
        pool.shutdown(wait=False, cancel_futures=True)


def _in_fit_units(prior: Callable, units: units_lib.Units) -> Callable:
    """A prior h(τ) of the user's τ as a function of the fit's."""
    return lambda tau: prior(units.from_fit(tau))


def _in_user_units(on_relation: Callable, units: units_lib.Units) -> Callable:
    """`on_relation` handed the set and its summary's lengths in the user's units."""

    def call(rs: RelationSet, summary: RelationSummary):
        land = units_lib.scaled_landing(summary.landing, units.scale)
        on_relation(units_lib.to_user(rs, units), dataclasses.replace(summary, landing=land))

    return call


class _Loop(NamedTuple):
    """What a fit's loop kept: the relations, where projected box points landed once the
    codimension-th relation (of at least two) was kept, what `on_relation` was given as each
    relation was kept (the set so far, its summary), how each relation ended (statuses, shares
    a fresh syzygy left unexplained: the quality report's), and whether it paused there."""

    rs: RelationSet
    land: dict | None
    kept: list
    ends: tuple[list, list]
    paused: bool = False


def _lands_away(land: dict | None) -> bool:
    """Whether more than RETRY_SPURIOUS of the projected box points land away from the data
    (or reach no zero) with the codimension-th relation kept after all its starts."""
    return land is not None and 1 - quality.on_data(land) > RETRY_SPURIOUS


def _below_again(cfg, batches, empty, key, priors, callback, on_relation, pool,
                 first: _Loop) -> _Loop:
    """The fit once more with the relations below the codimension from other starts, kept
    where more projected box points land on the data; the kept relations reach `on_relation`
    again. Where every start of the codimension-th relation leaves box points on spurious
    zeros, the surface it cuts (g_1's zero set, say) is often the cause."""
    log.info("the codimension-th relation leaves %.0f%% of projected box points away from the "
             "data on every start: the relations below it trained again from another "
             "initialisation", 100 * (1 - quality.on_data(first.land)))
    other = _fit_loop(cfg, batches, empty, key, priors, callback, None, pool,
                      below_attempt=1, pause_at_codim=True)
    if other.land is None or quality.on_data(other.land) <= quality.on_data(first.land):
        log.info("trained again, %s: the first relations kept",
                 "no relation completed the codimension" if other.land is None else
                 f"{100 * quality.on_data(other.land):.0f}% land on the data against "
                 f"{100 * quality.on_data(first.land):.0f}%")
        return first
    log.info("trained again, %.0f%% of projected box points land on the data against %.0f%%: "
             "kept", 100 * quality.on_data(other.land), 100 * quality.on_data(first.land))
    for so_far, summary in other.kept if on_relation is not None else ():
        on_relation(so_far, summary)
    return other


def _compile_ahead(cfg, batches: Batches, rs: RelationSet, params, k_next: int, pool,
                   codim: int):
    """Compile g_{k_next+1}'s training loop in a background thread while g_{k_next} trains:
    one call of the loop on a finished state (every step idle) leaves its program compiled,
    a dispatch only where an earlier fit of the process compiled it.

    The loop depends on the frozen relations only through their shapes, so the still untrained
    `params` of g_{k_next} stand in for it. Only the plain transversality loop is compiled ahead
    (syzygy rounds have data-dependent shapes). Returns {k_next: future}: wait for it before
    running that loop, or both threads compile it.
    """
    if cfg.independence != "transversality" or k_next >= cfg.max_relations:
        return {}
    width = relation_width(rs.num_relations, cfg.base_width, cfg.max_width)
    stand_in = rs.append(params, 0.0, 0.0, width)
    next_module = Relation(relation_width(k_next, cfg.base_width, cfg.max_width), cfg.depth)
    next_params = jax.eval_shape(next_module.init, jax.random.key(0), jnp.zeros((1, rs.dim)))
    next_params = jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), next_params)
    chunk, state, args = relation_trainer(
        cfg, batches, stand_in, next_params, jax.random.key(0), cfg.max_steps,
        with_mined=_with_mined(cfg, k_next, codim), clip=_clip(cfg, k_next, codim),
    )
    done = state.replace(status=jnp.asarray(CONVERGED, jnp.int32))
    # JAX's config contexts are thread-local and a compiled program is kept under the caller's:
    # the one that decides the loop's random bits is set again in the pool's thread.
    partitionable = jax.config.jax_threefry_partitionable

    def warm():
        with jax.threefry_partitionable(partitionable):
            jax.block_until_ready(chunk(done, args))

    return {k_next: pool.submit(warm)}


# ‖∇g‖ past which −log‖∇g‖ stops pushing in a relation's first last resort (None: not tried).
RETRY_GRADIENT_CAP = 0.1
RETRY_STEP_FACTOR = 0.3  # the step size's factor in its second last resort (None: not tried)
DROP_RATIO = 2.0  # off/on below which a capped relation up to the codimension is dropped
REFINE_SHARE = 5  # a refinement round's step budget: this fraction of max_steps
REFINE_HALVES = 0.5  # a round leaving this share of the points landing away may separate less
RETRY_SPURIOUS = 0.1  # a pre-mined relation with more box points landing away: tried again
COVER_KEPT = 0.8  # beyond the codimension, a relation may not cut the data's reach below this
# A start separating this share of what an exact relation reaches on the rows (the noise
# floor) is not tried again for separation, where that is below the stopping bar (None: the bar).
RETRY_FLOOR_SHARE = 0.5
COMPLETE = 0.02  # at most this share of projected box points on spurious zeros: complete
BELOW_AGAIN_KEY = 1_000  # folded into the keys of relations below the codimension trained again
CALIBRATION_ROWS = 4096  # training rows both tolerances are calibrated on


def _grow(cfg, batches: Batches, rs: RelationSet, module, params, width, key, syzygies=0):
    """rs with g = module(params) appended: its on/off means recorded on fresh batches and
    `project`'s residual tolerance calibrated on training rows (`holds`' distance tolerance is
    set once the relation is kept: no decision of the fit reads it)."""
    on_mean, off_mean = record_means(cfg, batches, module, params, key)
    grown = rs.append(params, on_mean, off_mean, width, syzygies)
    tolerance = quality.calibrated_tolerance(grown, batches.dense[:CALIBRATION_ROWS])
    return grown.replace(tolerance=tolerance), on_mean, off_mean


class _Fitted(NamedTuple):
    """A relation as trained so far: its loop state, the set grown by it, its recorded means
    and Algorithm 1's status."""

    state: LoopState
    grown: RelationSet
    on_mean: float
    off_mean: float
    status: int

    @property
    def ratio(self) -> float:
        return self.off_mean / max(self.on_mean, 1e-30)


def _refine(cfg, batches, rs, module, width, fitted: _Fitted, within, codim, callback,
            k_train, k_mine, k_eval, pool=None, clip: float = MINED_CLIP):
    """Where the intersection with g_k has parts away from the data, train g_k on, pushed off
    the points that landed there (and those mined before), for up to `refine_rounds` rounds.
    A round is kept only if more projected points then land on the data and g_k still
    separates (down to the stopping rule's ratio, or to DROP_RATIO where the round at least
    halves the share landing away of the codimension-th relation); otherwise g_k stays as it
    was.

    Returns (the relation as kept, its landing shares, rounds kept, steps spent). The status
    stays that of Algorithm 1's stopping rule: a round ends where its mined rows clear or at
    its budget.
    """
    k = rs.num_relations
    pool, land = mine(cfg, fitted.grown, batches, jax.random.fold_in(k_mine, 1), within, pool,
                      codim)
    kept, spent = 0, 0
    for r in range(cfg.refine_rounds if cfg.mined_weight > 0 else 0):
        if land["spurious"] <= COMPLETE:
            break
        log.info("relation %d: %.0f%% of projected box points land away from the data; "
                 "refining (round %d)", k + 1, 100 * land["spurious"], r + 1)
        refined = _fit_relation(cfg, batches, rs, fitted.state.params,
                                jax.random.fold_in(k_train, 100 + r), cfg.max_steps,
                                callback=callback, phase="refine", pool=pool,
                                budget=max(cfg.max_steps // REFINE_SHARE, 1),
                                codim=codim, clip=clip)
        spent += int(refined.step)
        if int(refined.status) == NONFINITE:
            break
        grown, on_mean, off_mean = _grow(cfg, batches, rs, module, refined.params, width, k_eval)
        candidate = _Fitted(refined, grown, on_mean, off_mean, fitted.status)
        new_pool, new_land = mine(cfg, grown, batches, jax.random.fold_in(k_mine, 2 + r),
                                  within, pool, codim)
        # Separation may give way to landing, down to the stopping rule's; for the relation
        # completing the codimension, a round that at least halves the share landing away,
        # down to what keeps it (under noise the push off a spurious branch near the data
        # costs separation on the noisy rows).
        away, new_away = 1 - quality.on_data(land), 1 - quality.on_data(new_land)
        halves = new_away <= REFINE_HALVES * away and k + 1 <= codim
        floor = DROP_RATIO if halves else cfg.separation_ratio
        if new_away >= away or candidate.ratio < min(fitted.ratio, floor):
            log.info("relation %d: refining did not help (%.0f%% → %.0f%% land on the data, "
                     "off/on %.1f); kept as before", k + 1, 100 * quality.on_data(land),
                     100 * quality.on_data(new_land), candidate.ratio)
            break
        fitted, pool, land, kept = candidate, new_pool, new_land, kept + 1
    return fitted, land, kept, spent


def _joint_syzygy(cfg, batches, rs: RelationSet, module, state: LoopState, key, callback):
    """g_k trained on with its syzygy network f alongside (`syzygy.joint_trainer`); the fit
    judges it afterwards, as kept, by a fresh f (`unexplained_share`). Returns (state, steps)."""
    k = rs.num_relations
    earlier = [Relation(w, rs.depth) for w in rs.widths]
    level = choose_thickening(cfg, batches, rs, key)
    objective = _relation_objective(cfg, module, earlier, 0, with_mined=False)
    chunk, joint, args = syzygy.joint_trainer(
        cfg, batches, objective, module, earlier, rs.params, state.params,
        jax.random.fold_in(key, 1), level, cfg.max_steps, cfg.syzygy_clip)
    report = None
    if callback is not None:
        report = lambda s, m, n: callback("push", k, {"step": int(s.step), "steps": n, **m})  # noqa: E731
    joint = run_until_done(chunk, joint, args, report)
    log.info("relation %d: trained beside its syzygy network (%d steps)", k + 1,
             int(joint.step))
    return state.replace(params=joint.params["g"], status=joint.status), int(joint.step)


def unexplained_share(cfg, batches, rs: RelationSet, g_k: Callable | tuple, key,
                      callback: Callback | None = None) -> float:
    """Share of mean |g_k| that a restricted syzygy of the relations `rs`, fitted afresh
    (Algorithm 1's f, on thickened rows), leaves unexplained on test rows: near 0, g_k is a
    copy of them (Σ_j f_j g_j); at least 1/separation_ratio, it is new."""
    level = choose_thickening(cfg, batches, rs, key)
    _, _, info = fit_syzygy(cfg, batches, _relation_pairs(rs), g_k, jax.random.fold_in(key, 1),
                            level, callback, rs.num_relations)
    return info["residual"] / max(info["g_scale"], 1e-30)


def _beyond_codimension_unneeded(cfg: Config, unexplained: float, land, before) -> str:
    """Why a syzygy-trained relation of a `transversal_first` fit (so beyond the data's
    codimension) is not kept, or "" if it is: a fresh syzygy explains it, no more projected
    box points land on the data with it than without, or they reach less of the data with it
    (below COVER_KEPT of the share without it: its zero set cuts the data's)."""
    if not cfg.transversal_first:
        return ""
    if unexplained * cfg.separation_ratio < 1:
        return (f"is a restricted syzygy of the earlier ones (a fresh syzygy network explains "
                f"all but {100 * unexplained:.0f}% of it): not new")
    if land is None or before is None:
        return ""
    with_it, without = quality.on_data(land), quality.on_data(before)
    if with_it <= without:
        return (f"is new, but no more projected box points land on the data with it "
                f"({100 * with_it:.0f}% against {100 * without:.0f}% without it)")
    reach, reach_before = land["coverage"], before["coverage"]
    if reach < COVER_KEPT * reach_before:
        return (f"is new, but cuts the data: the landed points reach {100 * reach:.0f}% of the "
                f"data's rows with it against {100 * reach_before:.0f}% without it")
    return ""


def _relation_config(cfg: Config, k: int, codim: int) -> Config:
    """The config g_{k+1} trains with: in a syzygy fit with `transversal_first`, the relations
    up to the data's codimension train as a transversality fit's."""
    if cfg.independence == "syzygy" and cfg.transversal_first and k + 1 <= codim:
        return dataclasses.replace(cfg, independence="transversality")
    return cfg


def _start_ends(rs: RelationSet) -> tuple[list[str], list[float | None]]:
    """How the relations a fit starts from ended, as their quality report says: statuses
    ("restored" where it has none: a checkpoint written before the fit's report) and the
    shares a fresh syzygy left unexplained."""
    recorded = (rs.quality or {}).get("relations", [])
    ends = [recorded[j] if j < len(recorded) else {"status": "restored"}
            for j in range(rs.num_relations)]
    return [e["status"] for e in ends], [e.get("unexplained") for e in ends]


def _last_resorts(cfg: Config) -> list[tuple[Config, range, str]]:
    """What a relation no start separates trains again with, in turn: each config, the starts
    it trains (their indices) and what it changes. First the starts after the first with
    −log‖∇g‖ capped at RETRY_GRADIENT_CAP (not where the user caps it already), then every start
    at RETRY_STEP_FACTOR of the step size."""
    resorts = []
    if cfg.gradient_cap is None and RETRY_GRADIENT_CAP is not None:
        resorts.append((dataclasses.replace(cfg, gradient_cap=RETRY_GRADIENT_CAP),
                        range(1, cfg.premine_attempts),
                        f"the push of −log‖∇g‖ capped at ‖∇g‖ = {RETRY_GRADIENT_CAP:g}"))
    if RETRY_STEP_FACTOR is not None:
        resorts.append((dataclasses.replace(cfg, learning_rate=cfg.learning_rate
                                            * RETRY_STEP_FACTOR), range(cfg.premine_attempts),
                        f"at {RETRY_STEP_FACTOR:g} of the step size"))
    return resorts


def _lands_better(other: _Fitted, other_land: dict, kept: _Fitted, land: dict,
                  bar: float) -> bool:
    """Whether another training of g_k replaces the one kept: more projected box points on
    the data, separating on- from off-rows no less than the kept one (or the bar)."""
    return (quality.on_data(other_land) > quality.on_data(land)
            and other.ratio >= min(kept.ratio, bar))


def _noise_floor(cfg: Config, batches: Batches, codim: int, key) -> dict:
    """What an exact relation's stopping statistic reaches on the rows training sees (the
    data's, with `noise_scale`'s noise; `quality.separation_floor`), beside the bar; says so
    where their scatter puts the bar out of reach (relations then end capped however well
    they fit)."""
    rows = batches.noisy(jax.random.fold_in(key, 1), batches.dense)
    floor = quality.separation_floor(rows, codim, key, batches.low, batches.high,
                                     cfg.separation_top_fraction)
    floor["separation_ratio"] = cfg.separation_ratio
    if floor["separation"] < cfg.separation_ratio:
        log.warning("the rows scatter %.2g%% of the box diagonal across their manifold: an exact "
                    "relation separates them from the box only %.1fx, below the stopping bar "
                    "(%g), so relations end capped; judge them by where projected points land",
                    100 * floor["across"], floor["separation"], cfg.separation_ratio)
    return floor


def _fit_loop(fit_cfg, batches, rs, key, priors, callback, on_relation, pool, partial=None,
              below_attempt: int = 0, pause_away: bool = False,
              pause_at_codim: bool = False, after: _Loop | None = None) -> _Loop:
    """Algorithm 1 from `rs` on; `below_attempt` > 0 draws the relations below the data's
    codimension from another start (every key of theirs folded with it). The loop pauses
    (no report) once the codimension-th relation of at least two is kept, with `pause_at_codim`
    always, with `pause_away` where it `_lands_away`; `after` (a paused loop's) goes on from
    it, as if it had not paused."""
    ahead = {}
    kept, codim_land = [], None  # (the set so far, its summary) as each relation is kept
    statuses, unexplained = _start_ends(rs) if after is None else map(list, after.ends)
    kept_land = None  # where projected box points land on the relations kept so far
    if after is not None:
        kept_land = codim_land = after.land
    mining = fit_cfg.mined_weight > 0
    within = quality.landing_distance(batches.dense, batches.held_out, batches.low, batches.high)
    codim = fit_cfg.codimension or quality.data_codimension(batches.dense,
                                                            jax.random.fold_in(key, 5))
    codim_from = "given" if fit_cfg.codimension else quality.BY_LOCAL_PCA
    bands = 0  # directions across the rows read as a band: one relation is still tried there
    if not fit_cfg.codimension and codim >= 2:
        band = quality.band_directions(batches.dense, codim, jax.random.fold_in(key, 5))
        if band["bands"]:
            scatter = band["scatter"]
            log.info("the rows fill a band across %d of the local PCA's %d directions off them "
                     "(scatter %s of the box diagonal, %.0fx the tightest): %s, not a "
                     "relation; fitting codimension %d (Config.codimension=%d fits a relation "
                     "there)", band["bands"], codim,
                     ", ".join(f"{100 * x:.2g}%" for x in scatter[-band["bands"]:]),
                     scatter[-1] / max(scatter[0], 1e-30),
                     "a band" if band["bands"] == 1 else "bands", codim - band["bands"], codim)
            log.info("a relation beyond it is still tried, and kept only if it separates "
                     "on- from off-manifold rows fully (noise around a surface can)")
            bands = band["bands"]
            codim -= bands
            codim_from = f"{quality.BY_LOCAL_PCA}, less {band['bands']} band direction" + (
                "s" if band["bands"] > 1 else "")
    if codim == 0:  # the local PCA saw the data fill its neighbourhoods: noise, or too few rows
        log.warning("the data's local PCA finds no codimension (its neighbourhoods are full: "
                    "noisy or few rows); fitting as codimension 1 (Config.codimension sets it)")
        codim, codim_from = 1, f"{quality.BY_LOCAL_PCA} 0, taken as 1"
    log.info("the data's codimension: %d%s", codim, "" if fit_cfg.codimension else
             " (local PCA of the data; Config.codimension overrides it)")
    if fit_cfg.independence == "syzygy" and fit_cfg.transversal_first:
        log.info("syzygy mode: g_1..g_%d (the data's codimension) train with transversality, "
                 "restricted syzygies train the relations beyond (Config.transversal_first)",
                 codim)
    noise = _noise_floor(fit_cfg, batches, codim, jax.random.fold_in(key, 6))
    retry_bar = fit_cfg.separation_ratio if RETRY_FLOOR_SHARE is None else min(
        fit_cfg.separation_ratio, RETRY_FLOOR_SHARE * noise["separation"])
    complete = (after is not None and fit_cfg.stop_when_complete and after.land is not None
                and after.land["spurious"] <= COMPLETE)  # it would have stopped there
    for k in range(rs.num_relations, rs.num_relations if complete else fit_cfg.max_relations):
        cfg = _relation_config(fit_cfg, k, codim)  # g_{k+1}'s: by the fit's, or transversal
        started = time.perf_counter()
        k_key = jax.random.fold_in(key, k)
        if below_attempt and k + 1 < codim:
            k_key = jax.random.fold_in(k_key, BELOW_AGAIN_KEY + below_attempt)
        k_init, k_pre, k_train, k_syz, k_eval = jax.random.split(k_key, 5)
        k_mine = jax.random.fold_in(k_key, 7)
        width = relation_width(k, cfg.base_width, cfg.max_width)
        module = Relation(width, cfg.depth)
        init = _init_program(module)
        example_tau = jnp.zeros((1, batches.dim))
        params = init(k_init, example_tau)
        ahead |= _compile_ahead(_relation_config(fit_cfg, k + 1, codim), batches, rs, params,
                                k + 1, pool, codim)
        resuming = partial is not None and partial.holds(k)
        if priors is not None and k < len(priors) and priors[k] is not None and not resuming:
            params = _pretrain(cfg, batches, module, params, priors[k], k_pre)
        # From the codim-th relation on, the intersection should be the data: its parts away
        # from the data are spurious, and g_k is refined not to vanish there (below).
        completing = k + 1 >= codim
        warm = ahead.pop(k, None)
        if warm is not None:
            warm.result()

        def start_of(attempt, params=params, keys=(k_init, k_train), init=init,
                     example=example_tau):
            """Start `attempt` of g_k: its initial parameters and training key (0: the first)."""
            k_init, k_train = keys
            if attempt == 0:
                return params, k_train
            return (init(jax.random.fold_in(k_init, attempt), example),
                    jax.random.fold_in(k_train, attempt))

        def plain_fit(params, rs=rs, k_train=k_train, cfg=cfg):  # the paper's way, no mined rows
            return _fit_relation(cfg, batches, rs, params, k_train, cfg.max_steps,
                                 callback=callback, codim=codim)

        def refine(state, pool=None, clip=MINED_CLIP, rs=rs, module=module, width=width,
                   keys=(k_train, k_mine, k_eval), cfg=cfg):
            """g_k as trained: its means recorded, then `_refine`d."""
            grown = _grow(cfg, batches, rs, module, state.params, width, keys[2])
            return _refine(cfg, batches, rs, module, width,
                           _Fitted(state, *grown, int(state.status)), within, codim,
                           callback, *keys, pool, clip)

        premined, clip = None, MINED_CLIP
        # Resuming, the mined rows are not kept: training goes on the paper's way.
        if _premines(cfg, k, codim) and not resuming:
            premined, _ = mine(cfg, rs, batches, jax.random.fold_in(k_mine, 0), within,
                               codim=codim)
            clip = cfg.premine_clip
            log.info("relation %d: %d points of the earlier relations' zero set away from "
                     "the data mined before training", k + 1, premined[1])
        state = _fit_relation(
            cfg,
            batches,
            rs,
            params,
            k_train,
            cfg.max_steps,
            callback=callback,
            partial=partial,
            codim=codim,
            pool=premined,
            clip=clip,
            budget=cfg.premine_steps if premined is not None else None,
        )
        steps, status, rounds = int(state.step), int(state.status), []
        syzygies = cfg.independence == "syzygy" and k > 0 and status != NONFINITE
        if syzygies and cfg.syzygy_training == "joint":
            state, spent = _joint_syzygy(cfg, batches, rs, module, state, k_syz, callback)
            steps += spent
            status = int(state.status)
        elif syzygies:
            syz_found = []
            for s in range(cfg.syzygies_per_relation):
                ks = jax.random.fold_in(k_syz, s)
                level = choose_thickening(cfg, batches, rs, ks)
                f_params, found, info = fit_syzygy(
                    cfg,
                    batches,
                    _relation_pairs(rs),
                    (module, state.params),
                    jax.random.fold_in(ks, 1),
                    level,
                    callback,
                    k,
                )
                rounds.append(info)
                log.info(
                    "relation %d syzygy %d: residual %.4g vs |g| %.4g -> %s",
                    k + 1,
                    s + 1,
                    info["residual"],
                    info["g_scale"],
                    "found" if found else "none",
                )
                # Soft / incremental syzygies (paper App. B.3.1): the push away from f is
                # applied every round, "even if f did not reach output close to zero".
                syz_found.append(f_params)
                state = _fit_relation(
                    cfg,
                    batches,
                    rs,
                    state.params,
                    jax.random.fold_in(ks, 2),
                    cfg.push_steps,
                    syz_params=_stack(syz_found),
                    thickening=level,
                    callback=callback,
                    phase="push",
                    codim=codim,
                )
                steps += int(state.step)
                status = int(state.status)
                if status == NONFINITE:
                    break
        if premined is not None and status == NONFINITE:
            log.info("relation %d: its loss became non-finite on mined rows; trained again "
                     "without them", k + 1)
            premined, clip = None, MINED_CLIP
            state = plain_fit(params)
            steps += int(state.step)
            status = int(state.status)
        if status == NONFINITE:
            log.error(
                "relation %d: loss became non-finite at step %d; stopping with the %d "
                "relations learned so far",
                k + 1,
                steps,
                rs.num_relations,
            )
            break
        land, refined_rounds = None, 0
        last = k + 1 == cfg.max_relations  # the final report measures it anyway
        if not (completing and (mining or (cfg.stop_when_complete and not last))):
            grown, on_mean, off_mean = _grow(cfg, batches, rs, module, state.params, width,
                                             k_eval)
            # Below the codimension nothing is refined or tried again for landing, but a
            # relation capped without separating may have settled where a steep g vanishes on
            # the data yet not on its noisy rows: other starts, then the last resorts, may
            # separate.
            retries = not (completing or syzygies) and cfg.premine_attempts > 1
            tries = [(cfg, attempt, "from another initialisation")
                     for attempt in range(1, cfg.premine_attempts)] + [
                (resort, attempt, how) for resort, attempts, how in _last_resorts(cfg)
                for attempt in attempts]
            for try_cfg, attempt, how in tries if retries else ():
                if status != CAPPED or off_mean >= retry_bar * on_mean:
                    break
                log.info("relation %d: capped separating only %.1fx; start %d once more, %s",
                         k + 1, off_mean / max(on_mean, 1e-30), attempt + 1, how)
                start, k_start = start_of(attempt)
                again = plain_fit(start, k_train=k_start, cfg=try_cfg)
                steps += int(again.step)
                if int(again.status) == NONFINITE:
                    continue
                other, other_on, other_off = _grow(cfg, batches, rs, module, again.params, width,
                                                   k_eval)
                if other_off * on_mean > off_mean * other_on:  # separates more
                    state, status = again, int(again.status)
                    grown, on_mean, off_mean = other, other_on, other_off
        else:
            fitted, land, refined_rounds, spent = refine(state, premined, clip)
            steps += spent
            attempt = 1
            # The codimension-th relation is tried again from other initialisations: the
            # pre-mined one, and the first one at codimension 1 (no earlier zero set to
            # pre-mine) unless a prior sets its start.
            retried = premined is not None or (
                k == 0 and codim == 1 and (not priors or priors[0] is None))
            while retried and attempt < cfg.premine_attempts and (
                    fitted.ratio < retry_bar or land["spurious"] > RETRY_SPURIOUS):
                # Where g_k starts decides which surface through the data it settles on: from
                # another initialisation the zero set may have no spurious part. (A sign that
                # changes away from the data, as a near-linear start leaves it, puts a zero
                # there that no local push can remove.)
                log.info("relation %d: %.0f%% of projected box points land away from the data "
                         "(off/on %.1f); %s again from another initialisation", k + 1,
                         100 * land["spurious"], fitted.ratio,
                         "pre-mined" if premined is not None else "trained")
                start, k_start = start_of(attempt)
                if premined is None:
                    again = plain_fit(start, k_train=k_start)
                else:
                    again = _fit_relation(
                        cfg, batches, rs, start, k_start, cfg.max_steps, callback=callback,
                        codim=codim, pool=premined, clip=clip,
                        budget=cfg.premine_steps)
                attempt += 1
                steps += int(again.step)
                if int(again.status) == NONFINITE:
                    continue
                other, other_land, other_rounds, spent = refine(again, premined, clip)
                steps += spent
                if _lands_better(other, other_land, fitted, land, cfg.separation_ratio):
                    fitted, land, refined_rounds = other, other_land, other_rounds
            if premined is not None and fitted.ratio < retry_bar:
                # Pushed off the earlier zero set, g_k may no longer separate on- from off-rows
                # (rows mined "away from the data" can lie on it where the data are sparse):
                # trained again the paper's way, then refined, and kept only where it lands
                # more or the pre-mined one would be dropped (under noise no start reaches the
                # bar, and a start without spurious zeros is worth more than a little more
                # separation).
                log.info("relation %d: trained on mined rows it separates only %.1fx; trained "
                         "again without them", k + 1, fitted.ratio)
                state = plain_fit(params)
                steps += int(state.step)
                plain = None
                if int(state.status) != NONFINITE:
                    plain, plain_land, plain_rounds, spent = refine(state)
                    steps += spent
                if plain is not None and (
                        fitted.ratio < DROP_RATIO < plain.ratio
                        or _lands_better(plain, plain_land, fitted, land, cfg.separation_ratio)):
                    premined, fitted, land, refined_rounds = None, plain, plain_land, plain_rounds
                elif plain is None:
                    log.info("relation %d: without them its loss became non-finite: the "
                             "pre-mined one kept", k + 1)
                else:
                    log.info("relation %d: without them %.0f%% of projected box points land on "
                             "the data (off/on %.1f) against %.0f%%: the pre-mined one kept",
                             k + 1, 100 * quality.on_data(plain_land), plain.ratio,
                             100 * quality.on_data(land))
            # No start separated, so the relation would be dropped, or every start leaves
            # spurious zeros (or points that reach none). Starts tend to settle in one basin
            # there: a g_k with zeros everywhere (steep and wiggly, d_g small on and off the
            # data), which −log‖∇g‖ rewards and a large step reaches early (on noisy rows it
            # still separates a little). The same starts again, that push capped; then every
            # start at a smaller step. One that separates replaces one that does not; else one
            # that lands more.
            for resort, attempts, how in _last_resorts(cfg) if retried else ():
                for attempt in attempts:
                    separates, away = fitted.ratio >= DROP_RATIO, 1 - quality.on_data(land)
                    if separates and away <= RETRY_SPURIOUS:
                        break
                    log.info("relation %d: %s; start %d once more, %s", k + 1,
                             f"{100 * away:.0f}% of projected box points land away from the "
                             "data or reach no zero on every start" if separates else
                             f"no start separates (off/on {fitted.ratio:.1f})", attempt + 1, how)
                    start, k_start = start_of(attempt)
                    again = plain_fit(start, k_train=k_start, cfg=resort)
                    steps += int(again.step)
                    if int(again.status) == NONFINITE:
                        continue
                    other, other_land, other_rounds, spent = refine(again, cfg=resort)
                    steps += spent
                    if (_lands_better(other, other_land, fitted, land, DROP_RATIO) if separates
                            else other.ratio > fitted.ratio):  # trained without mined rows
                        premined, fitted, land, refined_rounds = (None, other, other_land,
                                                                  other_rounds)
            state, grown, on_mean, off_mean, status = fitted
            if (premined is not None and status == CAPPED
                    and fitted.ratio >= cfg.separation_ratio):
                # Its loop also waits for the mined rows to clear, which is jaml's target, not
                # Algorithm 1's rule: that rule (off/on ≥ separation_ratio) holds, so it is done.
                status = CONVERGED
        summary = RelationSummary(
            index=k + 1,
            width=width,
            steps=steps,
            seconds=time.perf_counter() - started,
            status=STATUS_NAMES[status],
            on_mean=on_mean,
            off_mean=off_mean,
            syzygies_found=sum(r["found"] for r in rounds),
            syzygy_rounds=rounds,
            refined=refined_rounds,
        )
        # Not a relation: capped without separating on- from off-manifold rows (the paper's
        # termination: no further relation vanishes on the data and nowhere else). Up to the
        # data's codimension a relation is needed, so only one that barely separates goes;
        # beyond it a relation must separate fully to earn its place.
        needed = cfg.separation_ratio if k + 1 > codim else DROP_RATIO
        if cfg.stop_when_complete and status == CAPPED and summary.ratio < needed:
            log.warning(
                "relation %d is not a relation (capped; %d steps in all its trainings, off/on "
                "%.1f < %g): dropped; "
                "stopping with %d relations", k + 1, steps, summary.ratio, needed,
                rs.num_relations)
            break
        if syzygies:
            summary.unexplained = unexplained_share(cfg, batches, rs, (module, state.params),
                                                    jax.random.fold_in(k_syz, 1_000), callback)
            log.info("relation %d: a fresh syzygy of the earlier relations leaves %.0f%% of it "
                     "unexplained", k + 1, 100 * summary.unexplained)
            # Beyond the codimension the data is cut already: a relation earns its place by
            # being new and by moving more projected points onto the data (off a spurious part).
            why = _beyond_codimension_unneeded(cfg, summary.unexplained, land, kept_land)
            if why:
                log.warning("relation %d %s: dropped, stopping with %d relations", k + 1, why,
                            rs.num_relations)
                break
        rows = batches.on(jax.random.fold_in(k_eval, 1), batches.data, RANK_ROWS)
        summary.codimension = codimension(grown, rows)
        if land is not None:
            summary.landing = kept_land = land
            if k + 1 == codim >= 2:
                codim_land = land
        rs = grown.replace(syzygies=(*rs.syzygies, summary.syzygies_found),
                           distance_tolerance=quality.distance_tolerance(
                               grown, batches.dense[:CALIBRATION_ROWS]))
        statuses.append(summary.status)
        unexplained.append(summary.unexplained)
        log.info(
            "relation %d %s after %d steps (%.1fs): mean |g| on %.4g off %.4g (x%.1f)",
            k + 1,
            summary.status,
            steps,
            summary.seconds,
            on_mean,
            off_mean,
            summary.ratio,
        )
        kept.append((rs, summary))
        if on_relation is not None:
            on_relation(rs, summary)
        if k + 1 == codim >= 2 and (pause_at_codim or (pause_away and _lands_away(land))):
            return _Loop(rs, codim_land, kept, (statuses, unexplained), paused=True)
        # Where a band was read off the codimension, a relation beyond it is still tried: it is
        # kept only if it separates fully (noise around a surface can; a band does not).
        if cfg.stop_when_complete and land is not None and land["spurious"] <= COMPLETE and \
                k + 1 < cfg.max_relations and not (bands and k + 1 == codim):
            log.info("relations complete: %.0f%% of projected box points land on the data, "
                     "none away from it; stopping at %d relations", 100 * quality.on_data(land),
                     k + 1)
            break
    if rs.num_relations:
        report = quality.assess(rs, jax.random.fold_in(key, 10_000), batches.held_out,
                                batches.dense, batches.low, batches.high, statuses, codim,
                                codim_from, noise, unexplained)
        rs = rs.replace(quality=report)
        for line in units_lib.scaled_report(report, batches.units.scale)["lines"]:
            (log.warning if line.startswith("warning") else log.info)("%s", line)
    return _Loop(rs, codim_land, kept, (statuses, unexplained))


__all__ = [
    "Partial",
    "RelationSummary",
    "choose_thickening",
    "fit",
    "fit_syzygy",
    "record_means",
    "relation_trainer",
    "unexplained_share",
]
