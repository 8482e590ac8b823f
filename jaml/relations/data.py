"""Turn what a user passes to `fit` (rows or a sampler) into pure on/off-manifold batch samplers.

Validation happens here, eagerly and before any training: wrong shapes or dtypes, NaN/inf,
empty or constant data raise a ValueError/TypeError that names the problem.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaml import sources
from jaml.relations.units import ScaledSampler, Units, choose
from jaml.sources.off_manifold import bounding_box, uniform_in_box

log = logging.getLogger(__name__)


class Data(NamedTuple):
    """The arrays the samplers read: the user's rows (None for a sampler) and the box around the
    data. Jitted code takes them as an argument and never closes over them, so its programs do
    not depend on the data or the seed (the calibration sample that sets the box is drawn with
    the fit's key) and the persistent compilation cache serves them to every later fit."""

    rows: jax.Array | None  # [N, D]
    low: jax.Array  # [D]
    high: jax.Array  # [D]


class Batches(NamedTuple):
    """Pure samplers of [B, D] batches; the arrays they read come in as `data` (`Batches.data`)."""

    rows: jax.Array | None  # the user's data [N, D], or None for a sampler
    sampler: Callable[[jax.Array], jax.Array] | None
    low: jax.Array  # [D] the box around the data
    high: jax.Array
    batch_size: int
    noise_scale: float
    dim_names: tuple[str, ...]
    # Rows kept out of training for the quality report ([H, D]), and training rows the mining
    # of spurious zeros measures distances to ([R, D]); neither enters the training loops.
    held_out: jax.Array | None = None
    dense: jax.Array | None = None
    # The fit's units (`relations.units`): every array above is in them.
    units: Units = Units()

    @property
    def dim(self) -> int:
        return int(self.low.shape[0])

    @property
    def data(self) -> Data:
        """What the samplers below take as `data`."""
        return Data(self.rows, self.low, self.high)

    def static(self) -> Batches:
        """The samplers without their arrays: what a compiled program built from them depends
        on, hashable, and equal for two fits of equal sources (programs are keyed by it)."""
        return self._replace(rows=None, low=None, high=None, held_out=None, dense=None)

    def _noise(self, key, x, data: Data):
        if self.noise_scale == 0.0:
            return x
        width = data.high - data.low
        return x + (jax.random.uniform(key, x.shape) - 0.5) * width * self.noise_scale

    def noisy(self, key, x: jax.Array) -> jax.Array:
        """Rows `x` [N, D] with the noise training adds to its on and off rows (none at 0)."""
        return self._noise(key, x, self.data)

    def clean_on(self, key, data: Data, n: int | None = None) -> jax.Array:
        n = n or self.batch_size
        if self.sampler is not None:
            return self.sampler(key, n)
        return data.rows[jax.random.randint(key, (n,), 0, data.rows.shape[0])]

    def on(self, key, data: Data, n: int | None = None) -> jax.Array:
        """[n, D] on-manifold rows (with noise, if configured)."""
        k_draw, k_noise = jax.random.split(key)
        return self._noise(k_noise, self.clean_on(k_draw, data, n), data)

    def off(self, key, data: Data, n: int | None = None) -> jax.Array:
        """[n, D] off-manifold rows: uniform in the data's box (with noise, if configured)."""
        k_draw, k_noise = jax.random.split(key)
        box = uniform_in_box(k_draw, data.low, data.high, n or self.batch_size)
        return self._noise(k_noise, box, data)


class SourceSampler:
    """A Source's `sample`, equal for equal sources: a bound method is equal only to the same
    object's, so each fit of `sources.make("circle")` would otherwise compile its own programs.
    A source that cannot be hashed is equal only to itself."""

    __slots__ = ("_key", "source")

    def __init__(self, source):
        self.source = source
        try:
            hash(source)
            self._key = (type(source), source)
        except TypeError:
            self._key = (type(source), id(source))  # kept alive by `source`: the id stays its

    def __call__(self, key: jax.Array, n: int) -> jax.Array:
        return self.source.sample(key, n)

    def __eq__(self, other) -> bool:
        return isinstance(other, SourceSampler) and self._key == other._key

    def __hash__(self) -> int:
        return hash(self._key)


def _as_sampler(on_manifold):
    """A (key, n) -> [n, D] function for a Source, a key -> [B, D] callable, or None for rows."""
    if hasattr(on_manifold, "sample") and callable(on_manifold.sample):
        return SourceSampler(on_manifold), tuple(getattr(on_manifold, "dim_names", ()))
    if callable(on_manifold):
        fn = on_manifold

        def sampler(key, n):
            # A user's key -> [B, D] sampler fixes its own batch size; draw enough batches.
            first = fn(key)
            if getattr(first, "ndim", None) != 2:
                shape = getattr(first, "shape", type(first).__name__)
                raise ValueError(
                    f"the on_manifold sampler's output must have shape [B, D], got {shape}"
                )
            reps = -(-n // first.shape[0])
            if reps == 1:
                return first[:n]
            more = jax.vmap(fn)(jax.random.split(jax.random.fold_in(key, 1), reps - 1))
            return jnp.concatenate([first, more.reshape(-1, first.shape[-1])])[:n]

        return sampler, ()
    return None, ()


def _check_rows(rows, what: str) -> np.ndarray:
    if isinstance(rows, jax.Array | np.ndarray):
        dtype = rows.dtype
    else:
        rows = np.asarray(rows)
        dtype = rows.dtype
    if not np.issubdtype(dtype, np.floating):
        raise TypeError(f"{what} must be a floating-point array, got dtype {dtype}: cast it "
                        "first (rows.astype(np.float32))")
    host = np.asarray(rows)
    if host.ndim != 2:
        raise ValueError(f"{what} must have shape [N, D], got {host.shape}")
    if host.shape[0] == 0 or host.shape[1] == 0:
        raise ValueError(f"{what} is empty: shape {host.shape}")
    bad = ~np.isfinite(host)
    if bad.any():
        rows_bad = np.unique(np.nonzero(bad)[0])
        raise ValueError(
            f"{what} has {bad.sum()} non-finite values (NaN/inf) in {rows_bad.size} rows, "
            f"first at row {rows_bad[0]}: drop them first (rows[np.isfinite(rows).all(1)])"
        )
    if host.shape[0] < 2 or np.all(host.max(axis=0) == host.min(axis=0)):
        raise ValueError(
            f"{what} is constant: every row is identical, there is no manifold to learn"
        )
    if host.shape[0] < MIN_ROWS:
        raise ValueError(
            f"{what}: {host.shape[0]} rows, at least {MIN_ROWS} are needed to learn a "
            f"manifold and keep some rows out to check it; pass more rows"
        )
    return host


MIN_ROWS = 32
HELD_OUT = 8192  # rows kept out of training (at most a tenth of the user's rows)
DENSE = 16384  # training rows the mining of spurious zeros measures distances to
THIN = 0.01  # an axis narrower than this share of the widest is padded ...
PADDED = 0.1  # ... to this share of it


def padded_box(low: np.ndarray, high: np.ndarray, names=()) -> tuple[np.ndarray, np.ndarray]:
    """The data's box with every axis at least `PADDED` × the widest one wide.

    A constant (or nearly constant) coordinate is itself a relation, x_i = c; in a box of zero
    width no off-manifold row would ever leave it, so nothing could be learned of it. Padded,
    the relation is learned like any other.
    """
    low, high = np.asarray(low, np.float64), np.asarray(high, np.float64)
    width = high - low
    widest = float(width.max())
    thin = width < THIN * widest
    for i in np.nonzero(thin)[0]:
        name = names[i] if i < len(names) else f"column {i}"
        centre_i = (low[i] + high[i]) / 2
        if width[i] == 0:
            log.warning("%s is constant (%.4g): it is the relation %s = %.4g; its off-manifold "
                        "box is padded to ±%.3g", name, centre_i, name, centre_i,
                        PADDED * widest / 2)
        else:
            log.warning("%s spans %.3g, under %g%% of the widest column's %.3g: taken as the "
                        "relation %s ≈ %.4g, its off-manifold box padded to ±%.3g (columns on "
                        "very different scales: divide each by its spread first)", name,
                        width[i], 100 * THIN, widest, name, centre_i, PADDED * widest / 2)
    centre = (low + high) / 2
    half = np.where(thin, PADDED * widest / 2, width / 2)
    return (centre - half).astype(np.float32), (centre + half).astype(np.float32)


def _pool_size(on_manifold) -> int | None:
    """A Source's `pool_size` (draw that many rows once, then treat them as rows), or None."""
    pool_size = getattr(on_manifold, "pool_size", None)
    if pool_size is None or not hasattr(on_manifold, "sample"):
        return None
    if not isinstance(pool_size, int) or isinstance(pool_size, bool) or pool_size < 2:
        raise ValueError(f"a source's pool_size must be None or an integer ≥ 2, got {pool_size!r}")
    return pool_size


def prepare(on_manifold, batch_size: int, noise_scale: float, key, calibration_batches: int):
    """Validate the user's data and build its `Batches`.

    A Source with a `pool_size` is sampled once here (`pool_size` rows) and then behaves as rows;
    a path (str or os.PathLike) names a `.npy` / `.csv` file of rows (`sources.make`).
    """
    if isinstance(on_manifold, str | os.PathLike):
        on_manifold = sources.make(os.fspath(on_manifold))
    batches = _prepare(on_manifold, batch_size, noise_scale, key, calibration_batches)
    if not batches.units.identity:
        log.info("the rows are far from unit scale or the origin: fitting them %s (the "
                 "relations returned take τ as given)", batches.units.describe(batches.dim_names))
    return batches


def _box_and_units(host, names) -> tuple[np.ndarray, np.ndarray, Units]:
    """The padded box of rows [N, D] (the user's units, its warnings in them) and the fit's
    units, the box moved into them."""
    box = np.asarray(bounding_box(jnp.asarray(host, jnp.float32)))
    low, high = padded_box(*box, names)
    units = choose(*box)
    if units.identity:
        return low, high, units
    return units.to_fit(low.astype(np.float64)), units.to_fit(high.astype(np.float64)), units


def _prepare(on_manifold, batch_size: int, noise_scale: float, key, calibration_batches: int):
    sampler, names = _as_sampler(on_manifold)
    pool_size = _pool_size(on_manifold)
    if sampler is None or pool_size is not None:
        if pool_size is None:
            host = _check_rows(on_manifold, "on_manifold data")
        else:
            started = time.perf_counter()
            pool = _call_sampler(sampler, key, pool_size)
            host = _check_rows(pool, getattr(on_manifold, "name", None)
                               or "the on_manifold source's pool")
            log.info(
                "drew a pool of %d rows from %s in %.1f s",
                pool_size,
                getattr(on_manifold, "name", type(on_manifold).__name__),
                time.perf_counter() - started,
            )
            if names and len(names) != host.shape[1]:
                names = ()
        k_split = jax.random.fold_in(key, 1)
        order = np.asarray(jax.random.permutation(k_split, host.shape[0]))
        held = min(HELD_OUT, max(host.shape[0] // 10, 1))
        held_out, train = host[order[:held]], host[order[held:]]
        if train.shape[0] < batch_size:
            log.warning("%d training rows < batch_size %d: batches repeat rows (drawn with "
                        "replacement)", train.shape[0], batch_size)
        low, high, units = _box_and_units(host, names)
        held_out, train = units.to_fit(held_out), units.to_fit(train)
        rows = jnp.asarray(train, jnp.float32)
        dense = rows[: min(DENSE, rows.shape[0])]
        return Batches(rows, None, jnp.asarray(low), jnp.asarray(high), batch_size,
                       noise_scale, names, jnp.asarray(held_out, jnp.float32), dense, units)
    sample = _call_sampler(sampler, key, batch_size * calibration_batches)
    host = _check_rows(sample, "the on_manifold sampler's output")
    if names and len(names) != host.shape[1]:
        names = ()
    low, high, units = _box_and_units(host, names)
    if not units.identity:
        sampler = ScaledSampler(sampler, units)
    fresh = jnp.asarray(_call_sampler(sampler, jax.random.fold_in(key, 1), HELD_OUT + DENSE),
                        jnp.float32)
    held_out, dense = fresh[:HELD_OUT], fresh[HELD_OUT:]
    return Batches(None, sampler, jnp.asarray(low), jnp.asarray(high), batch_size, noise_scale,
                   names, held_out, dense, units)


def _call_sampler(sampler, key, n: int):
    try:
        return sampler(key, n)
    except ValueError as error:
        if "sampler's output" in str(error):
            raise
        raise ValueError(
            f"the on_manifold sampler failed when called with a PRNG key: {error}"
        ) from error
    except Exception as error:  # the user's code: say whose it is
        raise ValueError(
            f"the on_manifold sampler failed when called with a PRNG key: {error}"
        ) from error
