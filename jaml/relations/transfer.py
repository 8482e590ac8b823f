"""Imposing learned relations on a learner's latent space (paper §4, eq. 4): the latent penalty.

How relation coordinates map onto latent steps and actions, and the reference's ok-row term:
docs/transfer.md. Latents meet relations raw (the sampled, pre-sigmoid τ̃ of eq. 4), so they must
be on the scale the relations were trained on: configure the learner with `mu_nl=False` when
the source's units are not (0, 1). Shapes: B batch, S latent steps, P per-step latent, A action,
D relation input, K relations.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp

from jaml.learners.learner import PenaltyTerms
from jaml.relations.relation_set import RelationSet, evaluate

FORMS = ("sum", "hinge")


class LayoutError(ValueError):
    """A latent layout that does not match a relation set's coordinates."""


@dataclasses.dataclass(frozen=True)
class LatentLayout:
    """Where each coordinate of a relation set sits in a learner's per-step latent.

    static: relation coordinate name → index into the per-step latent P (one value per sequence).
    dynamic: state name → index into P; the relation's "<name>0" / "<name>1" read it at t / t + 1.
    actions: action name → column of the learner's actions; the relation's "<name>0" reads it at t.
    """

    static: Mapping[str, int]
    dynamic: Mapping[str, int]
    actions: Mapping[str, int] = dataclasses.field(default_factory=lambda: {"a": 0})

    @classmethod
    def place(cls, slots: Mapping[str, Sequence[int]], static: Sequence[str] = (),
              dynamic: Sequence[str] = (), actions: Mapping[str, int] | None = None
              ) -> LatentLayout:
        """The layout that puts relation coordinates on a learner's declared latent
        (`LearnerConfig.penalty_slots`): the `static` names on its last static entries (the
        reference reads θ from PRED's last static entry), the `dynamic` names on its first
        dynamic entries, in order; `actions` as in the constructor (default {"a": 0})."""
        have = {kind: tuple(slots.get(kind, ())) for kind in ("static", "dynamic")}
        for kind, names in (("static", static), ("dynamic", dynamic)):
            if len(names) > len(have[kind]):
                raise LayoutError(f"{len(names)} {kind} coordinates {list(names)} but the "
                                  f"learner's latent has {len(have[kind])} {kind} entries; "
                                  f"give it a larger {kind} part")
        placed_static = dict(zip(static, have["static"][len(have["static"]) - len(static):],
                                 strict=True))
        placed_dynamic = dict(zip(dynamic, have["dynamic"][:len(dynamic)], strict=True))
        return cls(placed_static, placed_dynamic,
                   {"a": 0} if actions is None else dict(actions))

    def gather(self, names: tuple[str, ...], latent_size: int, action_size: int):
        """For each relation coordinate, (source, index, step offset) with source "z" or "a";
        raises LayoutError naming every coordinate the layout cannot place, every layout entry
        the relations do not use, and indices out of range."""
        problems, plan, used = [], [], set()
        for name in names:
            if name in self.static:
                plan.append(("z", self.static[name], 0, True))
                used.add(("static", name))
                continue
            base, suffix = name[:-1], name[-1:]
            if suffix in ("0", "1") and base in self.dynamic:
                plan.append(("z", self.dynamic[base], int(suffix), False))
                used.add(("dynamic", base))
            elif suffix == "0" and base in self.actions:
                plan.append(("a", self.actions[base], 0, False))
                used.add(("actions", base))
            else:
                problems.append(f"relation coordinate {name!r} has no place in the layout")
        for kind in ("static", "dynamic", "actions"):
            for name in getattr(self, kind):
                if (kind, name) not in used:
                    problems.append(f"layout {kind} entry {name!r} is not a relation coordinate")
        for source, index, _, _ in plan:
            size = latent_size if source == "z" else action_size
            if not 0 <= index < size:
                what = "per-step latent" if source == "z" else "action"
                problems.append(f"{what} index {index} outside [0, {size})")
        if problems:
            raise LayoutError(
                f"latent layout does not match the relations' coordinates {list(names)}: "
                + "; ".join(problems)
            )
        return plan


def transitions(plan, z: jax.Array, actions: jax.Array) -> jax.Array:
    """τ [B, S − 1, D] for every consecutive latent pair, coordinates in the relations' order."""
    steps = z.shape[1] - 1
    columns = []
    for source, index, offset, static in plan:
        if source == "a":
            columns.append(actions[:, :steps, index])
        elif static:
            columns.append(jnp.broadcast_to(z[:, :1, index], (z.shape[0], steps)))
        else:
            columns.append(z[:, offset : offset + steps, index])
    return jnp.stack(columns, axis=-1)


def pair_penalty(rs: RelationSet, tau: jax.Array, form: str) -> jax.Array:
    """[...]: the per-transition penalty of tau [..., D] (see the module docstring)."""
    g = jnp.abs(evaluate(rs, tau))
    if form == "sum":
        return jnp.sum(g, axis=-1)
    return jnp.mean(jnp.where(g > rs.on_means, g, 0.0), axis=-1)


OK_ROWS = ("relations", "random")


