"""Analytic Manifold Learning (paper §3): learn independent relations g_k(τ) = 0 from data.

from jaml import relations
rs = relations.fit(rows_or_sampler, relations.Config(max_relations=2))
relations.evaluate(rs, tau)   # [..., K]
relations.penalty(rs, tau)    # [...] Σ_k |g_k|  (paper eq. 4)
relations.holds(rs, tau)      # bool [...]
relations.save(rs, path); rs = relations.load(path)
points, residuals = relations.project(rs, tau)   # onto {g_1 = … = g_K = 0}, Gauss–Newton
relations.codimension(rs, on_rows)  # how often ∇g_1..∇g_K are independent there
pen = relations.latent_penalty(rs, relations.LatentLayout(static={"theta": 2},
                               dynamic={"s": 3, "v": 4}), latent_size=5, action_size=1)
                              # (z [B, S, 5], a [B, S, 1]) -> [B], for a learner's loss (eq. 4)
"""

from jaml import _lazy

# Public names, imported from their modules on first use (PEP 562): `jaml.relations.config` (and
# so `jaml relations --help`) stays free of JAX, which every other module here imports.
_EXPORTS = {
    "load": "checkpoint",
    "save": "checkpoint",
    "Config": "config",
    "codimension": "geometry",
    "jacobian_ranks": "geometry",
    "project": "geometry",
    "RelationSet": "relation_set",
    "evaluate": "relation_set",
    "holds": "relation_set",
    "penalty": "relation_set",
    "RelationSummary": "training",
    "fit": "training",
    "LatentLayout": "transfer",
    "LayoutError": "transfer",
    "latent_penalty": "transfer",
}


__getattr__, __dir__ = _lazy.exports(__name__, _EXPORTS)


__all__ = [
    "Config",
    "LatentLayout",
    "LayoutError",
    "RelationSet",
    "RelationSummary",
    "codimension",
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
