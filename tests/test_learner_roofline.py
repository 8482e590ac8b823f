"""benchmarks/learner_roofline.py: a convolution's and a dense layer's FLOPs and bytes by hand,
the layers' sum against XLA's CPU cost analysis of the compiled step, and name stacks read as
layers."""

import jax
import pytest

from benchmarks import learner_roofline as lr
from benchmarks.learner_throughput import jaml_step

N = 2  # frames a step: VAE_rpl, float32, as it runs on the CPU


@pytest.fixture(scope="module")
def vae_layers():
    return {layer.name: layer for layer in lr.layers(lr.step_jaxpr("VAE_rpl", N, "float32",
                                                                   "float32"))}


def test_name_stacks_are_read_as_layers_forward_and_backward():
    assert lr.layer_of("/jvp(FeedForwardVAE)/FeedForwardVAE.posterior/conv/conv0/") == (
        "conv/conv0", False)
    assert lr.layer_of("/transpose(jvp(FeedForwardVAE))/FeedForwardVAE.decode/decoder/"
                       "deconv3/transpose()") == ("decoder/deconv3", True)
    # A scanned cell is one layer over its steps, its inner dense layers included.
    assert lr.layer_of("/transpose(jvp(DSA))/DSA.dynamic_posterior/dynamic_rnn/rnn/"
                       "SimpleCell_0.scan_fn/SimpleCell_0/i") == ("dynamic_rnn/rnn/SimpleCell_0",
                                                                  True)
    assert lr.layer_of("/jvp(FeedForwardVAE)") == (lr.OUTSIDE, False)


def test_a_convolution_by_hand(vae_layers):
    conv1 = vae_layers["conv/conv1"]  # k4 s2 p1, 32×32×64 → 16×16×128
    # Per axis, 16 outputs × 4 taps less the 2 that land on padding: 62 taps.
    assert conv1.fwd_flops == 2 * N * 128 * 64 * 62 * 62
    assert conv1.bwd_flops == 2 * conv1.fwd_flops  # input and kernel gradients
    assert conv1.in_bytes == 4 * N * 32 * 32 * 64
    assert conv1.weight_bytes == 4 * 4 * 4 * 64 * 128
    assert conv1.out_bytes == 4 * N * 16 * 16 * 128
    assert conv1.writes_input_grad
    # The first convolution reads the frames: its backward computes no input gradient.
    assert not vae_layers["conv/conv0"].writes_input_grad


def test_a_dense_layer_by_hand(vae_layers):
    dense = vae_layers["trunk/dense1"]  # 1024 → 512
    assert dense.fwd_flops == 2 * N * 1024 * 512
    assert dense.bwd_flops == 2 * dense.fwd_flops
    assert (dense.in_bytes, dense.weight_bytes, dense.out_bytes) == (
        4 * N * 1024, 4 * 1024 * 512, 4 * N * 512)
    assert dense.fwd_bytes == 4 * (N * 1024 + 1024 * 512 + N * 512)
    assert dense.bwd_bytes == 4 * (2 * N * 512 + 2 * N * 1024 + 2 * 1024 * 512)


def test_the_layers_sum_to_xla_s_cpu_count_less_its_elementwise_work(vae_layers):
    if jax.default_backend() != "cpu":
        pytest.skip("XLA's GPU cost analysis counts no cuDNN convolution")
    step, state, batch = jaml_step("VAE_rpl", N)
    cost = step.lower(state, batch, jax.random.key(0)).compile().cost_analysis()
    xla = (cost[0] if isinstance(cost, list) else cost)["flops"]
    counted = sum(layer.fwd_flops + layer.bwd_flops for layer in vae_layers.values())
    # XLA also counts the elementwise work (batch norms, ELUs, loss, Adam): a few percent here.
    assert 0.9 * xla <= counted <= xla
