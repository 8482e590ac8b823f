"""The PyTorch peer of VAE_rpl, PRED and DSA (benchmarks/peers/torch_learners.py): jaml's
parameter counts and FLOPs, and its compiled train step against its eager one.

Marked slow (torch is no dependency of the default suite: `make test-slow`, with torch installed
from the `bench` extra or a CPU build); each test skips with the reason when torch is absent.
"""

import jax
import numpy as np
import pytest

from benchmarks import flops
from jaml import learners
from jaml.learners import networks

pytestmark = pytest.mark.slow
NAMES = ("VAE_rpl", "PRED", "DSA")
LD_DIM, ACTION_DIM = 4, 1  # benchmarks/learner_throughput.py's CartPole sizes


def _peer():
    pytest.importorskip("torch", reason="torch is not installed (the bench extra)")
    from benchmarks.peers import torch_learners

    return torch_learners


def _jaml(name, batch=2):
    learner = learners.make(name, ld_dim=LD_DIM)
    t = learner.config.seq_len
    frames = np.zeros((batch, t, 64, 64, 3), np.uint8)
    actions = np.zeros((batch, t, ACTION_DIM), np.float32)
    return learner, learner.init(jax.random.key(0), frames, actions), frames, actions


def _lax_upsample2x(x, kernel, compute_dtype=None, form=None):
    """ConvTranspose2d(4, 2, 1) as the plain input-dilated convolution (tests/learners'
    reference): the formulation whose count is the model's, not a backend's."""
    return jax.lax.conv_transpose(x, kernel[::-1, ::-1], (2, 2), ((2, 2), (2, 2)),
                                  dimension_numbers=("NHWC", "HWIO", "NHWC"))


@pytest.mark.parametrize("name", NAMES)
def test_trainable_parameter_counts_equal_jamls(name):
    tl = _peer()
    _, variables, _, _ = _jaml(name)
    want = sum(x.size for x in jax.tree.leaves(variables["params"]))
    model = tl.build(name, LD_DIM, ACTION_DIM)
    assert sum(p.numel() for p in tl.trainable_parameters(model)) == want
    # What is frozen is exactly the LSTMs' and RNN's second bias, at zero.
    frozen = [(n, p) for n, p in model.named_parameters() if not p.requires_grad]
    assert all(".bias_hh_" in n and not p.any() for n, p in frozen)
    assert (len(frozen) > 0) == (name == "DSA")


@pytest.mark.parametrize("name", NAMES)
def test_forward_and_step_flops_equal_jamls_count_of_the_same_network(name, monkeypatch):
    """benchmarks/flops.py on jaml's loss, its convolutions traced in their plain formulation
    (padding, cropped outputs and inserted zeros are no work), against FlopCounterMode on the
    peer with the same convolution count: the forward pass exactly; the gradient within 0.1 %
    (JAX's scan also differentiates each LSTM's first step through its zero initial state,
    autograd does not; 0 for VAE_rpl and PRED, which have no RNN)."""
    tl = _peer()
    batch = 2
    learner, variables, frames, actions = _jaml(name, batch)
    monkeypatch.setattr(networks, "_use_cpu_kernels", lambda cpu_kernels: False)
    monkeypatch.setattr(networks, "upsample2x", _lax_upsample2x)

    def loss(v):
        return learner.loss(v, jax.random.key(1), frames, actions)[0]

    forward = flops.flops(loss, variables)
    step = flops.flops(jax.grad(loss), variables)
    ours = tl.useful_flops(name, batch, backward=False, ld_dim=LD_DIM, action_dim=ACTION_DIM)
    assert sum(ours.values()) == forward
    ours = tl.useful_flops(name, batch, backward=True, ld_dim=LD_DIM, action_dim=ACTION_DIM)
    assert sum(ours.values()) == pytest.approx(step, rel=1e-3 if name == "DSA" else 0)


