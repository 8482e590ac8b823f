"""`RelationSet`: learned relations g_1..g_K as a pytree, and the functions users call on it."""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping

import jax
import jax.numpy as jnp
from flax import struct

from jaml.relations.networks import Relation


class Report(Mapping):
    """A fit's quality report (`relations.quality.assess`): a read-only mapping of JSON values.

    Hashable (by its JSON text), so a RelationSet carrying one stays a valid static pytree part.
    """

    def __init__(self, data: Mapping):
        self._data = dict(data)
        self._text = json.dumps(self._data, sort_keys=True, default=float)

    def __getitem__(self, key):
        return self._data[key]

    def __iter__(self):
        return iter(self._data)

    def __len__(self):
        return len(self._data)

    def __hash__(self):
        return hash(self._text)

    def __eq__(self, other):
        return isinstance(other, Report) and self._text == other._text

    def to_dict(self) -> dict:
        return json.loads(self._text)

    def __repr__(self) -> str:
        return "\n".join(self.get("lines", ()))


@struct.dataclass
class RelationSet:
    """Learned relations and their recorded statistics (paper App. B.3.1).

    Attributes:
      params: per-relation Flax parameters, g_1 first.
      on_means, off_means: [K] mean |g_k| on fresh on- and off-manifold data after training.
      widths: hidden width of each g_k. depth: hidden layers. dim: D, the size of τ.
      tolerance: every |g_k| < tolerance × on_means[k]: the residuals down to the data's own
        level (`project`'s converged; `holds` where there is no distance_tolerance).
      distance_tolerance: per relation, `holds` accepts τ where each relation's first-order
        distance |g_k| / ‖∇g_k‖ to its zero set is below its own tolerance (τ's units), so a
        fuzzy relation does not loosen an exact one; None in checkpoints written before it (and
        where the fit's rows sit where a relation is flat).
      syzygies: restricted syzygies found (and pushed away from) per relation.
      dim_names: names of τ's coordinates, when the source gave them.
      low, high: the box of the training data (per coordinate), `project`'s trust region.
      quality: the fit's quality report on held-out rows (`relations.quality.assess`), or None.
      centre: subtracted from τ before the networks, per coordinate ((): none): where the rows
        sat far from the origin, the fit trained on them centred (`relations.units`).
    """

    params: tuple
    on_means: jax.Array
    off_means: jax.Array
    widths: tuple[int, ...] = struct.field(pytree_node=False)
    depth: int = struct.field(pytree_node=False)
    dim: int = struct.field(pytree_node=False)
    tolerance: float = struct.field(pytree_node=False, default=1.5)
    syzygies: tuple[int, ...] = struct.field(pytree_node=False, default=())
    dim_names: tuple[str, ...] = struct.field(pytree_node=False, default=())
    low: tuple[float, ...] = struct.field(pytree_node=False, default=())
    high: tuple[float, ...] = struct.field(pytree_node=False, default=())
    quality: Report | None = struct.field(pytree_node=False, default=None)
    distance_tolerance: tuple[float, ...] | None = struct.field(pytree_node=False, default=None)
    centre: tuple[float, ...] = struct.field(pytree_node=False, default=())

    def __post_init__(self):
        # A single tolerance (checkpoints written before per-relation ones) holds every relation.
        t = self.distance_tolerance
        if t is not None and not isinstance(t, tuple):
            t = tuple(float(x) for x in t) if hasattr(t, "__len__") else (float(t),) * len(
                self.params)
            object.__setattr__(self, "distance_tolerance", t)

    @property
    def num_relations(self) -> int:
        return len(self.params)

    def __repr__(self) -> str:
        """One line: the relations with their widths and on/off means, not their weights."""
        try:
            means = [f"on {float(on):.3g} off {float(off):.3g}"
                     for on, off in zip(self.on_means, self.off_means, strict=True)]
        except (TypeError, jax.errors.ConcretizationTypeError):  # traced
            means = ["traced"] * self.num_relations
        rows = "; ".join(f"g{k + 1}: width {w}, {m}"
                         for k, (w, m) in enumerate(zip(self.widths, means, strict=True)))
        names = f" ({', '.join(self.dim_names)})" if self.dim_names else ""
        count = f"{self.num_relations} relation{'' if self.num_relations == 1 else 's'}"
        centred = (f", centred at ({', '.join(f'{c:.6g}' for c in self.centre)})"
                   if self.centre else "")
        head = (f"RelationSet({count} of τ in R^{self.dim}{names}{centred}, depth {self.depth}, "
                f"tolerance {self.tolerance:.3g}"
                + (f", holds within {tolerances_text(self.distance_tolerance)}"
                   if self.distance_tolerance is not None else "")
                + (f": {rows})" if rows else ")"))
        if self.quality is None:
            return head
        return head + "\n" + "\n".join("  " + line for line in self.quality.get("lines", ()))

    def relation(self, k: int, raw: bool = False):
        """g_{k+1} as a function of τ [..., D] → [...]; raw: its output before the final tanh
        (atanh g: the same zero set, with no plateau where g saturates at ±1)."""
        module = Relation(self.widths[k], self.depth, raw)
        if not self.centre:
            return lambda tau: module.apply(self.params[k], tau)
        centre = jnp.asarray(self.centre, jnp.float32)
        return lambda tau: module.apply(self.params[k], tau - centre.astype(tau.dtype))

    def append(self, params, on_mean, off_mean, width: int, syzygies: int = 0) -> RelationSet:
        return self.replace(
            params=(*self.params, params),
            on_means=jnp.append(self.on_means, on_mean),
            off_means=jnp.append(self.off_means, off_mean),
            widths=(*self.widths, width),
            syzygies=(*self.syzygies, syzygies),
            quality=None,
            distance_tolerance=None,  # calibrated for the set without the new relation
        )

    def select(self, indices) -> RelationSet:
        """The relations at `indices` (0-based, in order), e.g. only those that converged."""
        indices = [int(i) for i in indices]
        if not indices or any(not 0 <= i < self.num_relations for i in indices):
            raise ValueError(f"indices must name relations in 0..{self.num_relations - 1}, "
                             f"got {indices}")
        idx = jnp.asarray(indices)
        syzygies = tuple(self.syzygies[i] for i in indices) if self.syzygies else ()
        return self.replace(
            params=tuple(self.params[i] for i in indices),
            on_means=self.on_means[idx],
            off_means=self.off_means[idx],
            widths=tuple(self.widths[i] for i in indices),
            syzygies=syzygies,
            quality=None,
            distance_tolerance=(None if self.distance_tolerance is None
                                else tuple(self.distance_tolerance[i] for i in indices)),
        )

    @classmethod
    def empty(cls, dim: int, depth: int, tolerance: float, dim_names=(), low=(), high=()
              ) -> RelationSet:
        zeros = jnp.zeros((0,), jnp.float32)
        return cls((), zeros, zeros, (), depth, dim, tolerance, (), tuple(dim_names),
                   tuple(float(x) for x in low), tuple(float(x) for x in high))


