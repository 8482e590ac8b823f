"""jaml's BatchNorm against Flax's nn.BatchNorm: the same variables, forward and running averages
bit for bit, and the hand-written backward pass against Flax's autodiff."""

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml.learners.batch_norm import BatchNorm

_ARGS = {"momentum": 0.9, "epsilon": 1e-5}


def _pair(train: bool, dtype):
    return (BatchNorm(use_running_average=not train, dtype=dtype, **_ARGS),
            nn.BatchNorm(use_running_average=not train, dtype=dtype, **_ARGS))


def _x(dtype, shape=(6, 5, 4, 7)):
    # An offset and spread per channel, and one constant channel (variance rounding to ~0).
    x = (jax.random.normal(jax.random.key(0), shape) * jnp.arange(1, shape[-1] + 1)
         + jnp.linspace(-3, 3, shape[-1]))
    return x.at[..., 0].set(0.7).astype(dtype)


@pytest.mark.parametrize("in_dtype, out_dtype", [(jnp.float32, None), (jnp.bfloat16, jnp.bfloat16),
                                                 (jnp.bfloat16, jnp.float32)])
def test_variables_forward_and_running_averages_are_flaxs(in_dtype, out_dtype):
    x = _x(in_dtype)
    ours, flax = _pair(True, out_dtype)
    variables = flax.init(jax.random.key(1), x)
    assert jax.tree.structure(ours.init(jax.random.key(1), x)) == jax.tree.structure(variables)
    # Parameters away from their initial values, so that scale and bias take part.
    params = {"scale": jnp.linspace(0.5, 2.0, 7), "bias": jnp.linspace(-1.0, 1.0, 7)}
    variables = {**variables, "params": params}
    (y, new), (y_flax, new_flax) = (m.apply(variables, x, mutable=["batch_stats"])
                                    for m in (ours, flax))
    assert y.dtype == y_flax.dtype
    np.testing.assert_array_equal(np.asarray(y, np.float32), np.asarray(y_flax, np.float32))
    for a, b in zip(jax.tree.leaves(new), jax.tree.leaves(new_flax), strict=True):
        np.testing.assert_array_equal(a, b)
    # Evaluation reads the running averages.
    evaluating, evaluating_flax = _pair(False, out_dtype)
    variables = {**variables, **new}
    np.testing.assert_array_equal(
        np.asarray(evaluating.apply(variables, x), np.float32),
        np.asarray(evaluating_flax.apply(variables, x), np.float32))


@pytest.mark.parametrize("dtype, tol", [(jnp.float32, 2e-5), (jnp.bfloat16, 1e-2)])
def test_the_backward_pass_is_flaxs_autodiff(dtype, tol):
    """Gradients of x, scale and bias through a nonlinear loss against Flax's autodiff: equal to
    float32 rounding, and in bfloat16 to the rounding of the bfloat16 input gradient."""
    x = _x(dtype)
    ours, flax = _pair(True, dtype)
    variables = flax.init(jax.random.key(1), x)
    params = {"scale": jnp.linspace(0.5, 2.0, 7), "bias": jnp.linspace(-1.0, 1.0, 7)}

    def loss(module, params, x):
        y, _ = module.apply({**variables, "params": params}, x, mutable=["batch_stats"])
        return jnp.sum(jnp.sin(3 * y.astype(jnp.float32)) * jnp.arange(y.size).reshape(y.shape)
                       / y.size)

    (gp, gx), (gp_flax, gx_flax) = (jax.grad(loss, argnums=(1, 2))(m, params, x)
                                    for m in (ours, flax))
    assert gx.dtype == gx_flax.dtype == dtype
    scale = float(jnp.max(jnp.abs(gx_flax.astype(jnp.float32))))
    np.testing.assert_allclose(np.asarray(gx, np.float32), np.asarray(gx_flax, np.float32),
                               rtol=tol, atol=tol * scale)
    for name in ("scale", "bias"):
        np.testing.assert_allclose(gp[name], gp_flax[name], rtol=tol,
                                   atol=tol * float(jnp.max(jnp.abs(gp_flax[name]))))
    # The constant channel: its normalised values are 0, so only the mean's gradient moves it.
    np.testing.assert_allclose(np.asarray(gx[..., 0], np.float32),
                               np.asarray(gx_flax[..., 0], np.float32), rtol=tol, atol=tol * scale)


def _exact_backward(x: np.ndarray, g: np.ndarray, scale: np.ndarray, eps: float):
    """The batch norm's gradients (x, scale, bias) in float64 with NumPy, from the textbook
    closed form: the reference both backward passes are held to."""
    x = x.astype(np.float64).reshape(-1, x.shape[-1])
    g = g.astype(np.float64).reshape(x.shape)
    n = x.shape[0]
    xhat = (x - x.mean(0)) / np.sqrt(x.var(0) + eps)
    dbias, dscale = g.sum(0), (g * xhat).sum(0)
    return scale * (g - dbias / n - xhat * dscale / n) / np.sqrt(x.var(0) + eps), dscale, dbias


def test_the_bfloat16_backward_is_no_further_from_float64_than_autodiffs():
    """In bfloat16 the written-out backward is as close to the float64 gradients as Flax's
    autodiff or closer: its rounding differs, and the difference is not a loss of accuracy (a
    training run with it cannot be explained by a less accurate gradient)."""
    rng = np.random.default_rng(0)
    shape = (16, 8, 8, 32)
    x = jnp.asarray(rng.normal(1.0, 2.0, size=shape), jnp.bfloat16)
    g = jnp.asarray(rng.normal(size=shape), jnp.bfloat16)
    scale = np.linspace(0.5, 2.0, shape[-1])
    exact = _exact_backward(np.asarray(x, np.float32), np.asarray(g, np.float32), scale,
                            _ARGS["epsilon"])
    errors = []
    for module in _pair(True, jnp.bfloat16):
        variables = module.init(jax.random.key(1), x)
        params = {"scale": jnp.asarray(scale, jnp.float32),
                  "bias": jnp.zeros(shape[-1], jnp.float32)}

        def loss(params, x, module=module, variables=variables):
            y, _ = module.apply({**variables, "params": params}, x, mutable=["batch_stats"])
            return jnp.sum(y.astype(jnp.float32) * g.astype(jnp.float32))

        gp, gx = jax.grad(loss, argnums=(0, 1))(params, x)
        got = (np.asarray(gx, np.float64).reshape(exact[0].shape), np.asarray(gp["scale"]),
               np.asarray(gp["bias"]))
        errors.append([np.linalg.norm((a - b).ravel()) / np.linalg.norm(b.ravel())
                       for a, b in zip(got, exact, strict=True)])
    (dx, dscale, dbias), (dx_flax, dscale_flax, dbias_flax) = errors
    # bfloat16 keeps 8 bits: rounding the gradient alone leaves ~1e-3 relative.
    assert dx <= dx_flax and dx < 2.5e-3, errors
    # The parameters' sums are float32: both within float32 rounding of the exact sums.
    assert max(dscale, dbias, dscale_flax, dbias_flax) < 1e-5, errors