def _step_losses(tl, peer, steps, seed=0):
    import torch

    rng = np.random.default_rng(seed)
    t = tl.seq_len(peer.name, LD_DIM)
    frames = rng.integers(0, 256, (2, t, 64, 64, 3), dtype=np.uint8)
    actions = rng.normal(size=(2, t, ACTION_DIM)).astype(np.float32)
    batch = peer.batch(frames, actions)
    losses = []
    with peer.host_context():
        for i in range(steps):
            torch.manual_seed(100 + i)  # the same noise for both peers, step by step
            losses.append(float(peer.step(*batch)))
    return losses


def test_compiled_step_equals_the_eager_step_and_learns():
    """VAE_rpl at batch 2 on the CPU: the whole train step under torch.compile (channels_last)
    gives the eager step's losses (Inductor drawing its random numbers as eager does), and
    the loss falls over a few Adam steps."""
    tl = _peer()
    import torch
    from torch._inductor import config as inductor

    torch._dynamo.reset()
    eager = tl.Peer("VAE_rpl", tl.Variant(), ld_dim=LD_DIM, action_dim=ACTION_DIM)
    compiled = tl.Peer("VAE_rpl", tl.Variant("default", channels_last=True), ld_dim=LD_DIM,
                       action_dim=ACTION_DIM)
    compiled.model.load_state_dict(eager.model.state_dict())
    want = _step_losses(tl, eager, 4)
    with inductor.patch(fallback_random=True):
        got = _step_losses(tl, compiled, 4)
    np.testing.assert_allclose(got, want, rtol=1e-4)
    assert got[-1] < got[0]


@pytest.mark.parametrize("name", ["PRED", "DSA"])
def test_bfloat16_autocast_step_runs_and_is_near_the_float32_loss(name):
    """The sequence learners' eager step under bf16 autocast, as the benchmark's bf16 rows run
    it: a finite loss within bf16's rounding of the float32 one on the same weights and noise."""
    tl = _peer()
    f32 = tl.Peer(name, tl.Variant(), ld_dim=LD_DIM, action_dim=ACTION_DIM)
    bf16 = tl.Peer(name, tl.Variant(dtype="bfloat16"), ld_dim=LD_DIM, action_dim=ACTION_DIM)
    bf16.model.load_state_dict(f32.model.state_dict())
    want, got = _step_losses(tl, f32, 1), _step_losses(tl, bf16, 1)
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got, want, rtol=2e-2)


def test_a_failing_peer_variant_is_an_error_row_and_the_case_goes_on(monkeypatch):
    """A compiler error in one variant (as Inductor's stride assertion on PyTorch 2.11's GPU
    backward) is reported in that variant's row, and the case's other rows are still measured."""
    tl = _peer()
    from benchmarks import learner_throughput as lt

    real = tl.Peer

    def peer(name, variant, **kwargs):
        if variant.compile_mode is not None:
            raise AssertionError("expected size 8==8, stride 16==1 at dim=1\nmore detail")
        return real(name, variant, **kwargs)

    monkeypatch.setattr(tl, "Peer", peer)
    bad = lt.bench_torch("VAE_rpl", 2, 1, 1, compile_mode="default")
    assert bad["error"] == "AssertionError: expected size 8==8, stride 16==1 at dim=1"
    assert bad["label"] == "compiled default, channels_last"
    good = lt.bench_torch("VAE_rpl", 2, 1, 1, memory_format="contiguous")
    assert good["label"] == "eager" and good["fps"] > 0
    case = lt.Case("VAE_rpl", 2, 1, "float32", 1.0, None, lt.useful_gflop_per_frame(
        "VAE_rpl", 2, "float32"), peers=[bad, good])
    case.jaml = [(("auto", "float32"), lt.bench_jax(2, 1, 1))]
    rows = case.rows()
    assert [r.get("note") for r in rows[1:]] == [bad["error"], None]
    assert rows[0]["speedup_vs_pytorch"] == rows[0]["frames_per_s"] / good["fps"]
    assert "speedup_vs_pytorch_compiled" not in rows[0]
