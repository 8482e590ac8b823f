"""The on-device replay of frame columns that keeps its initial fraction
(docs/reference/suite.md §3, VAE_rpl).

A column is `column_len` consecutive steps of one env: frames, the actions executed after them,
the true LD states and a flag for frames that begin an episode. The replay fills its slots in
order; once full, each new column overwrites a random slot in [keep·N, N), so the first
`keep_fraction` of the slots (the initial policy's frames) stay for the whole run. `keep_fraction`
0 is VAE_v0's replay: every slot is replaceable.

Sequences of L frames are drawn as the reference draws them: a random filled column, a random
start t ∈ [0, column_len − L) (so a window never ends on the column's last frame, whose action is
the unknown dummy 0; t = 0 when L = column_len); when an episode begins at k inside the window
(t < k), the frames and LD states from k − 1 on repeat frame k − 1, and the actions from k − 1
on repeat action k − 2, so a sequence never crosses into the next episode.

Shapes: N slots, C = column_len, L sequence length, A action size, D LD-state size.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


@struct.dataclass
class Columns:
    """A batch of columns: frames uint8 [M, C, H, W, 3], actions [M, C, A], ld [M, C, D],
    starts bool [M, C] (frame begins an episode)."""

    frames: jax.Array
    actions: jax.Array
    ld: jax.Array
    starts: jax.Array


@struct.dataclass
class Replay:
    """data: Columns with leading N; size: filled slots; added: columns ever added."""

    data: Columns
    size: jax.Array
    added: jax.Array
    keep_fraction: float = struct.field(pytree_node=False, default=0.5)

    @property
    def num_slots(self) -> int:
        return self.data.starts.shape[0]

    @property
    def column_len(self) -> int:
        return self.data.starts.shape[1]

    @property
    def first_replaceable(self) -> int:
        """Slots below this index are never overwritten once filled."""
        return int(self.keep_fraction * self.num_slots)

    @property
    def full(self) -> jax.Array:
        return self.size >= self.num_slots


def init(num_slots: int, column_len: int, frame_shape: tuple[int, ...], action_size: int,
         ld_size: int, keep_fraction: float = 0.5) -> Replay:
    """An empty replay; raises ValueError on sizes it cannot hold."""
    if num_slots < 1 or column_len < 1:
        raise ValueError(f"replay needs ≥ 1 slot and column_len ≥ 1, got {num_slots}, {column_len}")
    if not 0.0 <= keep_fraction < 1.0:
        raise ValueError(f"replay keep_fraction must be in [0, 1), got {keep_fraction}")
    if int(keep_fraction * num_slots) >= num_slots:
        raise ValueError(f"replay of {num_slots} slots keeps them all at {keep_fraction}")
    data = Columns(
        frames=jnp.zeros((num_slots, column_len, *frame_shape), jnp.uint8),
        actions=jnp.zeros((num_slots, column_len, action_size), jnp.float32),
        ld=jnp.zeros((num_slots, column_len, ld_size), jnp.float32),
        starts=jnp.zeros((num_slots, column_len), bool),
    )
    zero = jnp.zeros((), jnp.int32)
    return Replay(data=data, size=zero, added=zero, keep_fraction=float(keep_fraction))


def add(replay: Replay, columns: Columns, key: jax.Array) -> Replay:
    """Writes M columns: into the next empty slots while any are left, else into random slots of
    [first_replaceable, N) (drawn without replacement within the batch)."""
    m, n = columns.starts.shape[0], replay.num_slots
    if columns.starts.shape[1] != replay.column_len:
        raise ValueError(
            f"columns have {columns.starts.shape[1]} steps, the replay holds {replay.column_len}"
        )
    if m > n - replay.first_replaceable:
        raise ValueError(
            f"{m} columns per add exceed the {n - replay.first_replaceable} replaceable slots"
        )
    sequential = replay.size + jnp.arange(m)
    lo = replay.first_replaceable
    # A random draw without replacement among the replaceable slots (a permutation's head).
    random_slots = lo + jax.random.permutation(key, n - lo)[:m]
    slots = jnp.where(sequential < n, sequential, random_slots)
    data = jax.tree.map(lambda buf, new: buf.at[slots].set(new.astype(buf.dtype)), replay.data,
                        columns)
    return replay.replace(
        data=data, size=jnp.minimum(replay.size + m, n), added=replay.added + m
    )


def sample(replay: Replay, key: jax.Array, batch: int, seq_len: int) -> Columns:
    """`batch` sequences of `seq_len` frames from filled slots, cut at episode starts (see top)."""
    if not 1 <= seq_len <= replay.column_len:
        raise ValueError(
            f"sequence length {seq_len} does not fit the replay's columns of "
            f"{replay.column_len} frames"
        )
    k_col, k_start = jax.random.split(key)
    cols = jax.random.randint(k_col, (batch,), 0, jnp.maximum(replay.size, 1))
    starts = jax.random.randint(k_start, (batch,), 0, max(replay.column_len - seq_len, 1))
    return jax.vmap(lambda c, t: window(jax.tree.map(lambda x: x[c], replay.data), t, seq_len))(
        cols, starts
    )


def held_out_slots(num_slots: int, fraction: float) -> np.ndarray:
    """bool [N]: the slots whose columns only give held-out (validation) rows, floor(N·fraction)
    of them spread evenly over the kept and the replaceable slots. Rows drawn from them share no
    frame with rows drawn from the others: a column's frames are its own."""
    i = np.arange(num_slots)
    return np.floor((i + 1) * fraction) > np.floor(i * fraction)


