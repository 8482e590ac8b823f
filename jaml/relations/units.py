"""The units a fit trains in: rows far from unit scale, or far from the origin, are moved to it.

The defaults (networks' initialisation, learning rate, step caps) suit rows whose box spans
about ±1 near the origin; rows in other units (a circle of radius 1,000, or one centred at
1,000) saturate the networks' first layer. Rows outside that range are fitted as
(τ − centre) / scale, the scale a power of two (exact in floats: copies of rows 2^j and 2^k times
larger, both outside the range, train on the same bits), and the set the fit returns takes the
user's τ: the scale is folded into each relation's first layer, the centre kept on the set and
subtracted before it (exact for rows near it, where folding it into the bias would cancel
digits)."""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import numpy as np

from jaml.relations import quality
from jaml.relations.relation_set import RelationSet, Report

# Rows whose box's widest half-side lies within [1/BAND, BAND] keep their scale: every source
# the defaults were measured on (half-sides 1 to 2) trains as it always has.
BAND = 2**1.5
# A column whose centre lies farther than FAR half-sides from zero is centred (the unit circle
# centred at (5, 5) capped where at (3, 3) it trained as at the origin).
FAR = 3.0


class Units(NamedTuple):
    """τ_fit = (τ − centre) / scale; centre () where no column is moved."""

    centre: tuple[float, ...] = ()
    scale: float = 1.0

    @property
    def identity(self) -> bool:
        return not self.centre and self.scale == 1.0

    def to_fit(self, rows):
        """Rows [..., D] in the user's units → the fit's (float64 on the host for arrays of
        NumPy, traced for JAX's)."""
        if self.identity:
            return rows
        if isinstance(rows, np.ndarray):
            moved = rows.astype(np.float64) - (np.asarray(self.centre) if self.centre else 0.0)
            return (moved / self.scale).astype(np.float32)
        moved = rows - np.asarray(self.centre, np.float32) if self.centre else rows
        return moved / np.float32(self.scale)

    def from_fit(self, rows):
        """`to_fit`'s inverse, for JAX arrays (a prior's argument)."""
        if self.identity:
            return rows
        moved = rows * np.float32(self.scale)
        return moved + np.asarray(self.centre, np.float32) if self.centre else moved

    def describe(self, names=()) -> str:
        """The move in words, for the fit's log."""
        parts = []
        if self.scale != 1.0:
            parts.append(f"divided by {self.scale:g}")
        moved = [(names[i] if i < len(names) else f"column {i}", c)
                 for i, c in enumerate(self.centre) if c != 0.0]
        if moved:
            parts.append("centred (" + ", ".join(f"{n} − {c:.6g}" for n, c in moved) + ")")
        return " and ".join(parts)


def choose(low, high) -> Units:
    """The units for rows whose box is [low, high] (per column, the user's units)."""
    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    half = float((high - low).max()) / 2
    if not half > 0:
        return Units()
    scale = 1.0 if 1 / BAND <= half <= BAND else 2.0 ** round(math.log2(half))
    centre = (low + high) / 2
    far = np.abs(centre) > FAR * half
    return Units(tuple(float(c) if f else 0.0 for c, f in zip(centre, far, strict=True))
                 if far.any() else (), scale)


class ScaledSampler:
    """A sampler's rows in the fit's units; equal for equal samplers and units (compiled loops
    are keyed by their samplers)."""

    __slots__ = ("sampler", "units")

    def __init__(self, sampler, units: Units):
        self.sampler, self.units = sampler, units

    def __call__(self, key: jax.Array, n: int) -> jax.Array:
        return self.units.to_fit(self.sampler(key, n))

    def __eq__(self, other) -> bool:
        return (isinstance(other, ScaledSampler) and self.sampler == other.sampler
                and self.units == other.units)

    def __hash__(self) -> int:
        return hash((self.sampler, self.units))


def _kernels(params: dict, factor: float) -> dict:
    """Relation params with the first layer's kernel times `factor`."""
    inner = dict(params["params"])
    inner["hidden0_kernel"] = inner["hidden0_kernel"] * np.float32(factor)
    return {**params, "params": inner}


# The fields of `quality.landing` (and the report's landing) that are lengths in τ's units.
_LANDING_LENGTHS = ("within", "box_diagonal", "median_distance")


def scaled_landing(land: dict, scale: float) -> dict:
    """A landing record with its lengths in units `scale` times its own."""
    return {k: v * scale if k in _LANDING_LENGTHS and v is not None else v
            for k, v in land.items()}


def scaled_report(report: Report | None, scale: float) -> Report | None:
    """The quality report with its lengths in units `scale` times the fit's."""
    if report is None or scale == 1.0:
        return report
    data = report.to_dict()
    if "landing" not in data:  # the statuses a resumed run's checkpoint carries: no lengths
        return report
    data["landing"] = scaled_landing(data["landing"], scale)
    hold = data.get("holds", {})
    if hold.get("distance_tolerance") is not None:
        hold["distance_tolerance"] = [t * scale for t in hold["distance_tolerance"]]
    return Report(quality.relabelled(data))


def to_user(rs: RelationSet, units: Units) -> RelationSet:
    """A set fitted in `units` as a set of the user's τ (the same relations, the same bits of g
    for τ that map to the same fit rows where the centre is 0)."""
    if units.identity:
        return rs
    s, c = units.scale, np.asarray(units.centre or np.zeros(rs.dim))
    return rs.replace(
        params=tuple(_kernels(p, 1 / s) for p in rs.params),
        centre=units.centre,
        low=tuple(float(x) for x in c + s * np.asarray(rs.low)) if rs.low else (),
        high=tuple(float(x) for x in c + s * np.asarray(rs.high)) if rs.high else (),
        distance_tolerance=(None if rs.distance_tolerance is None
                            else tuple(t * s for t in rs.distance_tolerance)),
        quality=scaled_report(rs.quality, s),
    )


def to_fit(rs: RelationSet, units: Units) -> RelationSet:
    """`to_user`'s inverse: a set of the user's τ (a fit's `start`) in the fit's units."""
    if units.identity and not rs.centre:
        return rs
    if tuple(rs.centre) != tuple(units.centre):
        raise ValueError(f"start relations were fitted centred at {rs.centre or 'the origin'}, "
                         f"these rows' fit at {units.centre or 'the origin'}: continue a fit "
                         "only on rows of the same source")
    s, c = units.scale, np.asarray(units.centre or np.zeros(rs.dim))
    return rs.replace(
        params=tuple(_kernels(p, s) for p in rs.params),
        centre=(),
        low=tuple(float(x) for x in (np.asarray(rs.low) - c) / s) if rs.low else (),
        high=tuple(float(x) for x in (np.asarray(rs.high) - c) / s) if rs.high else (),
        distance_tolerance=(None if rs.distance_tolerance is None
                            else tuple(t / s for t in rs.distance_tolerance)),
        quality=scaled_report(rs.quality, 1 / s),
    )
