"""Loss terms, networks and the stopping rule on hand-computed values
(docs/reference/aml.md §12)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml import relations
from jaml.relations import losses
from jaml.relations.networks import Relation, SyzygyCoefficients, relation_width


def _count(params):
    return sum(x.size for x in jax.tree.leaves(params))


def test_widths_double_per_relation_up_to_the_cap():
    assert [relation_width(k, 4, 256) for k in range(9)] == [4, 8, 16, 32, 64, 128, 256, 256, 256]


@pytest.mark.parametrize(("dim", "counts"), [(3, (61, 185, 625)), (4, (65, 193, 641))])
def test_parameter_counts_match_the_reference(dim, counts):
    for k, count in enumerate(counts):
        params = Relation(relation_width(k, 4, 256)).init(jax.random.key(0), jnp.zeros((1, dim)))
        assert _count(params) == count
    syz = SyzygyCoefficients(9).init(jax.random.key(0), jnp.zeros((1, 3)))
    assert _count(syz) == 2537


def test_relation_output_is_bounded_and_syzygy_output_clamped():
    tau = jax.random.normal(jax.random.key(0), (64, 3)) * 100
    g = Relation(4)
    y = g.apply(g.init(jax.random.key(1), tau), tau)
    assert y.shape == (64,) and float(jnp.max(jnp.abs(y))) < 1.0
    f = SyzygyCoefficients(2, bound=0.5)
    out = f.apply(f.init(jax.random.key(2), tau), tau * 1e4)
    assert out.shape == (64, 2) and float(jnp.max(jnp.abs(out))) <= 0.5


def test_input_gradients_equal_per_row_autodiff():
    g = Relation(8)
    params = g.init(jax.random.key(0), jnp.zeros((1, 3)))
    tau = jax.random.normal(jax.random.key(1), (16, 3))
    y, v = losses.input_gradients(lambda t: g.apply(params, t), tau)
    for i in range(16):
        np.testing.assert_allclose(v[i], jax.grad(lambda t: g.apply(params, t))(tau[i]), atol=1e-7)
    np.testing.assert_allclose(y, g.apply(params, tau), rtol=1e-6)
    # The reference's per-row vector is 1/B of this: its hinge uses ‖v‖/B.
    B = 16
    np.testing.assert_allclose(
        losses.reference_gradient_term(v, B),
        1 - 100 * np.minimum(np.linalg.norm(v, axis=-1) / B, 1e-4),
        rtol=1e-6,
    )


def test_paper_terms_on_hand_values():
    y = jnp.array([0.3, -0.2])
    v = jnp.array([[3.0, 4.0], [0.0, 0.5]])  # norms 5 and 0.5
    np.testing.assert_allclose(losses.distance(y, v), [0.06, 0.4], rtol=1e-6)
    np.testing.assert_allclose(losses.log_gradient_norm(v), [-math.log(5), math.log(2)], rtol=1e-6)
    # Capped at ‖∇g‖ = 1: no push past it (and no gradient: the min is flat there).
    np.testing.assert_allclose(losses.log_gradient_norm(v, 1.0), [0.0, math.log(2)], atol=1e-7)
    push = jax.grad(lambda v: losses.log_gradient_norm(v, 1.0).sum())(v)
    np.testing.assert_allclose(push[0], [0.0, 0.0])
    np.testing.assert_allclose(push[1], [0.0, -2.0], rtol=1e-6)  # −d log‖v‖/dv = −v/‖v‖²


def test_reference_terms_on_hand_values():
    B = 1024
    v = jnp.array([[0.0, 0.05 * B * 1e-3], [0.2 * B * 1e-3, 0.0]])  # ‖v/B‖ = 5e-5 and 2e-4
    np.testing.assert_allclose(losses.reference_gradient_term(v, B), [0.995, 0.99], rtol=1e-6)
    y = jnp.array([1e-3, 1.0])  # 1e-3·|g|/‖v/B‖ = 0.02 → floor 0.05;  5.0
    np.testing.assert_allclose(losses.reference_distance_term(y, v, B), [0.05, 5.0], rtol=1e-5)


def _pair(angle):
    u = jnp.array([[[1.0, 0.0, 0.0]]])  # [J=1, B=1, D]
    v = jnp.array([[math.cos(angle), math.sin(angle), 0.0]])
    return u, v


def test_transversality_orthogonal_parallel_and_45_degrees():
    u, v = _pair(math.pi / 2)
    assert float(losses.reference_transversality(u, v)[0]) == pytest.approx(0.0, abs=1e-6)
    assert float(losses.log_sin_product(u, v)[0]) == pytest.approx(0.0, abs=1e-6)
    assert float(losses.mean_angle(u, v)) == pytest.approx(math.pi / 2, abs=1e-3)
    u, v = _pair(0.0)  # s² ≤ 0 is floored at 1e-15
    assert float(losses.reference_transversality(u, v)[0]) == pytest.approx(1.0, abs=1e-6)
    assert float(losses.log_sin_product(u, v)[0]) == pytest.approx(-math.log(1e-15), rel=1e-4)
    u, v = _pair(math.pi / 4)
    assert 1 - float(losses.reference_transversality(u, v)[0]) == pytest.approx(0.70711, abs=1e-5)
    assert float(losses.log_sin_product(u, v)[0]) == pytest.approx(math.log(2), abs=1e-5)
    assert float(losses.mean_angle(u, v)) == pytest.approx(math.pi / 4, abs=1e-4)
    # The stopping rule's angle floor: 0.4 · π/2 (the reference's 0.4 of a right angle).
    assert relations.Config().min_angle == pytest.approx(0.62832, abs=1e-5)


def test_transversality_takes_the_product_over_earlier_relations():
    earlier = jnp.array([[[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]]])
    v = jnp.array([[1.0, 1.0, 0.0]])  # 45° to both
    assert float(losses.log_sin_product(earlier, v)[0]) == pytest.approx(2 * math.log(2), abs=1e-5)
    assert 1 - float(losses.reference_transversality(earlier, v)[0]) == pytest.approx(0.5, abs=1e-5)


def test_stopping_rule_uses_the_largest_fifth_of_on_values():
    on = jnp.concatenate([jnp.full((4,), 0.01), jnp.zeros((16,))])  # B = 20: top 4 average 0.01
    assert bool(losses.separated(on, jnp.full((20,), 0.051), 5.0, 0.2))
    assert not bool(losses.separated(on, jnp.full((20,), 0.049), 5.0, 0.2))
    # B ≤ 10 averages every row: mean 0.004 → threshold 0.02.
    small = jnp.array([0.02, 0.0, 0.0, 0.0, 0.0])
    assert bool(losses.separated(small, jnp.full((5,), 0.021), 5.0, 0.2))
    assert not bool(losses.separated(small, jnp.full((5,), 0.019), 5.0, 0.2))
    # top_fraction = 1 is the paper's plain mean-vs-mean rule.
    assert bool(losses.separated(on, jnp.full((20,), 0.011), 5.0, 1.0))


def test_clip_scales_other_terms_to_twice_the_first():
    first = jnp.asarray(0.1)
    assert float(losses.clip_to(jnp.asarray(0.15), first)) == pytest.approx(0.15)
    assert float(losses.clip_to(jnp.asarray(-3.0), first)) == pytest.approx(-0.2)
    # The gradient keeps its direction, scaled by the same factor; the bound carries none.
    grad = jax.grad(lambda t, f: losses.clip_to(t, f), argnums=(0, 1))(jnp.asarray(-3.0), first)
    assert float(grad[0]) == pytest.approx(0.2 / 3.0) and float(grad[1]) == 0.0


def test_syzygy_residual_is_a_dot_product_with_minus_one_last():
    coefficients = jnp.array([[2.0, -1.0]])
    earlier = jnp.array([[0.5, 0.25]])
    y = jnp.array([0.4])
    assert float(losses.syzygy_residual(coefficients, earlier, y)[0]) == pytest.approx(0.35)


def test_the_joint_syzygy_residual_is_blind_to_scale():
    """A syzygy that tracks g_k's scale explains it as well at every scale (what stops g_k from
    escaping f by rescaling); g_k = c·Σ f_j g_j leaves |1 − c|/c of it unexplained."""
    from jaml.relations.syzygy import explained_share

    rng = np.random.default_rng(0)
    coefficients = jnp.asarray(rng.normal(size=(64, 2)))
    earlier = jnp.asarray(rng.normal(size=(64, 2)))
    y = jnp.sum(coefficients * earlier, -1) + 0.1 * jnp.asarray(rng.normal(size=64))
    share = float(explained_share(coefficients, earlier, y))
    assert float(explained_share(7.0 * coefficients, earlier, 7.0 * y)) == pytest.approx(share)
    exact = jnp.sum(coefficients * earlier, -1)
    assert float(explained_share(coefficients, earlier, exact)) == pytest.approx(0.0, abs=1e-6)
    assert float(explained_share(coefficients, earlier, 4.0 * exact)) == pytest.approx(0.75)
    with pytest.raises(ValueError, match="syzygy_training must be one of"):
        relations.Config(syzygy_training="alternating")