def sample_split(replay: Replay, key: jax.Array, held_out: jax.Array, seq_len: int,
                 fraction: float) -> Columns:
    """Sequences as `sample` draws them, one per entry of `held_out` (bool [B]): those marked
    from the `held_out_slots(N, fraction)` columns, the others from the rest, each uniform over
    its filled slots. The fit rows and the held-out rows of a regressor then share no frame."""
    mask = held_out_slots(replay.num_slots, fraction)
    pools = np.flatnonzero(mask), np.flatnonzero(~mask)
    if not all(len(p) for p in pools):
        raise ValueError(f"a replay of {replay.num_slots} slots cannot hold out {fraction:.0%} of "
                         "them by slot: raise replay.slots or use eval.validation_split=leading")
    k_val, k_fit, k_start = jax.random.split(key, 3)
    batch = held_out.shape[0]

    def draw(k, pool):  # the filled slots of a sorted pool are its leading entries
        filled = jnp.maximum(jnp.sum(jnp.asarray(pool) < replay.size), 1)
        return jnp.asarray(pool)[jax.random.randint(k, (batch,), 0, filled)]

    cols = jnp.where(held_out, draw(k_val, pools[0]), draw(k_fit, pools[1]))
    starts = jax.random.randint(k_start, (batch,), 0, max(replay.column_len - seq_len, 1))
    return jax.vmap(lambda c, t: window(jax.tree.map(lambda x: x[c], replay.data), t, seq_len))(
        cols, starts
    )


def window(column: Columns, start: jax.Array, seq_len: int) -> Columns:
    """One column's steps [start, start + seq_len), frozen from the step before an episode start."""
    t = start + jnp.arange(seq_len)
    # An episode starting at the window's first frame needs no cut.
    inside = column.starts[t] & (jnp.arange(seq_len) > 0)
    k = jnp.where(jnp.any(inside), t[jnp.argmax(inside)], column.starts.shape[0] + 1)
    frame_idx = jnp.minimum(t, k - 1)
    action_idx = jnp.where(t >= k - 1, jnp.maximum(k - 2, 0), t)
    return Columns(
        frames=column.frames[frame_idx],
        actions=column.actions[action_idx],
        ld=column.ld[frame_idx],
        starts=column.starts[frame_idx] & (jnp.arange(seq_len) == 0),
    )
