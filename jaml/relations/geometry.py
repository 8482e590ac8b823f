"""The learned manifold {g_1 = … = g_K = 0}: points moved onto it, and whether the relations cut
K dimensions there (the rank of their Jacobian, the paper's transversality lemma)."""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaml.relations.loop import ONCE_COMPILER_OPTIONS
from jaml.relations.relation_set import RelationSet, _check_tau, evaluate

DEFAULT_RANK_RTOL = 0.1  # σ_i / σ_1 of the row-normalised Jacobian; for K = 2, tan(θ/2) > 0.1


def _relations_fn(relations) -> Callable:
    """G: τ [D] → [K] from a RelationSet or a user function of τ [..., D] → [..., K]."""
    if isinstance(relations, RelationSet):
        return lambda t: evaluate(relations, t)
    if callable(relations):
        return relations
    raise TypeError(f"relations must be a RelationSet or a callable, got {type(relations)}")


def _gauss_newton(fn, tau, mask, steps: int, rtol, max_step):
    """`steps` minimum-norm steps δ = −J⁺ G(τ) per row, J's fixed columns zeroed by `mask`.

    Each step is at most `max_step` long and halved (up to 3 times) until ‖G‖ decreases: where
    a tanh network saturates its gradient is tiny and the full step would leave for infinity.
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
            tries = t - _HALVINGS[:, None] * delta  # [4, D]
            norms = jnp.linalg.norm(jax.vmap(fn)(tries), axis=-1)
            better = norms < jnp.linalg.norm(g)
            return jnp.where(jnp.any(better), tries[jnp.argmax(better)], tries[-1]), None

        t, _ = jax.lax.scan(step, t, None, length=steps)
        return t, fn(t)

    return jax.vmap(one_row)(tau)


_HALVINGS = jnp.asarray([1.0, 0.5, 0.25, 0.125])


@functools.partial(jax.jit, static_argnames="steps")
def _project_set(rs: RelationSet, tau, mask, steps: int, rtol, max_step):
    scale = 1.0 / jnp.maximum(rs.on_means, 1e-30)
    points, residuals = _gauss_newton(
        lambda t: evaluate(rs, t) * scale, tau, mask, steps, rtol, max_step
    )
    return points, residuals / scale


def project(relations, tau, steps: int = 10, free=None, max_step: float = jnp.inf,
            rtol: float = 1e-6):
    """Move τ [..., D] onto the learned manifold by Gauss–Newton steps; returns (points [..., D],
    residuals G(points) [..., K]).

    Each step is the minimum-norm solution of J δ = −G (J⁺ through an SVD of the K×D Jacobian,
    singular values below rtol·σ_max dropped), so a point moves as little as it must; for
    relations linear in τ one step lands on the nearest point of their intersection. Steps are
    cut to `max_step` and halved while they do not reduce ‖G‖ (a damped Gauss–Newton). `free`
    (bool [D]) restricts the moves to those coordinates, e.g. the next state of a transition for
    given start (s0, v0). `relations`: a RelationSet, or a function τ [..., D] → [..., K].
    A RelationSet's g_k are measured in units of their recorded on-manifold means, which matters
    only where the K equations cannot all hold (then ‖G‖ is minimised in those units).
    """
    if isinstance(relations, RelationSet):
        tau = _check_tau(relations, tau)
    tau = jnp.asarray(tau)
    if not jnp.issubdtype(tau.dtype, jnp.floating):
        tau = tau.astype(jnp.float32)
    dim = tau.shape[-1]
    mask = jnp.ones((dim,), tau.dtype) if free is None else jnp.asarray(free, tau.dtype)
    if mask.shape != (dim,):
        raise ValueError(f"free must have shape ({dim},), got {mask.shape}")
    if steps < 1:
        raise ValueError(f"steps must be ≥ 1, got {steps}")
    flat = tau.reshape(-1, dim)
    if isinstance(relations, RelationSet):
        points, residuals = _project_set(relations, flat, mask, steps, rtol, max_step)
    else:
        run = jax.jit(functools.partial(_gauss_newton, _relations_fn(relations), steps=steps))
        points, residuals = run(flat, mask, rtol=rtol, max_step=max_step)
    return points.reshape(tau.shape), residuals.reshape(*tau.shape[:-1], -1)


def _sigma_ratios(fn, tau):
    """[N, K]: singular values of the row-normalised Jacobian at each row, over the largest."""

    def one_row(t):
        jac = jax.jacfwd(fn)(t)
        norms = jnp.linalg.norm(jac, axis=-1, keepdims=True)
        flat = norms == 0.0  # no direction at all; any other length is scaled to 1
        unit = jnp.where(flat, 0.0, jac / jnp.where(flat, 1.0, norms))
        s = jnp.linalg.svd(unit, compute_uv=False)
        s = jnp.pad(s, (0, jac.shape[0] - s.shape[0]))  # K > D: the missing ones are zero
        return s / jnp.maximum(s[0], 1e-30)

    return jax.vmap(one_row)(tau)


@functools.partial(jax.jit, compiler_options=ONCE_COMPILER_OPTIONS)
def _sigma_ratios_set(rs: RelationSet, tau):
    return _sigma_ratios(lambda t: evaluate(rs, t), tau)


def jacobian_ranks(relations, tau, rtol: float = DEFAULT_RANK_RTOL):
    """(ranks int [N], σ ratios [N, K]) of the K×D Jacobian of (g_1..g_K) at rows τ [N, D].

    Each gradient is scaled to unit length first (learned g_k's gradients differ in scale by
    orders of magnitude, and transversality is about directions), a zero one stays zero; the
    rank counts singular values above rtol × the largest. With K ≤ D, rank K means the K
    gradients are independent there, i.e. the zero sets cut K dimensions (transversality).
    """
    tau = jnp.asarray(tau).reshape(-1, jnp.shape(tau)[-1])
    if isinstance(relations, RelationSet):
        ratios = _sigma_ratios_set(relations, _check_tau(relations, tau))
    else:
        ratios = jax.jit(functools.partial(_sigma_ratios, _relations_fn(relations)))(tau)
    ratios = np.asarray(ratios)
    return (ratios > rtol).sum(-1), ratios


def codimension(relations, tau, rtol: float = DEFAULT_RANK_RTOL) -> dict:
    """JSON-ready summary of `jacobian_ranks` on on-manifold rows τ [N, D]: how often the K
    relations have independent gradients (the fraction a user reads as "they cut K dims")."""
    ranks, ratios = jacobian_ranks(relations, tau, rtol)
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


__all__ = ["DEFAULT_RANK_RTOL", "codimension", "jacobian_ranks", "project"]
