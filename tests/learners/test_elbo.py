"""ELBO pieces against numpy closed forms, Monte-Carlo estimates and hand-computed values."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml.learners import elbo


def _np_log_normal(z, mu, logvar):
    return -0.5 * (np.log(2 * np.pi) + logvar + (z - mu) ** 2 / np.exp(logvar))


def test_standard_kl_matches_numpy_closed_form():
    rng = np.random.default_rng(0)
    mu, logvar = rng.normal(size=(4, 3, 5)), rng.uniform(-3, 3, size=(4, 3, 5))
    sigma2 = np.exp(logvar)
    expected = np.sum(0.5 * (sigma2 + mu**2 - 1.0) - 0.5 * np.log(sigma2), axis=-1)
    got = elbo.kl_to_standard_normal(jnp.asarray(mu), jnp.asarray(logvar))
    assert got.shape == (4, 3)
    np.testing.assert_allclose(got, expected, rtol=1e-5)
    # KL(q‖q) = 0 and KL grows with |μ|.
    assert float(elbo.kl_to_standard_normal(jnp.zeros(5), jnp.zeros(5))) == 0.0


@pytest.mark.parametrize("prior", ["standard", "learned"])
def test_kl_matches_monte_carlo_estimate(prior):
    rng = np.random.default_rng(1)
    mu_q, logvar_q = np.array([0.7, -1.2, 0.1]), np.array([-0.5, 0.3, -1.5])
    if prior == "standard":
        mu_p, logvar_p = np.zeros(3), np.zeros(3)
        closed = float(elbo.kl_to_standard_normal(jnp.asarray(mu_q), jnp.asarray(logvar_q)))
    else:
        mu_p, logvar_p = np.array([0.2, 0.4, -0.3]), np.array([0.5, -0.2, 0.1])
        closed = float(elbo.gaussian_kl(*map(jnp.asarray, (mu_q, logvar_q, mu_p, logvar_p))))
    z = mu_q + np.exp(0.5 * logvar_q) * rng.normal(size=(200_000, 3))
    log_ratio = (_np_log_normal(z, mu_q, logvar_q) - _np_log_normal(z, mu_p, logvar_p)).sum(-1)
    stderr = log_ratio.std() / np.sqrt(len(log_ratio))
    assert abs(log_ratio.mean() - closed) < 4 * stderr, (log_ratio.mean(), closed, stderr)


def test_general_kl_reduces_to_standard_and_is_asymmetric():
    mu, logvar = jnp.array([[0.3, -0.4]]), jnp.array([[0.2, -1.0]])
    zeros = jnp.zeros_like(mu)
    np.testing.assert_allclose(elbo.gaussian_kl(mu, logvar, zeros, zeros),
                               elbo.kl_to_standard_normal(mu, logvar), rtol=1e-6)
    assert not np.isclose(elbo.gaussian_kl(mu, logvar, zeros, zeros),
                          elbo.gaussian_kl(zeros, zeros, mu, logvar))


def test_reparameterized_samples_have_the_posterior_moments():
    mu, logvar = jnp.array([1.5, -2.0]), jnp.array([0.0, np.log(0.25)])
    z = elbo.reparameterize(jax.random.key(0), jnp.broadcast_to(mu, (50_000, 2)),
                            jnp.broadcast_to(logvar, (50_000, 2)))
    np.testing.assert_allclose(z.mean(0), mu, atol=0.02)
    np.testing.assert_allclose(z.std(0), [1.0, 0.5], rtol=0.02)


def test_loglik_is_minus_half_squared_error_per_frame():
    x = jnp.zeros((2, 3, 4, 4, 3))
    x_hat = x.at[0, 1, 0, 0, 0].set(0.5).at[1, 2].set(1.0)
    got = elbo.gaussian_loglik(x, x_hat)
    expected = np.zeros((2, 3))
    expected[0, 1] = -0.5 * 0.25
    expected[1, 2] = -0.5 * 4 * 4 * 3
    np.testing.assert_allclose(got, expected)


def test_frames_to_float():
    frames = jnp.array([0, 51, 255], jnp.uint8)
    np.testing.assert_allclose(elbo.frames_to_float(frames), [0.0, 0.2, 1.0], rtol=1e-6)
    assert elbo.frames_to_float(jnp.array([0.5])).dtype == jnp.float32
    with pytest.raises(TypeError, match="uint8 or floating"):
        elbo.frames_to_float(jnp.array([1, 2], jnp.int32))
