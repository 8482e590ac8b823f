"""benchmarks/relations_quality.py's measures against closed forms: the ellipse's true relations
land every box point on the curve, all around it, with independent gradients; a pair whose zero
set holds a spurious line, and a dependent pair, score lower (the measures can fail)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks import relations_quality as rq
from jaml import sources


def plane(tau):
    return tau[..., 1] - 2 * tau[..., 2] - 1


def hyperboloid(tau):
    return tau[..., 0] ** 2 + tau[..., 1] ** 2 - 2 * tau[..., 2] ** 2 - 1


def true_pair(tau):
    return jnp.stack([plane(tau), hyperboloid(tau)], -1)


def cylinder(tau):
    """The hyperboloid with z = (y − 1)/2 put in (an element of the same ideal): x² + y²/2 + y
    − 3/2, whose gradient meets the plane's at ≥ 63° all along the curve."""
    return tau[..., 0] ** 2 + tau[..., 1] ** 2 / 2 + tau[..., 1] - 1.5


def spurious_pair(tau):
    """{plane = 0} ∩ {hyperboloid · x = 0}: the ellipse and the line x = 0, y = 2z + 1."""
    return jnp.stack([plane(tau), hyperboloid(tau) * tau[..., 0]], -1)


def dependent_pair(tau):
    return jnp.stack([plane(tau), plane(tau) + plane(tau) ** 2], -1)


@pytest.fixture(scope="module")
def box():
    return rq.data_box(sources.make("ellipse"))


def test_box_and_nearest_point_of_the_ellipse(box):
    low, high = box
    np.testing.assert_allclose(low, [-np.sqrt(2), -3, -2], atol=1e-3)
    np.testing.assert_allclose(high, [np.sqrt(2), 1, 0], atol=1e-3)
    t = np.linspace(0.05, 6.2, 7)
    on = rq.ellipse_curve(t)
    dist, found = rq.ellipse_nearest(on)
    assert dist.max() < 5e-5 and np.abs(found - t).max() < 1e-4  # t to ~2e-5 rad
    # Off the curve: against the nearest of 200,000 curve points, brute force.
    pts = np.random.default_rng(0).uniform(low, high, (16, 3))
    dense = rq.ellipse_curve(np.linspace(0, 2 * np.pi, 200_000, endpoint=False))
    brute = np.sqrt(((pts[:, None] - dense[None]) ** 2).sum(-1)).min(1)
    np.testing.assert_allclose(rq.ellipse_nearest(pts)[0], brute, atol=1e-4)


def test_block_plane_distance_is_zero_on_the_data_and_exact_off_it():
    rows = np.asarray(sources.make("block45").sample(jax.random.key(0), 256))
    assert rq.block_plane_distance(rows).max() < 1e-5
    # Along a unit normal of the plane (v1 − v0 = c moves with v1 alone, s1 − s0 − v0 with s1;
    # together their normals span (0,−1,0,1) and (−1,−1,1,0)), distance = the move.
    normal = np.asarray([0.0, -1.0, 0.0, 1.0]) / np.sqrt(2)
    np.testing.assert_allclose(rq.block_plane_distance(rows + 0.3 * normal), 0.3, atol=1e-5)


def test_true_relations_land_everywhere_and_a_spurious_line_does_not(box):
    low, high = box
    good = rq.landing(true_pair, "ellipse", low, high, seed=0)
    assert good["landed"] >= 0.99 and good["coverage"] == 1.0
    bad = rq.landing(spurious_pair, "ellipse", low, high, seed=0)
    assert bad["landed"] < good["landed"] - 0.1, bad


def test_independence_separates_transversal_from_dependent_relations():
    rows = sources.make("ellipse").sample(jax.random.key(1), 512)
    good = rq.independence(lambda t: jnp.stack([plane(t), cylinder(t)], -1), rows)
    assert good["rank2"] == 1.0 and good["cos_max_pair"] < 0.5
    # The hyperboloid's gradient meets the plane's at cos = (12s − 10)/√(5(24s² − 48s + 28)),
    # s = sin t: at 11.3° where s = −1, under the rank's 11.4° (σ2/σ1 = tan(θ/2) > 0.1), so
    # the true pair itself has rank 2 on only ~89 % of the curve.
    s = np.sin(np.linspace(0, 2 * np.pi, 100_000, endpoint=False))
    cos = np.abs(12 * s - 10) / np.sqrt(5 * (24 * s**2 - 48 * s + 28))
    expected = np.mean(np.tan(np.arccos(cos) / 2) > 0.1)
    assert rq.independence(true_pair, rows)["rank2"] == pytest.approx(expected, abs=0.04)
    bad = rq.independence(dependent_pair, rows)
    assert bad["rank2"] == 0.0 and bad["cos_median"] > 0.999


def test_aggregate_reads_worst_by_direction():
    records = [
        {"case": "ellipse-2", "stack": "jaml", "label": "ellipse-2", "seed": s, "landed": v,
         "wall_s": w, "cos_median": c, "config": {"objective": "paper"},
         "relations": [{"index": 1, "status": "done", "steps": 10, "off_on": 9.0}]}
        for s, v, w, c in ((0, 0.9, 10.0, 0.1), (1, 0.5, 30.0, 0.4), (2, 0.7, 20.0, 0.2))
    ]
    (row,) = rq.aggregate(records, 60.0)
    assert (row["landed_median"], row["landed_worst"], row["landed_best"]) == (0.7, 0.5, 0.9)
    assert (row["wall_s_worst"], row["wall_s_best"]) == (30.0, 10.0)
    assert row["cos_median_worst"] == 0.4 and row["seeds"] == "0/1/2"
    assert rq.parse_seeds("0..7") == list(range(8)) and rq.parse_seeds("2,5") == [2, 5]
    names = [r.name for r in rq.plan(["ellipse-syz", "ellipse-auto"], rq.STACKS, [0], [0, 0.05])]
    assert names == ["ellipse-syz-n0-jaml-s0", "ellipse-syz-n0.05-jaml-s0",
                     "ellipse-syz-n0-reference-s0", "ellipse-syz-n0.05-reference-s0",
                     "ellipse-auto-jaml-s0"]
    names = [r.name for r in rq.plan(["ellipse-syz", "ellipse-2-noisy"], rq.STACKS, [0], [0.05],
                                     skip={"ellipse-syz/jaml"})]
    assert names == ["ellipse-syz-n0.05-reference-s0", "ellipse-2-noisy-n0.05-jaml-s0",
                     "ellipse-2-noisy-n0.05-reference-s0"]
