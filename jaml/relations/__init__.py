"""Analytic Manifold Learning (paper §3): learn independent relations g_k(τ) = 0 from data.

from jaml import relations
rs = relations.fit(rows_sampler_source_or_path, relations.Config(max_relations=2))
relations.evaluate(rs, tau)   # [..., K]
relations.penalty(rs, tau)    # [...] Σ_k |g_k|  (paper eq. 4)
relations.holds(rs, tau)      # bool [...] within the fit's distance of every g_k = 0
relations.distances(rs, tau)  # [..., K] |g_k| / ‖∇g_k‖, first-order distance to g_k = 0
relations.save(rs, path); rs = relations.load(path)
points, residuals, converged = relations.project(rs, tau)  # onto {g = 0}, Gauss–Newton
relations.codimension(rs, on_rows)  # how often ∇g_1..∇g_K are independent there
pen = relations.latent_penalty(rs, relations.LatentLayout(static={"theta": 2},
                               dynamic={"s": 3, "v": 4}), latent_size=5, action_size=1)
                              # (z [B, S, 5], a [B, S, 1]) -> [B], for a learner's loss (eq. 4)
"""

from jaml.configs.relations import Config
from jaml.relations.checkpoint import load, save
from jaml.relations.geometry import codimension, jacobian_ranks, project
from jaml.relations.relation_set import RelationSet, distances, evaluate, holds, penalty
from jaml.relations.training import RelationSummary, fit
from jaml.relations.transfer import LatentLayout, LayoutError, latent_penalty

__all__ = [
    "Config",
    "LatentLayout",
    "LayoutError",
    "RelationSet",
    "RelationSummary",
    "codimension",
    "distances",
    "evaluate",
    "fit",
    "holds",
    "jacobian_ranks",
    "latent_penalty",
    "load",
    "penalty",
    "project",
    "save",
]
