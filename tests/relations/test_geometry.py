"""`relations.project` and the Jacobian rank check against closed forms."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml import relations, sources
from jaml.relations.networks import Relation
from jaml.relations.relation_set import RelationSet

# Two planes x + z = 1 and y − z = 2; their intersection is the line (1, 2, 0) + t (−1, 1, 1).
A = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, -1.0]], np.float32)
B = np.array([1.0, 2.0], np.float32)
LINE_POINT, LINE_DIR = np.array([1.0, 2.0, 0.0]), np.array([-1.0, 1.0, 1.0])


def _planes(tau):
    return tau @ A.T - B


def test_linear_relations_project_in_one_step_to_the_nearest_point_of_their_intersection():
    tau = np.asarray(jax.random.normal(jax.random.key(0), (64, 3))) * 3.0
    points, residuals, _ = relations.project(_planes, tau, steps=1)
    t = (tau - LINE_POINT) @ LINE_DIR / (LINE_DIR @ LINE_DIR)
    nearest = LINE_POINT + t[:, None] * LINE_DIR
    np.testing.assert_allclose(points, nearest, atol=1e-5)
    np.testing.assert_allclose(residuals, 0.0, atol=1e-5)


def test_free_coordinates_solve_for_the_next_state_and_keep_the_start():
    c = 2.5  # s1 = s0 + v0 + c/2, v1 = v0 + c: constant acceleration for one second

    def dynamics(tau):
        s0, v0, s1, v1 = (tau[..., i] for i in range(4))
        return jnp.stack([s1 - s0 - v0 - c / 2, v1 - v0 - c], axis=-1)

    tau = np.asarray(jax.random.uniform(jax.random.key(1), (32, 4), minval=-1.0, maxval=1.0))
    points, _, _ = relations.project(dynamics, tau, steps=1, free=[False, False, True, True])
    np.testing.assert_allclose(points[:, :2], tau[:, :2], atol=1e-6)
    np.testing.assert_allclose(points[:, 2], tau[:, 0] + tau[:, 1] + c / 2, atol=1e-5)
    np.testing.assert_allclose(points[:, 3], tau[:, 1] + c, atol=1e-5)


def test_gauss_newton_reaches_the_true_ellipse_from_nearby_points():
    src = sources.make("ellipse")
    on = src.sample(jax.random.key(2), 256)
    start = on + 0.2 * jax.random.normal(jax.random.key(3), on.shape)
    points, residuals, _ = relations.project(src.residuals, start, steps=15)
    assert float(jnp.max(jnp.abs(residuals))) < 1e-4
    # Independent check: distance to a dense sampling of the curve (spacing ≈ 1.5e-4).
    t = np.linspace(0.0, 2.0 * np.pi, 100_000)
    curve = np.stack([np.sqrt(2) * np.cos(t), 2 * np.sin(t) - 1, np.sin(t) - 1], -1)
    nearest = np.min(np.linalg.norm(np.asarray(points)[:, None] - curve[None], axis=-1), 1)
    assert nearest.max() < 1e-3


def test_project_on_a_relation_set_matches_its_function_form():
    module = Relation(4, 2)
    params = module.init(jax.random.key(4), jnp.zeros((1, 3)))
    rs = RelationSet.empty(3, 2, 1.5).append(params, 0.1, 1.0, 4)
    tau = jax.random.normal(jax.random.key(5), (8, 3))
    got, res, _ = relations.project(rs, tau, steps=3)
    # A RelationSet moves along its outputs before their tanh (same zero set, no plateau).
    raw = relations.relation_set.evaluate_raw
    want, _, _ = relations.project(lambda t: raw(rs, t), tau, steps=3)
    np.testing.assert_allclose(got, want, atol=1e-5)
    np.testing.assert_allclose(res, relations.evaluate(rs, want), atol=1e-6)
    assert res.shape == (8, 1)


def _at_angle(theta):
    return lambda tau: jnp.stack(
        [tau[..., 0], math.cos(theta) * tau[..., 0] + math.sin(theta) * tau[..., 1]], -1
    )


def test_rank_of_two_gradients_at_an_angle_follows_tan_half_angle():
    theta = math.radians(30.0)
    tau = jax.random.normal(jax.random.key(6), (16, 3))
    ranks, ratios = relations.jacobian_ranks(_at_angle(theta), tau, rtol=0.1)
    # Unit rows at angle θ: singular values √(1 ± cos θ), ratio tan(θ/2) = 0.268.
    np.testing.assert_allclose(ratios[:, 1], math.tan(theta / 2), rtol=1e-5)
    assert (ranks == 2).all()
    assert (relations.jacobian_ranks(_at_angle(theta), tau, rtol=0.3)[0] == 1).all()


def test_codimension_counts_dependent_and_degenerate_relations():
    # Points where x² + y² − 1 is exactly 0 in float32, so the squared relation's gradient is.
    on_circle = jnp.array([[1.0, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]])

    def plane_and_cylinder(t):
        return jnp.stack([t[..., 2], t[..., 0] ** 2 + t[..., 1] ** 2 - 1.0], -1)

    def plane_and_squared_cylinder(t):  # the same zero set, a zero gradient: it cuts nothing
        return jnp.stack([t[..., 2], (t[..., 0] ** 2 + t[..., 1] ** 2 - 1.0) ** 2], -1)

    def four_planes(t):  # four relations in R³ cut at most three dimensions
        return t[..., :3] @ jnp.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]]).T

    full = relations.codimension(plane_and_cylinder, on_circle)
    assert full["full_rank_fraction"] == 1.0 and full["rank_fractions"] == [0.0, 0.0, 1.0]
    degenerate = relations.codimension(plane_and_squared_cylinder, on_circle)
    assert degenerate["full_rank_fraction"] == 0.0 and degenerate["rank_fractions"][1] == 1.0
    over = relations.codimension(four_planes, on_circle)
    assert over["full_rank_fraction"] == 0.0 and over["rank_fractions"][3] == 1.0


def test_project_rejects_a_mask_of_the_wrong_size():
    with pytest.raises(ValueError, match="free"):
        relations.project(_planes, np.zeros((2, 3), np.float32), free=[True, False])


def test_the_trust_region_keeps_a_saturated_relation_from_sending_points_away():
    """g = tanh(5 (x − 0.5)) is flat far from its zero: an undamped Gauss–Newton step from
    there is |g| / |g'| ≈ e^{10 |x − 0.5|} / 10 long. With the data box [0, 1]³ every step is
    at most a tenth of its diagonal and every point stays in the box grown by half its width."""

    def saturated(tau):
        return jnp.tanh(5.0 * (tau[..., :1] - 0.5))

    start = np.asarray(jax.random.uniform(jax.random.key(6), (256, 3), minval=-0.5, maxval=1.5))
    x = start[:, 0]
    undamped = np.abs(np.tanh(5 * (x - 0.5)) / (5 * (1 - np.tanh(5 * (x - 0.5)) ** 2)))
    assert undamped.max() > 100  # the plain Gauss–Newton step the trust region prevents
    out = relations.project(saturated, start, steps=50, bounds=(np.zeros(3), np.ones(3)))
    points = np.asarray(out.points)
    assert np.isfinite(points).all() and points.min() >= -0.5 and points.max() <= 1.5
    np.testing.assert_allclose(points[:, 1:], start[:, 1:], atol=1e-6)  # only x moves
    inside = np.abs(start[:, 0] - 0.5) < 0.5  # starts whose slope is not vanishingly small
    assert np.asarray(out.converged)[inside].all()
    np.testing.assert_allclose(points[inside, 0], 0.5, atol=1e-3)
    # converged says so exactly where every |G_k| ≤ tolerance
    np.testing.assert_array_equal(np.asarray(out.converged),
                                  np.abs(np.asarray(out.residuals)[:, 0]) <= 1e-3)


def test_a_relation_set_projects_inside_its_own_data_box():
    module = Relation(4, 2)
    params = module.init(jax.random.key(7), jnp.zeros((1, 3)))
    rs = RelationSet.empty(3, 2, 1.5, low=(0.0, 0.0, 0.0), high=(1.0, 2.0, 1.0)).append(
        params, 0.01, 1.0, 4)
    start = jax.random.uniform(jax.random.key(8), (128, 3), minval=-3.0, maxval=3.0)
    points = np.asarray(relations.project(rs, start).points)
    low, high = np.array([-0.5, -1.0, -0.5]), np.array([1.5, 3.0, 1.5])
    assert (points >= low - 1e-6).all() and (points <= high + 1e-6).all()


def test_a_saturated_relation_projects_through_its_output_before_the_tanh():
    """g = tanh(u) with the output layer scaled ×1e4: g is ±1 (its float32 gradient 0) almost
    everywhere, yet its zero set is u's. `evaluate_raw` is u (atanh g where g is not saturated),
    and `project` moves along u, so box points still reach {g = 0}."""
    module = Relation(4, 2)
    params = module.init(jax.random.key(9), jnp.zeros((1, 3)))
    params = jax.tree_util.tree_map_with_path(
        lambda path, x: x * 1e4 if "out_" in jax.tree_util.keystr(path) else x, params)
    rs = RelationSet.empty(3, 2, 1.5, low=(-1.0,) * 3, high=(1.0,) * 3).append(params, 1e-3,
                                                                             1.0, 4)
    tau = jax.random.uniform(jax.random.key(10), (256, 3), minval=-1.0, maxval=1.0)
    g = np.asarray(relations.evaluate(rs, tau))[:, 0]
    u = np.asarray(relations.relation_set.evaluate_raw(rs, tau))[:, 0]
    assert np.mean(np.abs(g) == 1.0) > 0.5  # saturated in float32
    small = np.abs(g) < 0.9
    np.testing.assert_allclose(u[small], np.arctanh(g[small]), rtol=1e-3, atol=1e-5)
    out = relations.project(rs, tau)
    assert np.mean(np.asarray(out.converged)) > 0.9
