"""Conv stacks: the sub-pixel transposed convolution against a loop of PyTorch's formula."""

import jax
import jax.numpy as jnp
import numpy as np

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
