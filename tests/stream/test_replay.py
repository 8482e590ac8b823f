"""The replay against the reference's rules (docs/reference/suite.md §3), checked with plain
loops."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml.stream import replay as rl

FRAME = (2, 2, 3)


def columns(ids, column_len=5, starts=None):
    """Columns whose every entry encodes (column id, step): id·100 + t."""
    ids = np.asarray(ids)
    tag = ids[:, None] * 100 + np.arange(column_len)[None]
    return rl.Columns(
        frames=jnp.asarray(
            np.broadcast_to((tag % 256)[..., None, None, None], (*tag.shape, *FRAME)), jnp.uint8
        ),
        actions=jnp.asarray(tag[..., None], jnp.float32),
        ld=jnp.asarray(tag[..., None], jnp.float32),
        starts=jnp.asarray(np.zeros(tag.shape, bool) if starts is None else starts),
    )


def empty(num_slots=8, column_len=5, keep=0.5):
    return rl.init(num_slots, column_len, FRAME, 1, 1, keep)


def slot_ids(replay):
    return np.asarray(replay.data.ld[:, 0, 0]) // 100


def test_fills_in_order_then_keeps_the_initial_fraction():
    replay = empty(num_slots=8, keep=0.5)
    key = jax.random.PRNGKey(0)
    replay = rl.add(replay, columns([1, 2, 3, 4]), key)
    assert int(replay.size) == 4 and not bool(replay.full)
    replay = rl.add(replay, columns([5, 6, 7, 8]), key)
    np.testing.assert_array_equal(slot_ids(replay), [1, 2, 3, 4, 5, 6, 7, 8])
    assert bool(replay.full)
    seen_replaced = set()
    for i in range(40):
        replay = rl.add(replay, columns([100 + 2 * i, 101 + 2 * i]), jax.random.PRNGKey(i))
        ids = slot_ids(replay)
        np.testing.assert_array_equal(ids[:4], [1, 2, 3, 4])  # the initial half stays
        assert len(set(ids)) == 8  # two new columns land in two different slots
        seen_replaced |= {k for k in range(4, 8) if ids[k] >= 100}
    assert seen_replaced == {4, 5, 6, 7}  # every replaceable slot gets replaced
    assert int(replay.size) == 8 and int(replay.added) == 88


def test_keep_zero_replaces_any_slot():
    replay = rl.add(empty(num_slots=4, keep=0.0), columns([1, 2, 3, 4]), jax.random.PRNGKey(0))
    replaced = set()
    for i in range(30):
        replay = rl.add(replay, columns([100 + i]), jax.random.PRNGKey(i))
        replaced |= {k for k, v in enumerate(slot_ids(replay)) if v >= 100}
    assert replaced == {0, 1, 2, 3}


def reference_window(frames, actions, starts, t, L):
    """The reference rule, literally: if an episode starts at k in (t, t + L), frames from k − 1
    on become frame k − 1 and actions from k − 1 on become action k − 2."""
    f, a = list(frames[t:t + L]), list(actions[t:t + L])
    for k in range(t + 1, t + L):
        if starts[k]:
            for j in range(k - 1, t + L):
                f[j - t] = frames[k - 1]
                a[j - t] = actions[max(k - 2, 0)]
            break
    return np.asarray(f), np.asarray(a)


@pytest.mark.parametrize("start_steps", [(), (3,), (1, 4), (0, 6), (2, 3)])
def test_window_cuts_sequences_at_episode_starts_like_the_reference(start_steps):
    C, L = 8, 4
    starts = np.zeros((1, C), bool)
    starts[0, list(start_steps)] = True
    col = jax.tree.map(lambda x: x[0], columns([7], C, starts))
    for t in range(C - L + 1):
        got = rl.window(col, jnp.asarray(t), L)
        want_f, want_a = reference_window(np.asarray(col.ld[:, 0]), np.asarray(col.actions[:, 0]),
                                          starts[0], t, L)
        np.testing.assert_array_equal(np.asarray(got.ld[:, 0]), want_f, err_msg=f"t={t}")
        np.testing.assert_array_equal(np.asarray(got.frames[:, 0, 0, 0]), want_f % 256)
        np.testing.assert_array_equal(np.asarray(got.actions[:, 0]), want_a, err_msg=f"t={t}")


def test_sample_draws_valid_windows_from_filled_slots_only():
    replay = rl.add(empty(num_slots=8, column_len=6), columns([3, 9], 6), jax.random.PRNGKey(0))
    seqs = rl.sample(replay, jax.random.PRNGKey(1), 256, 3)
    tags = np.asarray(seqs.ld[..., 0]).astype(int)
    assert set(np.unique(tags // 100)) == {3, 9}
    np.testing.assert_array_equal(np.diff(tags, axis=1), 1)  # consecutive steps, no boundary here
    assert set(np.unique(tags[:, 0] % 100)) == {0, 1, 2}  # every start in [0, C − L)


def test_bad_sizes_raise_named_errors():
    replay = empty(num_slots=8, column_len=5)
    with pytest.raises(ValueError, match="sequence length 6 does not fit"):
        rl.sample(replay, jax.random.PRNGKey(0), 4, 6)
    with pytest.raises(ValueError, match="columns have 4 steps"):
        rl.add(replay, columns([1], 4), jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="exceed the 4 replaceable slots"):
        rl.add(replay, columns(range(5)), jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match="keep_fraction"):
        rl.init(8, 5, FRAME, 1, 1, keep_fraction=1.0)


@pytest.mark.parametrize("num_slots", [8, 16, 64, 4992])
def test_held_out_slots_are_the_fraction_spread_over_kept_and_replaceable(num_slots):
    mask = rl.held_out_slots(num_slots, 0.3)
    assert mask.sum() == int(np.floor(0.3 * num_slots))
    half = num_slots // 2  # the kept half and the replaceable half each hold some
    assert mask[:half].any() and mask[half:].any()


def test_split_rows_come_from_disjoint_columns_and_share_no_frame():
    """Held-out rows only from the held-out slots, the others only from the rest, each pool's
    every filled slot drawn; a partly filled replay draws from its filled slots alone."""
    replay = rl.add(empty(num_slots=16), columns(np.arange(1, 9)), jax.random.PRNGKey(0))
    replay = rl.add(replay, columns(np.arange(9, 17)), jax.random.PRNGKey(1))
    mask = rl.held_out_slots(16, 0.3)
    held = np.arange(400) < 120
    seqs = rl.sample_split(replay, jax.random.PRNGKey(2), jnp.asarray(held), 2, 0.3)
    slot = np.asarray(seqs.ld[:, 0, 0]) // 100 - 1  # column id k sits in slot k - 1
    assert set(slot[held]) == set(np.flatnonzero(mask))
    assert set(slot[~held]) == set(np.flatnonzero(~mask))
    tags = np.asarray(seqs.ld[..., 0])
    assert not set(tags[held].ravel()) & set(tags[~held].ravel())
    half = rl.add(empty(num_slots=16), columns(np.arange(1, 9)), jax.random.PRNGKey(0))
    seqs = rl.sample_split(half, jax.random.PRNGKey(3), jnp.asarray(held), 2, 0.3)
    slot = np.asarray(seqs.ld[:, 0, 0]) // 100 - 1
    assert slot.max() < 8 and set(slot[held]) == set(np.flatnonzero(mask[:8]))


def test_a_replay_too_small_to_hold_out_a_slot_says_so():
    with pytest.raises(ValueError, match=r"cannot hold out 30% of them by slot.*leading"):
        rl.sample_split(empty(num_slots=2, keep=0.0), jax.random.PRNGKey(0),
                        jnp.zeros(4, bool), 2, 0.3)