@dataclasses.dataclass(frozen=True, eq=False)
class LatentPenalty:
    """`penalty(z [B, S, P], actions [B, S, A]) -> [B]`: weight × Σ_t penalty(τ_t), with the
    reference code's re-weighting of ok rows as `terms` (see `latent_penalty`)."""

    rs: RelationSet
    plan: tuple
    latent_size: int
    action_size: int
    weight: float
    form: str
    ok_weight: float = 0.0
    ok_rows: str = "relations"
    ok_fraction: float | None = None

    def _tau(self, z: jax.Array, actions: jax.Array) -> jax.Array:
        if z.ndim != 3 or z.shape[-1] != self.latent_size or z.shape[1] < 2:
            raise ValueError(
                f"the latent penalty needs z [B, S ≥ 2, {self.latent_size}], got "
                f"{tuple(z.shape)}"
            )
        if actions.shape[:2] != z.shape[:2] or actions.shape[-1] != self.action_size:
            raise ValueError(
                f"actions must be [B, S, {self.action_size}] = "
                f"{(*z.shape[:2], self.action_size)}, got {tuple(actions.shape)}"
            )
        return transitions(self.plan, z, actions)

    def __call__(self, z: jax.Array, actions: jax.Array) -> jax.Array:
        tau = self._tau(z, actions)
        return self.weight * jnp.sum(pair_penalty(self.rs, tau, self.form), axis=1)

    def ok(self, z: jax.Array, actions: jax.Array) -> jax.Array:
        """[B] bool: sequences whose every transition has |g_k| < on_mean_k for every k."""
        g = jnp.abs(evaluate(self.rs, self._tau(z, actions)))
        return jnp.all(g < self.rs.on_means, axis=(1, 2))

    def terms(self, z: jax.Array, actions: jax.Array, key: jax.Array) -> PenaltyTerms:
        """The penalty and the rows the learner re-weights: the relations' ok rows, or (the
        "random" control) as many rows drawn at random, so that only their choice differs."""
        ok = jax.lax.stop_gradient(self.ok(z, actions))
        if self.ok_rows == "random" and self.ok_fraction is not None:
            count = round(self.ok_fraction * ok.shape[0])
            ok = jax.random.permutation(key, jnp.arange(ok.shape[0]) < count)
        elif self.ok_rows == "random":
            ok = jax.random.permutation(key, ok)
        return PenaltyTerms(self(z, actions), ok, self.ok_weight)


def latent_penalty(
    rs: RelationSet,
    layout: LatentLayout,
    *,
    latent_size: int,
    action_size: int,
    weight: float = 100.0,
    form: str = "hinge",
    ok_weight: float = 0.0,
    ok_rows: str = "relations",
    ok_fraction: float | None = None,
) -> LatentPenalty:
    """`penalty(z [B, S, P], actions [B, S, A]) -> [B]`: weight × Σ_t penalty(τ_t), τ_t built
    from latent steps t, t + 1 by `layout`. Every mismatch is reported here, before training.

    latent_size, action_size: P and A of the learner that will call it (its
    `config.penalty_dim` and the env's `action_size`).
    weight: 100 by default (docs/transfer.md; the reference recipe's is 1000 against a
      per-frame mean likelihood, `jaml.experiments.fig9`).
    form: "hinge" (the reference's) by default; "sum" is the paper's Σ_k |g_k|.
    ok_weight: the reference code's extra term, ok_weight × the mean NLL of the rows whose
      latents satisfy every relation (|g_k| < on_mean_k on every transition); 0 (default): none.
      The paper's eq. 4 has no such term. The learners add it through `terms`.
    ok_rows: "relations" (the reference), or "random": the same number of rows per batch chosen
      at random (a control for what the re-weighting alone does).
    ok_fraction: with ok_rows "random", draw round(ok_fraction × B) rows per batch instead (a
      control at another arm's measured rate of ok rows).
    """
    if form not in FORMS:
        raise ValueError(f"form must be one of {FORMS}, got {form!r}")
    if ok_rows not in OK_ROWS:
        raise ValueError(f"ok_rows must be one of {OK_ROWS}, got {ok_rows!r}")
    if not weight >= 0:
        raise ValueError(f"weight must be ≥ 0, got {weight}")
    if not ok_weight >= 0:
        raise ValueError(f"ok_weight must be ≥ 0, got {ok_weight}")
    if ok_fraction is not None and (ok_rows != "random" or not 0 <= ok_fraction <= 1):
        raise ValueError(f"ok_fraction must be in [0, 1] and needs ok_rows='random', got "
                         f"{ok_fraction} with ok_rows={ok_rows!r}")
    if rs.num_relations == 0:
        raise ValueError("the relation set is empty: there is nothing to impose")
    if len(rs.dim_names) != rs.dim:
        raise LayoutError(
            "the relation set has no coordinate names, so a latent layout cannot be matched to "
            "it; learn it from a source with dim_names (or rows plus names)"
        )
    plan = layout.gather(tuple(rs.dim_names), latent_size, action_size)
    return LatentPenalty(rs, tuple(plan), latent_size, action_size, float(weight), form,
                         float(ok_weight), ok_rows,
                         None if ok_fraction is None else float(ok_fraction))


def residual(rs: RelationSet, layout: LatentLayout, z, actions) -> jax.Array:
    """[B]: mean over transitions of Σ_k |g_k| on latents (a diagnostic, unweighted)."""
    plan = layout.gather(tuple(rs.dim_names), z.shape[-1], actions.shape[-1])
    return jnp.mean(pair_penalty(rs, transitions(plan, z, actions), "sum"), axis=1)
