"""benchmarks/bn_reductions.py: the timed sums are a batch norm's, checked against autodiff, and
the Pallas kernels (in Pallas's interpreter) give XLA's sums."""

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import bn_reductions as bn

M, C = 512, 8


def _inputs():
    y = (jax.random.normal(jax.random.PRNGKey(0), (M, C)) * 2 + 0.5).astype(jnp.bfloat16)
    dz = jax.random.normal(jax.random.PRNGKey(1), (M, C), jnp.bfloat16)
    mean, rstd = jnp.linspace(0.3, 0.7, C), jnp.linspace(0.4, 0.6, C)
    return y, dz, mean, rstd, jnp.linspace(0.5, 1.5, C), jnp.linspace(-0.2, 0.2, C)


def test_the_sums_are_the_statistics_and_the_scale_and_bias_gradients():
    """Σy, Σy² by a float64 loop; (Σ dv, Σ dv·u) are the gradients of Σ dz·ELU(u·scale + bias)
    with respect to bias and scale, u the input normalised by fixed statistics."""
    y, dz, mean, rstd, scale, bias = _inputs()
    s, q = bn.xla_stats(y)
    y64 = np.asarray(y, np.float64)
    np.testing.assert_allclose(s, y64.sum(0), rtol=1e-5)
    np.testing.assert_allclose(q, (y64 ** 2).sum(0), rtol=1e-5)

    def loss(bias, scale):
        u = (y.astype(jnp.float32) - mean) * rstd
        return jnp.sum(dz.astype(jnp.float32) * jax.nn.elu(u * scale + bias))

    d_bias, d_scale = jax.grad(loss, argnums=(0, 1))(bias, scale)
    a, b = bn.xla_backward_sums(dz, y, mean, rstd * scale, bias, rstd)
    np.testing.assert_allclose(a, d_bias, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(b, d_scale, rtol=1e-5, atol=1e-4)


def test_the_pallas_kernels_give_xlas_sums():
    y, dz, mean, rstd, scale, bias = _inputs()
    channels = (mean, rstd * scale, bias, rstd)
    for rows in (64, 128):
        for got, want in zip(bn.pallas_stats(y, rows, interpret=True), bn.xla_stats(y),
                             strict=True):
            np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-3)
        for got, want in zip(bn.pallas_backward_sums(dz, y, *channels, rows, interpret=True),
                             bn.xla_backward_sums(dz, y, *channels), strict=True):
            np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-3)
