"""benchmarks/flops.py: the useful-FLOP count against hand-computed values and XLA's CPU count."""

import jax
import jax.numpy as jnp
import pytest

from benchmarks import flops

DIMS = ("NHWC", "HWIO", "NHWC")


def _xla_cpu_flops(fn, *args) -> float:
    cost = jax.jit(fn).lower(*args).compile().cost_analysis()
    return (cost[0] if isinstance(cost, list) else cost)["flops"]


def test_a_valid_convolution_and_a_matmul_by_hand():
    x, w = jnp.zeros((2, 8, 8, 3)), jnp.zeros((3, 3, 3, 5))
    conv = lambda x, w: jax.lax.conv_general_dilated(x, w, (1, 1), "VALID", dimension_numbers=DIMS)  # noqa: E731
    assert flops.flops(conv, x, w) == 2 * 2 * 6 * 6 * 5 * 3 * 9  # batch·out pixels·C_out·C_in·taps
    assert flops.flops(jnp.matmul, jnp.zeros((4, 7, 3)), jnp.zeros((3, 6))) == 2 * 4 * 7 * 6 * 3


@pytest.mark.parametrize("padding, stride, lhs_dilation", [
    ("SAME", (1, 1), None),              # taps on the zero border are not counted
    ("SAME", (2, 2), None),
    (((1, 2), (1, 2)), (1, 1), (2, 2)),  # a transposed convolution: inserted zeros not counted
])
def test_padding_strides_and_input_dilation_count_as_xla_cpu_counts(padding, stride,
                                                                      lhs_dilation):
    x, w = jnp.zeros((2, 8, 8, 3)), jnp.zeros((3, 3, 3, 5))

    def conv(x, w):
        return jax.lax.conv_general_dilated(x, w, stride, padding, lhs_dilation=lhs_dilation,
                                            dimension_numbers=DIMS)

    assert flops.flops(conv, x, w) == _xla_cpu_flops(conv, x, w)


def test_a_scan_body_counts_once_per_step_and_a_gradient_counts_its_convolutions():
    w = jnp.zeros((5, 5))
    body = lambda h, _: (h @ w, None)  # noqa: E731
    assert flops.flops(lambda h: jax.lax.scan(body, h, None, length=7)[0],
                       jnp.zeros((2, 5))) == 7 * 2 * 2 * 5 * 5

    def loss(w, x):
        return jnp.sum(jax.lax.conv_general_dilated(x, w, (2, 2), "SAME",
                                                    dimension_numbers=DIMS) ** 2)

    x, w4 = jnp.zeros((2, 16, 16, 3)), jnp.zeros((4, 4, 3, 8))
    forward = flops.flops(loss, w4, x)
    both = flops.flops(jax.grad(loss, argnums=(0, 1)), w4, x)
    assert both == pytest.approx(3 * forward)  # input and weight gradients: one forward each
