"""benchmarks/relations_variants.py's truth for the MJX incline rows against hand-computed
distances: the kinematic plane's, and the nearest dynamics of a second pool's rows."""

import json
import math

import numpy as np
import pytest

from benchmarks import relations_variants as rv

SLOPE = 0.1  # dt · velocity scale / position scale, as `draw_pools` records it


@pytest.fixture
def pools(tmp_path, monkeypatch):
    """Two pools of rows τ = (θ, s0, v0, a0, s1, v1) on the kinematic plane, as written by
    `draw_pools` (training pool 0, truth pool 1), with their slope."""
    monkeypatch.setattr(rv, "POOLS", tmp_path)
    rng = np.random.default_rng(0)
    rows = rng.uniform(-1, 1, (64, 6))
    rows[:, 4] = rows[:, 1] + SLOPE * (rows[:, 2] + rows[:, 5]) / 2
    for seed in (0, 1):
        np.save(tmp_path / f"fixed-{seed}.npy", rows.astype(np.float32))
    (tmp_path / "fixed.json").write_text(json.dumps({"slope": SLOPE}))
    return rows


def test_incline_truth_is_the_plane_and_the_nearest_dynamics(pools):
    row = pools[3]
    off_plane = row.copy()
    off_plane[4] += 0.2  # s1 moved: the dynamics are a pool row's, the plane is missed
    off_dynamics = row.copy()
    off_dynamics[5] += 0.5  # v1 moved: off the plane by SLOPE/2 of it, off the dynamics by it
    points = np.stack([row, off_plane, off_dynamics])
    nearest = np.min(np.linalg.norm(pools[:, [0, 2, 3, 5]] - off_dynamics[[0, 2, 3, 5]], axis=1))
    expected = [0.0, 0.2 / math.sqrt(2 + SLOPE**2 / 2),
                max(SLOPE / 2 * 0.5 / math.sqrt(2 + SLOPE**2 / 2), nearest)]
    np.testing.assert_allclose(rv._incline_truth("incline:fixed", points), expected, atol=1e-6)
    assert rv._truth("incline:fixed", points) is not None  # the screen's measure uses it
    plane, pool = rv._incline_truth("incline:fixed", points, parts=True)
    np.testing.assert_allclose(plane, [0.0, expected[1], SLOPE / 2 * 0.5
                                       / math.sqrt(2 + SLOPE**2 / 2)], atol=1e-6)
    np.testing.assert_allclose(pool, [0.0, 0.0, nearest], atol=1e-6)


def test_incline_pool_is_the_drawn_file_or_says_how_to_draw_it(pools, tmp_path):
    source = rv._incline_pool("incline:fixed")
    np.testing.assert_array_equal(np.asarray(source.rows), pools.astype(np.float32))
    assert rv._incline_pool("ellipse") is None
    (tmp_path / "fixed-0.npy").unlink()
    with pytest.raises(FileNotFoundError, match="draws the incline pools"):
        rv._incline_pool("incline:fixed")