def _check_tau(rs: RelationSet, tau) -> jax.Array:
    tau = jnp.asarray(tau)
    if tau.ndim < 1 or tau.shape[-1] != rs.dim:
        raise ValueError(f"tau must have shape [..., {rs.dim}], got {tuple(tau.shape)}")
    if not jnp.issubdtype(tau.dtype, jnp.floating):
        raise TypeError(f"tau must be a floating-point array, got dtype {tau.dtype}")
    return tau


def evaluate(rs: RelationSet, tau) -> jax.Array:
    """[..., K]: g_1..g_K at tau [..., D]."""
    tau = _check_tau(rs, tau)
    if rs.num_relations == 0:
        return jnp.zeros((*tau.shape[:-1], 0), tau.dtype)
    return _evaluate(canonical(rs), tau, False)


def evaluate_raw(rs: RelationSet, tau) -> jax.Array:
    """[..., K]: atanh g_1..g_K at tau [..., D], the relations before their output tanh."""
    tau = _check_tau(rs, tau)
    if rs.num_relations == 0:
        return jnp.zeros((*tau.shape[:-1], 0), tau.dtype)
    return _evaluate(canonical(rs), tau, True)


@functools.partial(jax.jit, static_argnums=2)
def _evaluate(rs: RelationSet, tau: jax.Array, raw: bool) -> jax.Array:
    """One compiled program for every relation of a set (called op by op, each matmul, add and
    tanh was a program of its own, compiled per shape and dispatched one at a time)."""
    return jnp.stack([rs.relation(k, raw)(tau) for k in range(rs.num_relations)], axis=-1)


def require_relations(rs: RelationSet, what: str) -> None:
    """A one-line ValueError where `rs` holds no relation: no equation holds or fails, so
    `holds` would accept every point and `penalty` be 0 everywhere."""
    if rs.num_relations == 0:
        raise ValueError(f"{what}: this RelationSet has no relations (the fit found none that "
                         "separates on- from off-manifold rows; its log says why)")


