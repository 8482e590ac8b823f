"""Encoder distortion (paper eq. 5, App. B.3.2): Var of ρ = log(‖φ1 − φ2‖ / ‖τ1 − τ2‖) over pairs.

The paper computes it on 10K test points and reports the variance (`distortion`). The
reference code reports another number, `irregularity`: the std of log-ratios over every pair of
the first 500 points that agree on the categorical LD entries, the latents read at the
continuous LD entries' indices.

Zero distances: a pair with τ1 = τ2 has no ratio and is skipped (repeated frames at episode ends
give such pairs). A pair with τ1 ≠ τ2 but φ1 = φ2 has ρ = −∞: the encoder collapses distinct
states, and the distortion is then +inf, as the definition says. Unless the encoder could not
tell them apart: two states a fraction of a pixel apart render the same 64×64 frame, and every
encoder gives both one latent. `inputs` (a fingerprint per point of what the encoder read,
e.g. `jaml.stream.analysis`'s hash of the input frames and actions) skips pairs with equal
inputs as pairs with τ1 = τ2 are skipped; skipping equal latents instead would also hide an
encoder's real collapse of distinct inputs.

Shapes: N points, Z latent width, D LD-state width, P pairs.
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np

from jaml.evaluation import _checks

DEFAULT_NUM_PAIRS = 10_000


class CollapsedPairsWarning(UserWarning):
    """The distortion is +inf: distinct states got one latent (the count is in the message)."""


def sample_pairs(num_points: int, num_pairs: int, seed: int = 0) -> tuple[jax.Array, jax.Array]:
    """Index pairs (i [P], j [P]), uniform over ordered pairs of distinct points (i ≠ j)."""
    if num_points < 2:
        raise ValueError(f"too few samples: need at least 2 points for pairs, got {num_points}")
    if num_pairs < 2:
        raise ValueError(f"num_pairs must be ≥ 2 (a variance needs two values), got {num_pairs}")
    first_key, offset_key = jax.random.split(jax.random.key(seed))
    i = jax.random.randint(first_key, (num_pairs,), 0, num_points)
    j = (i + jax.random.randint(offset_key, (num_pairs,), 1, num_points)) % num_points
    return i, j


@jax.jit
def _coefficients(latents, states, inputs, i, j):
    """ρ [P] and its validity mask [P] (False where τ_i = τ_j or the inputs are equal) for given
    pairs."""
    d_latent = jnp.linalg.norm(latents[i] - latents[j], axis=-1)
    d_state = jnp.linalg.norm(states[i] - states[j], axis=-1)
    valid = (d_state > 0) & jnp.any(inputs[i] != inputs[j], axis=-1)
    # log 0 = −inf on purpose where only the latent distance vanishes (see module docstring).
    rho = jnp.log(d_latent) - jnp.log(jnp.where(valid, d_state, 1.0))
    return jnp.where(valid, rho, jnp.nan), valid


def distortion_coefficients(latents, states, num_pairs: int = DEFAULT_NUM_PAIRS, seed: int = 0,
                            inputs=None):
    """ρ [P] for pairs drawn with `seed` (NaN where τ1 = τ2 or the inputs are equal) and the mask
    of valid pairs [P].

    latents [N, Z] = φ(x), states [N, D] = τ, inputs [N, K] (optional): a fingerprint of each
    point's encoder input, any dtype (see the module docstring). The same (N, num_pairs, seed)
    gives the same pairs, so coefficients of different maps over the same points can be
    compared pairwise.
    """
    lat, st = _checks.paired(("latents", "states"), latents, states, min_rows=2)
    if inputs is None:
        inputs = jnp.arange(lat.shape[0])[:, None]  # every point's input its own
    inputs = jnp.asarray(inputs)
    if inputs.ndim != 2 or inputs.shape[0] != lat.shape[0]:
        raise ValueError(f"inputs must be [N, K] with N = {lat.shape[0]} (one fingerprint per "
                         f"point), got shape {inputs.shape}")
    i, j = sample_pairs(lat.shape[0], num_pairs, seed)
    return _coefficients(jnp.asarray(lat), jnp.asarray(st), inputs, i, j)


def _valid_coefficients(latents, states, num_pairs: int, seed: int, inputs) -> np.ndarray:
    """ρ (float64) of the valid pairs; at least 2 of them, or a one-line error."""
    rho, valid = distortion_coefficients(latents, states, num_pairs, seed, inputs)
    rho = np.asarray(rho, np.float64)[np.asarray(valid)]
    if rho.size < 2:
        raise ValueError(
            f"too few non-coincident pairs: {rho.size} of {num_pairs} have τ1 ≠ τ2 (and distinct "
            "inputs); need at least 2"
        )
    return rho


def distortion(latents, states, num_pairs: int = DEFAULT_NUM_PAIRS, seed: int = 0,
               inputs=None) -> float:
    """Var(ρ) over `num_pairs` random pairs of distinct points, skipping pairs with τ1 = τ2 and
    (given `inputs`) pairs whose encoder inputs are equal."""
    rho = _valid_coefficients(latents, states, num_pairs, seed, inputs)
    if np.isneginf(rho).any():
        warnings.warn(f"distortion is inf: the encoder maps {int(np.isneginf(rho).sum())} of "
                      f"{rho.size} pairs of distinct states (and inputs) to one latent",
                      CollapsedPairsWarning, stacklevel=2)
        return float("inf")
    return float(np.var(rho))


def distortion_trimmed(latents, states, num_pairs: int = DEFAULT_NUM_PAIRS, seed: int = 0,
                       inputs=None) -> tuple[float, float, int]:
    """(exact, trimmed, left out): `distortion`'s Var(ρ) over the same pairs (+inf when the
    encoder maps a pair of distinct states and inputs to one latent), Var(ρ) over the pairs
    with a finite ρ, and how many pairs the trimmed figure leaves out (those with ρ = −∞).
    One collapsed pair makes eq. 5's figure infinite; the trimmed one still says how the
    encoder stretches the other pairs, and the count how far it is from the definition."""
    rho = _valid_coefficients(latents, states, num_pairs, seed, inputs)
    finite = rho[np.isfinite(rho)]
    left_out = int(rho.size - finite.size)
    trimmed = float(np.var(finite)) if finite.size >= 2 else float("nan")
    return (float("inf") if left_out else float(np.var(rho)), trimmed, left_out)


IRREGULARITY_POINTS = 500
IRREGULARITY_EPS = 1e-10


def irregularity(latents, states, names, *, latent_columns=None,
                 num_points: int = IRREGULARITY_POINTS) -> float:
    """The reference code's `irreg_std` (utils/analyze_utils.py `analyze_irregularity`).

    Over every pair of the first `num_points` points whose categorical LD entries (names ending
    in "_id") are equal: std of log((‖Δφ‖ + ε) / (‖Δτ‖ + ε)), ε = 1e-10, Δτ over the continuous
    LD entries and Δφ over `latent_columns` of the latents (default: the continuous entries'
    own indices, as the reference indexes them). NaN with fewer than two such pairs.
    latents [N, Z], states [N, D], names: the D LD-state names.
    """
    lat, st = _checks.paired(("latents", "states"), latents, states, min_rows=2)
    names = list(names)
    if len(names) != st.shape[1]:
        raise ValueError(f"names has {len(names)} entries for states of width {st.shape[1]}")
    categorical = [i for i, n in enumerate(names) if n.endswith("_id")]
    continuous = [i for i, n in enumerate(names) if not n.endswith("_id")]
    columns = continuous if latent_columns is None else list(latent_columns)
    if max(columns) >= lat.shape[1]:
        raise ValueError(f"latent columns {columns} outside latents of width {lat.shape[1]}")
    lat = np.asarray(lat, np.float64)[:num_points]
    st = np.asarray(st, np.float64)[:num_points]
    i, j = np.triu_indices(len(st), k=1)
    same = np.all(np.abs(st[i][:, categorical] - st[j][:, categorical]) < 1e-5, axis=1)
    i, j = i[same], j[same]
    if i.size < 2:
        return float("nan")
    d_state = np.linalg.norm(st[i][:, continuous] - st[j][:, continuous], axis=1)
    d_latent = np.linalg.norm(lat[i][:, columns] - lat[j][:, columns], axis=1)
    ratio = np.log((d_latent + IRREGULARITY_EPS) / (d_state + IRREGULARITY_EPS))
    return float(np.std(ratio, ddof=1))
