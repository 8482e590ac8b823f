"""The Pallas k4 s2 p1 convolution with batch-norm statistics in its epilogue, run in Pallas's
interpreter on the CPU, against `lax.conv_general_dilated` and float32 sums."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from benchmarks.conv_bn_kernel import halving_conv_stats


# (x shape, output channels, (block_m, block_o, block_k), taps per load): a tile of two frames
# with two channel tiles and two chunks per load; a tile of a quarter frame (2 of its 8 rows).
@pytest.mark.parametrize("x_shape, o, blocks, span", [
    ((2, 8, 8, 32), 32, (32, 16, 16), 1), ((1, 16, 16, 16), 32, (16, 32, 16), 1),
    ((2, 8, 8, 32), 32, (32, 16, 32), 2), ((1, 16, 16, 16), 32, (16, 32, 32), 2)])
def test_halving_conv_stats_is_lax_conv_and_its_sums(x_shape, o, blocks, span):
    rng = np.random.default_rng(sum(x_shape) + o)
    c = x_shape[-1]
    x = jnp.asarray(rng.normal(size=x_shape), jnp.bfloat16)
    w = jnp.asarray(rng.normal(size=(4, 4, c, o)) / np.sqrt(16 * c), jnp.bfloat16)
    bm, bo, bk = blocks
    y, s, q = halving_conv_stats(x, w, block_m=bm, block_o=bo, block_k=bk, span=span,
                                 interpret=True)
    # bfloat16 operands, float32 accumulation: the reference's products are exact and only the
    # order of the float32 sums differs.
    ref = jax.lax.conv_general_dilated(x, w, (2, 2), ((1, 1), (1, 1)),
                                       dimension_numbers=("NHWC", "HWIO", "NHWC"),
                                       preferred_element_type=jnp.float32)
    ref, y = np.asarray(ref), np.asarray(y.astype(jnp.float32))
    assert y.shape == ref.shape and s.shape == q.shape == (o,)
    # The output is the accumulator rounded to bfloat16: within half its ulp (2⁻⁹ relative),
    # plus the float32 sums' order.
    np.testing.assert_allclose(y, ref, rtol=2.0**-8, atol=1e-5)
    # The statistics are the float32 accumulator's, not the rounded output's: float32 sums in
    # another order, within 1e-5 of the sums of magnitudes.
    flat = ref.reshape(-1, o)
    assert np.all(np.abs(np.asarray(s) - flat.sum(0)) <= 1e-5 * np.abs(flat).sum(0) + 1e-6)
    assert np.all(np.abs(np.asarray(q) - (flat * flat).sum(0)) <= 1e-5 * (flat * flat).sum(0))