def penalty(rs: RelationSet, tau) -> jax.Array:
    """[...]: Σ_k |g_k(tau)| (paper eq. 4), differentiable in tau."""
    require_relations(rs, "penalty")
    return jnp.sum(jnp.abs(evaluate(rs, tau)), axis=-1)


def canonical(rs: RelationSet) -> RelationSet:
    """rs without the static fields no computation of g reads (its tolerance, box, names,
    report): one compiled program serves every set of the same shapes (and centre)."""
    return rs.replace(tolerance=1.0, syzygies=(), dim_names=(), low=(), high=(), quality=None,
                      distance_tolerance=None)


@jax.jit
def _distances(rs: RelationSet, flat: jax.Array) -> jax.Array:
    def one(t):
        jac, g = jax.jacfwd(lambda x: (evaluate(rs, x),) * 2, has_aux=True)(t)
        return jnp.abs(g) / jnp.linalg.norm(jac, axis=-1)

    d = jax.vmap(one)(flat)
    return jnp.where(jnp.isnan(d), jnp.inf, d)


def distances(rs: RelationSet, tau) -> jax.Array:
    """[..., K]: each relation's first-order distance to its zero set, |g_k| / ‖∇g_k‖ (the
    length of a Newton step onto it; inf where g_k is flat). Unlike |g_k| it does not grow
    where g_k is steep or shrink where it is flat, so one tolerance fits the whole manifold."""
    tau = _check_tau(rs, tau)
    if rs.num_relations == 0:
        return jnp.zeros((*tau.shape[:-1], 0), tau.dtype)
    d = _distances(canonical(rs), tau.reshape(-1, rs.dim))
    return d.reshape(*tau.shape[:-1], rs.num_relations)


def holds_measure(rs: RelationSet, tau, by: str | None = None, tolerance=None) -> jax.Array:
    """[...]: how far from holding tau is, in units of `holds`' tolerance (it holds below 1): by
    "distance", the largest of the relations' `distances`, each over its own tolerance; by
    "value", of |g_k| / on_means[k] over `rs.tolerance`. `tolerance` as `holds` takes it."""
    require_relations(rs, "holds")
    by = _checked_by(by, rs)
    tolerance = _tolerances(rs, by, tolerance)
    if by == "value":
        return jnp.max(jnp.abs(evaluate(rs, tau)) / rs.on_means, axis=-1) / tolerance
    return jnp.max(distances(rs, tau) / tolerance, axis=-1)


def _checked_by(by: str | None, rs: RelationSet) -> str:
    if by not in (None, "distance", "value"):
        raise ValueError(f"by must be 'distance' or 'value', got {by!r}")
    return by or ("value" if rs.distance_tolerance is None else "distance")


def _tolerances(rs: RelationSet, by: str, tolerance):
    """`holds`' tolerance `by` value (a number) or by distance ([K], one per relation)."""
    if tolerance is None:
        tolerance = rs.tolerance if by == "value" else rs.distance_tolerance
    if tolerance is None:
        raise ValueError("holds by distance: this RelationSet records no distance_tolerance "
                         "(a checkpoint written before it): pass tolerance=, or by='value'")
    if by == "value":
        return float(tolerance)
    return jnp.broadcast_to(jnp.asarray(tolerance, jnp.float32), (rs.num_relations,))


def holds(rs: RelationSet, tau, tolerance=None, by: str | None = None) -> jax.Array:
    """bool [...]: every relation holds at tau. By "distance" (where the set records a
    distance_tolerance, as fits do), each relation's first-order distance to its zero set is
    below its own tolerance, calibrated so that 99 % of held-out rows hold them all; by
    "value", every |g_k| < tolerance × on_means[k]. `tolerance`: a number for every relation,
    or by distance one per relation; default the fit's."""
    require_relations(rs, "holds")
    by = _checked_by(by, rs)
    tolerance = _tolerances(rs, by, tolerance)
    if by == "value":  # as `project` has always compared, not via the ratio (same rounding)
        return jnp.all(jnp.abs(evaluate(rs, tau)) < tolerance * rs.on_means, axis=-1)
    return jnp.all(distances(rs, tau) < tolerance, axis=-1)


def tolerances_text(tolerances) -> str:
    """Per-relation tolerances in a line: one number where they agree."""
    if len(set(tolerances)) == 1:
        return f"{tolerances[0]:.3g}"
    return " / ".join(f"{t:.3g}" for t in tolerances)
