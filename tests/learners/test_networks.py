"""Conv stacks: the sub-pixel transposed convolution against a loop of PyTorch's formula."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml import learners
from jaml.learners.networks import ConvDecoder, ConvEncoder, upsample2x


def test_upsample2x_is_pytorch_conv_transpose_k4_s2_p1():
    rng = np.random.default_rng(0)
    x, w = rng.normal(size=(2, 3, 4, 5)), rng.normal(size=(4, 4, 5, 6))
    # ConvTranspose2d: out[s·i − p + k] += x[i]·w[k] per axis, s = 2, p = 1.
    full = np.zeros((2, 2 * 3 + 2, 2 * 4 + 2, 6))
    for i in range(3):
        for j in range(4):
            for kh in range(4):
                for kw in range(4):
                    full[:, 2 * i + kh, 2 * j + kw] += x[:, i, j] @ w[kh, kw]
    got = upsample2x(jnp.asarray(x, jnp.float32), jnp.asarray(w, jnp.float32))
    assert got.shape == (2, 6, 8, 6)
    np.testing.assert_allclose(got, full[:, 1:-1, 1:-1], atol=1e-5)


def test_stacks_map_64x64_frames_to_features_and_back():
    x, z = jnp.zeros((3, 64, 64, 3)), jnp.zeros((3, 5))
    enc, dec = ConvEncoder((4, 4, 4, 4), 6), ConvDecoder((4, 4, 4, 4))
    assert jax.eval_shape(lambda: enc.init_with_output(jax.random.key(0), x, True)[0]).shape \
        == (3, 6)
    assert jax.eval_shape(lambda: dec.init_with_output(jax.random.key(0), z, True)[0]).shape \
        == (3, 64, 64, 3)


def test_bfloat16_convolutions_keep_float32_parameters_and_outputs():
    """Mixed precision: the convolutions compute in bfloat16 (8 mantissa bits), everything the
    optimizer and the loss see stays float32, and the result tracks the float32 stack."""
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.uniform(size=(4, 64, 64, 3)), jnp.float32)
    z = jnp.asarray(rng.normal(size=(4, 5)), jnp.float32)
    for f32, bf16, inp in ((ConvEncoder((4, 4, 4, 4), 6), ConvEncoder((4, 4, 4, 4), 6,
                                                                       jnp.bfloat16), x),
                           (ConvDecoder((4, 4, 4, 4)), ConvDecoder((4, 4, 4, 4),
                                                                   compute_dtype=jnp.bfloat16), z)):
        variables = f32.init(jax.random.key(0), inp, True)
        assert jax.tree.leaves(jax.tree.map(lambda a: a.dtype, bf16.init(
            jax.random.key(0), inp, True))) == [jnp.float32] * len(jax.tree.leaves(variables))
        want, _ = f32.apply(variables, inp, True, mutable=["batch_stats"])
        got, _ = bf16.apply(variables, inp, True, mutable=["batch_stats"])
        assert got.dtype == jnp.float32
        # Batch-normalised features of unit scale: bfloat16 rounding (2^-8 relative) of the
        # inputs and kernels moves them by a few hundredths at most.
        np.testing.assert_allclose(got, want, atol=0.05)
        assert 0 < float(jnp.mean(jnp.abs(got - want))) < 0.01, "bfloat16 must be used"


def test_compute_dtype_is_checked_and_reaches_the_learner():
    with pytest.raises(ValueError, match=r"compute_dtype must be one of \['float32', 'bfloat16'\]"):
        learners.make("VAE_rpl", ld_dim=4, compute_dtype="float16")
    assert learners.make("PRED", ld_dim=4, compute_dtype="bfloat16").config.conv_dtype \
        == jnp.bfloat16
