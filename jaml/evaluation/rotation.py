"""Rotation-block errors for objects in an LD state (docs/reference/suite.md §5): M = R_trueᵀ R̂.

The Rearrange LD states hold per object a normalised position (3) and the 9 row-major entries of
its rotation matrix. The reference scores a predicted block R̂ by its principal axis only (YCB
meshes are treated as cylinders): with M = R_trueᵀ R̂, the third column M[:, 2] is R̂'s z axis in
the true object frame, e_z when the axes agree, −e_z when flipped; the error is the elementwise
min(|M[:, 2] − e_z|, |M[:, 2] + e_z|) averaged over the three entries. R̂ comes from a regressor
and need not be orthonormal; the formula is applied as is.

Shapes: N rows, D LD-state width, J rotation blocks (9 entries each).
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

BLOCK = 9  # entries of a row-major 3×3 rotation matrix


def as_matrices(blocks: jax.Array) -> jax.Array:
    """[..., 9] row-major entries → [..., 3, 3]."""
    return jnp.reshape(blocks, (*jnp.shape(blocks)[:-1], 3, 3))


def relative(r_true: jax.Array, r_pred: jax.Array) -> jax.Array:
    """[..., 3, 3]: M = R_trueᵀ R̂."""
    return jnp.swapaxes(r_true, -1, -2) @ r_pred


def principal_axis_error(r_true: jax.Array, r_pred: jax.Array) -> jax.Array:
    """[...]: the reference's error of R̂ [..., 3, 3] against R_true: the mean over i of
    min(|M[i, 2] − e_z[i]|, |M[i, 2] + e_z[i]|), M = R_trueᵀ R̂ (sign of the axis ignored)."""
    axis = relative(r_true, r_pred)[..., :, 2]
    e_z = jnp.asarray([0.0, 0.0, 1.0], axis.dtype)
    return jnp.mean(jnp.minimum(jnp.abs(axis - e_z), jnp.abs(axis + e_z)), axis=-1)


def principal_axis_angle(r_true: jax.Array, r_pred: jax.Array) -> jax.Array:
    """[...] in [0, π/2]: the angle between the two z axes up to sign, arccos |M[2, 2]|, for
    rotations (a diagnostic in radians; R̂ is not re-orthonormalised, so M[2, 2] is clipped)."""
    m22 = relative(r_true, r_pred)[..., 2, 2]
    return jnp.arccos(jnp.clip(jnp.abs(m22), 0.0, 1.0))


def rotation_angle(r_true: jax.Array, r_pred: jax.Array) -> jax.Array:
    """[...] in [0, π]: the angle of the rotation M = R_trueᵀ R̂, arccos((tr M − 1)/2)."""
    trace = jnp.trace(relative(r_true, r_pred), axis1=-2, axis2=-1)
    return jnp.arccos(jnp.clip((trace - 1.0) / 2.0, -1.0, 1.0))


def rearrange_rotation_starts(num_objects: int = 4, prefix: int = 5) -> tuple[int, ...]:
    """Start indices of the rotation blocks in a Rearrange LD state: after `prefix` entries
    (reacher: version/10 and sin/cos of two joints = 5; Franka: 1 + 14 = 15), each object has
    3 position entries then 9 rotation entries."""
    if num_objects < 0 or prefix < 0:
        raise ValueError(f"num_objects and prefix must be ≥ 0, got {num_objects}, {prefix}")
    return tuple(prefix + 12 * i + 3 for i in range(num_objects))


def ld_blocks(names: Sequence[str], groups: Sequence[str]) -> tuple[tuple[int, ...],
                                                                       tuple[str, ...]]:
    """(starts, labels) of the rotation blocks of an LD state, from an env's metadata
    (`ld_state_names`, `ld_state_groups`): its "orientation" entries, in blocks of 9 named
    P_r00, P_r01, …, P_r22 (row-major) in that order; the label of block P is "P_rotation".
    ((), ()) for an LD state without "orientation" entries (every domain but Rearrange).
    ValueError if the orientation entries do not form such blocks."""
    names, groups = list(names), list(groups)
    if len(names) != len(groups):
        raise ValueError(f"{len(names)} LD names but {len(groups)} groups")
    entries = [f"r{i}{j}" for i in range(3) for j in range(3)]
    starts, labels = [], []
    k = 0
    while k < len(names):
        if groups[k] != "orientation":
            k += 1
            continue
        prefix = names[k].removesuffix("_r00")
        expected = [f"{prefix}_{e}" for e in entries]
        if prefix == names[k] or names[k:k + BLOCK] != expected or any(
                g != "orientation" for g in groups[k:k + BLOCK]):
            raise ValueError(f"LD entries from {names[k]!r} (index {k}) are not a 9-entry "
                             f"rotation block {expected[0]} … {expected[-1]} in the "
                             "\"orientation\" group")
        if f"{prefix}_rotation" in names:
            raise ValueError(f"the label {prefix}_rotation of a rotation block is an LD name")
        starts.append(k)
        labels.append(f"{prefix}_rotation")
        k += BLOCK
    return tuple(starts), tuple(labels)


def check_starts(starts: Sequence[int], dim: int) -> tuple[int, ...]:
    """`starts` as sorted ints, or ValueError if a block leaves [0, dim) or two overlap."""
    starts = tuple(sorted(int(s) for s in starts))
    for i, s in enumerate(starts):
        if s < 0 or s + BLOCK > dim:
            raise ValueError(f"rotation block at {s} does not fit in an LD state of width {dim}")
        if i and s < starts[i - 1] + BLOCK:
            raise ValueError(f"rotation blocks at {starts[i - 1]} and {s} overlap")
    return starts


def euclidean_mask(dim: int, starts: Sequence[int]) -> np.ndarray:
    """bool [D]: True for the entries outside every rotation block."""
    mask = np.ones(dim, bool)
    for s in check_starts(starts, dim):
        mask[s:s + BLOCK] = False
    return mask


def block_errors(pred: jax.Array, true: jax.Array, starts: Sequence[int]) -> jax.Array:
    """[N, J]: the principal-axis error of each rotation block of pred / true [N, D]."""
    starts = check_starts(starts, pred.shape[-1])
    if not starts:
        return jnp.zeros((*pred.shape[:-1], 0), pred.dtype)
    idx = np.asarray(starts)[:, None] + np.arange(BLOCK)  # [J, 9]
    return principal_axis_error(as_matrices(true[..., idx]), as_matrices(pred[..., idx]))


def alignment_loss(pred: jax.Array, true: jax.Array, starts: Sequence[int]) -> jax.Array:
    """Scalar: the reference regressor's loss, the mean L1 over the Euclidean entries plus, for
    each rotation block, its mean principal-axis error (the sum of the means)."""
    mask = euclidean_mask(pred.shape[-1], starts)
    l1 = jnp.mean(jnp.abs(pred[..., mask] - true[..., mask])) if mask.any() else 0.0
    return l1 + jnp.sum(jnp.mean(block_errors(pred, true, starts), axis=0))
