"""The learned manifold {g_1 = … = g_K = 0}: points moved onto it, and whether the relations cut
K dimensions there (the rank of their Jacobian, the paper's transversality lemma)."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaml.relations.loop import ONCE_COMPILER_OPTIONS
from jaml.relations.relation_set import (
    RelationSet,
    _check_tau,
    canonical,
    evaluate,
    evaluate_raw,
    holds,
    require_relations,
)

DEFAULT_RANK_RTOL = 0.1  # σ_i / σ_1 of the row-normalised Jacobian; for K = 2, tan(θ/2) > 0.1


def _relations_fn(relations) -> Callable:
    """G: τ [D] → [K] from a RelationSet or a user function of τ [..., D] → [..., K]."""
    if isinstance(relations, RelationSet):
        return lambda t: evaluate(relations, t)
    if callable(relations):
        return relations
    raise TypeError(f"relations must be a RelationSet or a callable, got {type(relations)}")


class Projection(NamedTuple):
    """What `project` returns: the moved points, G there, and whether every equation holds."""

    points: jax.Array  # [..., D]
    residuals: jax.Array  # [..., K] G(points)
    converged: jax.Array  # bool [...]


def _gauss_newton(fn, tau, mask, low, high, steps: int, rtol, max_step):
    """`steps` minimum-norm steps δ = −J⁺ G(τ) per row, J's fixed columns zeroed by `mask`.

    A trust region: each step is at most `max_step` long, halved (up to 3 times) until ‖G‖
    decreases (else the point stays), and every iterate, the start too, stays in the box
    [low, high]: where a tanh network saturates its gradient is tiny, and a full step would
    leave for infinity.
    """

    def one_row(t):
        def step(t, _):
            g = fn(t)
            jac = jax.jacfwd(fn)(t) * mask  # [K, D]
            u, s, vt = jnp.linalg.svd(jac, full_matrices=False)
            keep = s > rtol * jnp.max(s, initial=0.0)
            inv = jnp.where(keep, 1.0 / jnp.where(keep, s, 1.0), 0.0)
            delta = vt.T @ (inv * (u.T @ g))
            delta = delta * jnp.minimum(1.0, max_step / jnp.maximum(jnp.linalg.norm(delta), 1e-30))
            tries = jnp.clip(t - _HALVINGS[:, None] * delta, low, high)  # [4, D]
            norms = jnp.linalg.norm(jax.vmap(fn)(tries), axis=-1)
            better = norms < jnp.linalg.norm(g)
            # No try reduces ‖G‖: stay (a full step from a saturated point only wanders off).
            return jnp.where(jnp.any(better), tries[jnp.argmax(better)], t), None

        t, _ = jax.lax.scan(step, jnp.clip(t, low, high), None, length=steps)
        return t, fn(t)

    return jax.vmap(one_row)(tau)


_HALVINGS = jnp.asarray([1.0, 0.5, 0.25, 0.125])
# The trust region's defaults, in units of the data's box: steps of at most a tenth of its
# diagonal, iterates inside the box grown by half its width on every side.
STEP_FRACTION = 0.1
BOX_MARGIN = 0.5


@functools.partial(jax.jit, static_argnames="steps")
def _project_set(rs: RelationSet, tau, mask, low, high, steps: int, rtol, max_step):
    # Gauss–Newton on atanh g (the outputs before their tanh): the same zero set, but no
    # plateau where a relation saturates at ±1 and its gradient underflows to zero.
    scale = 1.0 / jnp.maximum(rs.on_means, 1e-30)
    points, _ = _gauss_newton(
        lambda t: evaluate_raw(rs, t) * scale, tau, mask, low, high, steps, rtol, max_step
    )
    return points, evaluate(rs, points)


def trust_region(bounds, dim: int, max_step=None):
    """(low, high, max_step) of `project`'s trust region from the data box `bounds` (or None:
    unbounded, unless `max_step` is given)."""
    if bounds is None:
        low = jnp.full((dim,), -jnp.inf)
        high = jnp.full((dim,), jnp.inf)
        return low, high, (jnp.inf if max_step is None else max_step)
    low, high = (np.asarray(b, np.float32).reshape(dim) for b in bounds)
    width = high - low
    if max_step is None:
        max_step = STEP_FRACTION * float(np.linalg.norm(width))
    return (jnp.asarray(low - BOX_MARGIN * width), jnp.asarray(high + BOX_MARGIN * width),
            max_step)


def project(relations, tau, steps: int = 50, free=None, max_step: float | None = None,
            rtol: float = 1e-6, bounds=None, tolerance: float = 1e-3) -> Projection:
    """Move τ [..., D] onto the learned manifold by damped Gauss–Newton steps; returns a
    `Projection` (points [..., D], residuals G(points) [..., K], converged bool [...]).

    Each step is the minimum-norm solution of J δ = −G (J⁺ through an SVD of the K×D Jacobian,
    singular values below rtol·σ_max dropped), so a point moves as little as it must; for
    relations linear in τ one step lands on the nearest point of their intersection. A trust
    region keeps it from diverging: steps are cut to `max_step` (default: a tenth of the data
    box's diagonal) and halved while they do not reduce ‖G‖, and points stay inside the box
    grown by half its width on each side. `bounds` = (low, high) is that box; a RelationSet
    carries its own. `free` (bool [D]) restricts the moves to those coordinates, e.g. the next
    state of a transition for given start (s0, v0). `relations`: a RelationSet, or a function
    τ [..., D] → [..., K]. `converged`: `holds` at the point for a RelationSet; every
    |G_k| ≤ `tolerance` for a function. A RelationSet's g_k are measured in units of their
    recorded on-manifold means, which matters only where the K equations cannot all hold.
    """
    if isinstance(relations, RelationSet):
        require_relations(relations, "project")
        tau = _check_tau(relations, tau)
        if bounds is None and relations.low:
            bounds = (relations.low, relations.high)
    tau = jnp.asarray(tau)
    if not jnp.issubdtype(tau.dtype, jnp.floating):
        tau = tau.astype(jnp.float32)
    dim = tau.shape[-1]
    mask = jnp.ones((dim,), tau.dtype) if free is None else jnp.asarray(free, tau.dtype)
    if mask.shape != (dim,):
        raise ValueError(f"free must have shape ({dim},), got {mask.shape}")
    if steps < 1:
        raise ValueError(f"steps must be ≥ 1, got {steps}")
    low, high, max_step = trust_region(bounds, dim, max_step)
    flat = tau.reshape(-1, dim)
    # Fixed coordinates stay where they are, even outside the box.
    low = jnp.where(mask > 0, low, -jnp.inf)
    high = jnp.where(mask > 0, high, jnp.inf)
    if isinstance(relations, RelationSet):
        points, residuals = _project_set(canonical(relations), flat, mask, low, high, steps,
                                         rtol, max_step)
        converged = holds(relations, points, by="value")  # residuals at the data's level
    else:
        run = jax.jit(functools.partial(_gauss_newton, _relations_fn(relations), steps=steps))
        points, residuals = run(flat, mask, low, high, rtol=rtol, max_step=max_step)
        converged = jnp.all(jnp.abs(residuals) <= tolerance, axis=-1)
    lead = tau.shape[:-1]
    return Projection(points.reshape(tau.shape), residuals.reshape(*lead, -1),
                      converged.reshape(lead))


def _jacobian_geometry(fn, tau):
    """([N, K] singular values of the row-normalised Jacobian at each row over the largest,
    [N, K, K] |cos| between the K gradients there): one pass serves both measures."""

    def one_row(t):
        jac = jax.jacfwd(fn)(t)
        norms = jnp.linalg.norm(jac, axis=-1, keepdims=True)
        flat = norms == 0.0  # no direction at all; any other length is scaled to 1
        unit = jnp.where(flat, 0.0, jac / jnp.where(flat, 1.0, norms))
        s = jnp.linalg.svd(unit, compute_uv=False)
        s = jnp.pad(s, (0, jac.shape[0] - s.shape[0]))  # K > D: the missing ones are zero
        return s / jnp.maximum(s[0], 1e-30), jnp.abs(unit @ unit.T)

    return jax.vmap(one_row)(tau)


@functools.partial(jax.jit, compiler_options=ONCE_COMPILER_OPTIONS)
def _jacobian_geometry_set(rs: RelationSet, tau):
    return _jacobian_geometry(lambda t: evaluate(rs, t), tau)


def _geometry(relations, tau):
    tau = jnp.asarray(tau).reshape(-1, jnp.shape(tau)[-1])
    if isinstance(relations, RelationSet):
        out = _jacobian_geometry_set(canonical(relations), _check_tau(relations, tau))
    else:
        out = jax.jit(functools.partial(_jacobian_geometry, _relations_fn(relations)))(tau)
    return tuple(np.asarray(x) for x in out)


def jacobian_ranks(relations, tau, rtol: float = DEFAULT_RANK_RTOL):
    """(ranks int [N], σ ratios [N, K]) of the K×D Jacobian of (g_1..g_K) at rows τ [N, D].

    Each gradient is scaled to unit length first (learned g_k's gradients differ in scale by
    orders of magnitude, and transversality is about directions), a zero one stays zero; the
    rank counts singular values above rtol × the largest. With K ≤ D, rank K means the K
    gradients are independent there, i.e. the zero sets cut K dimensions (transversality).
    """
    ratios, _ = _geometry(relations, tau)
    return (ratios > rtol).sum(-1), ratios


def pairwise_cosines(relations, tau) -> np.ndarray:
    """[K, K]: the median over rows τ [N, D] of |cos θ(∇g_i, ∇g_j)|, 1 on the diagonal.

    Independent relations have gradients at an angle on the data (|cos| well below 1); a
    relation that copies another (the same zero set) has |cos| ≈ 1 everywhere on it.
    """
    _, cos = _geometry(relations, tau)
    return np.median(cos, axis=0)


def codimension(relations, tau, rtol: float = DEFAULT_RANK_RTOL) -> dict:
    """JSON-ready summary of `jacobian_ranks` on on-manifold rows τ [N, D]: how often the K
    relations have independent gradients (the fraction a user reads as "they cut K dims")."""
    return codimension_summary(_geometry(relations, tau)[0], rtol)


def independence(relations, tau, rtol: float = DEFAULT_RANK_RTOL) -> tuple[dict, np.ndarray]:
    """(`codimension`, `pairwise_cosines`) from one pass over the rows' Jacobians."""
    ratios, cos = _geometry(relations, tau)
    return codimension_summary(ratios, rtol), np.median(cos, axis=0)


def codimension_summary(ratios: np.ndarray, rtol: float) -> dict:
    """`codimension`'s summary from the σ ratios [N, K] of `jacobian_ranks`."""
    ranks = (ratios > rtol).sum(-1)
    k = ratios.shape[-1]
    counts = np.bincount(ranks, minlength=k + 1)
    return {
        "relations": int(k),
        "points": len(ranks),
        "rtol": float(rtol),
        "full_rank_fraction": float(np.mean(ranks == k)) if k else 1.0,
        "rank_fractions": [float(c) / max(len(ranks), 1) for c in counts],
        "median_smallest_sigma_ratio": float(np.median(ratios[:, -1])) if k else 1.0,
    }


__all__ = [
    "DEFAULT_RANK_RTOL",
    "Projection",
    "codimension",
    "codimension_summary",
    "independence",
    "jacobian_ranks",
    "pairwise_cosines",
    "project",
    "trust_region",
]
