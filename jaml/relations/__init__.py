"""Analytic Manifold Learning (paper §3): learn independent relations g_k(τ) = 0 from data.

from jaml import relations
rs = relations.fit(rows_or_sampler, relations.Config(max_relations=2))
relations.evaluate(rs, tau)   # [..., K]
relations.penalty(rs, tau)    # [...] Σ_k |g_k|  (paper eq. 4)
relations.holds(rs, tau)      # bool [...]
relations.save(rs, path); rs = relations.load(path)
"""

from jaml.relations.checkpoint import load, save
from jaml.relations.config import Config
from jaml.relations.relation_set import RelationSet, evaluate, holds, penalty
from jaml.relations.training import RelationSummary, fit

__all__ = [
    "Config",
    "RelationSet",
    "RelationSummary",
    "evaluate",
    "fit",
    "holds",
    "load",
    "penalty",
    "save",
]
