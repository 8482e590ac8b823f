"""Restricted syzygies trained as a game: f fits alongside g_k, so g_k cannot escape by rescaling.

The paper (eq. 3, App. B.3.1) alternates rounds: fit f so that Σ_j f_j g_j ≈ g_k on thickened
data, then push g_k away from that frozen f. Against a frozen f, g_k escapes without becoming
independent: it rescales itself, or turns into another multiple of g_1 that the next f fits
again. Here f keeps fitting while g_k trains, both on the residual taken relative to mean |g_k|
(blind to g_k's scale), so g_k stays unexplained only by leaving the earlier relations' span.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import optax

from jaml.configs.relations import Config
from jaml.relations import losses
from jaml.relations.data import Batches
from jaml.relations.loop import init_state, make_chunk, optimizer_step
from jaml.relations.networks import Relation, SyzygyCoefficients
from jaml.sources.off_manifold import thicken

PUSH_TARGET = 0.5  # g_k is pushed until f's best residual is this share of mean |g_k|


def explained_share(coefficients, earlier_vals, y):
    """mean |Σ_j f_j g_j − g_k| / mean |g_k| on a batch: 0 when f expresses g_k exactly, about 1
    when f explains nothing of it."""
    residual = jnp.mean(jnp.abs(losses.syzygy_residual(coefficients, earlier_vals, y)))
    return residual / jnp.maximum(jnp.mean(jnp.abs(y)), losses.EPS)


def joint_objective(cfg: Config, relation_objective: Callable, module: Relation,
                    earlier: Sequence[Relation], clip: float):
    """(params {"g", "f"}, earlier params, on, off, thick) → (loss, (metrics, converged)).

    `relation_objective` is g_k's own loss (eq. 1–2, as `training` builds it). f descends the
    scale-free residual with g_k held fixed; g_k descends a log-hinge pushing that residual,
    with f held fixed, above `PUSH_TARGET`, bounded by `clip` × the first term as the paper
    bounds its other terms. g_k is done when its own stopping rule holds and f leaves more than
    1/separation_ratio of it unexplained (Algorithm 1's "f ≠ 0").
    """
    syz = SyzygyCoefficients(len(earlier), cfg.syzygy_width, cfg.depth)
    stop = jax.lax.stop_gradient

    def objective(params, earlier_params, on, off, thick):
        loss, (metrics, converged) = relation_objective(
            params["g"], None, earlier_params, 0, on, off, None, None)
        vals = jnp.stack([m.apply(p, thick) for m, p in zip(earlier, earlier_params,
                                                           strict=True)], -1)
        y = module.apply(params["g"], thick)
        coefficients = syz.apply(params["f"], thick)
        fit = explained_share(coefficients, vals, stop(y))  # f's loss
        share = explained_share(stop(coefficients), vals, y)  # what g_k pushes up
        hinge = jnp.maximum(0.0, jnp.log(PUSH_TARGET) - jnp.log(share + losses.EPS))
        push = losses.clip_to(hinge, metrics["distance"], clip)
        converged &= share * cfg.separation_ratio >= 1.0
        metrics |= {"syzygy_residual": share, "syzygy_push": push}
        return loss + push + fit, (metrics, converged)

    return objective, syz


def joint_trainer(cfg: Config, batches: Batches, relation_objective: Callable, module: Relation,
                  earlier: Sequence[Relation], earlier_params, g_params, key, thickening: float,
                  max_steps: int, clip: float):
    """The compiled joint loop of g_k and its syzygy network f: (chunk, initial state, args)."""
    objective, syz = joint_objective(cfg, relation_objective, module, earlier, clip)
    k_init, k_loop = jax.random.split(key)
    params = {"g": g_params, "f": syz.init(k_init, jnp.zeros((1, batches.dim)))}
    labels = {"g": jax.tree.map(lambda _: "g", params["g"]),
              "f": jax.tree.map(lambda _: "f", params["f"])}
    optimizer = optax.multi_transform(
        {"g": optax.adam(cfg.learning_rate), "f": optax.adam(cfg.syzygy_learning_rate)}, labels)

    def draw(key, args):
        data = args[0]
        k_on, k_off, k_thick, k_jit = jax.random.split(key, 4)
        thick = thicken(k_jit, batches.on(k_thick, data), data.low, data.high, thickening)
        return batches.on(k_on, data), batches.off(k_off, data), thick

    def train_step(state, batch, args):
        return optimizer_step(state, objective, optimizer, max_steps, args[1], *batch,
                              patience=cfg.stop_patience)

    chunk = make_chunk(train_step, cfg.chunk_steps, draw)
    return chunk, init_state(params, optimizer, k_loop), (batches.data, earlier_params)
