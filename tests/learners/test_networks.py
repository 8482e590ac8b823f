"""Conv stacks: the transposed convolution against a loop of PyTorch's formula; the CPU formulation
(the k4 s2 p1 convolution and its transpose as each other's input gradients, the 1×1 conv as a
matmul) against XLA's convolutions and autodiff."""

import re

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax._src.ad_checkpoint import saved_residuals  # what print_saved_residuals prints

from jaml import learners, stream
from jaml.learners import networks
from jaml.learners.batch_norm import BatchNorm
from jaml.learners.networks import Conv, ConvDecoder, ConvEncoder, conv2d, elu, upsample2x


@pytest.mark.parametrize("form", ["auto", "subpixel", "phase", "dilated", "pair"])
def test_upsample2x_is_pytorch_conv_transpose_k4_s2_p1(form):
    rng = np.random.default_rng(0)
    x, w = rng.normal(size=(2, 3, 4, 5)), rng.normal(size=(4, 4, 5, 6))
    # ConvTranspose2d: out[s·i − p + k] += x[i]·w[k] per axis, s = 2, p = 1.
    full = np.zeros((2, 2 * 3 + 2, 2 * 4 + 2, 6))
    for i in range(3):
        for j in range(4):
            for kh in range(4):
                for kw in range(4):
                    full[:, 2 * i + kh, 2 * j + kw] += x[:, i, j] @ w[kh, kw]
    got = upsample2x(jnp.asarray(x, jnp.float32), jnp.asarray(w, jnp.float32), form=form)
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
        # Jitted: run eagerly, every op of init and apply compiles apart.
        init = lambda m: jax.jit(lambda k, x, m=m: m.init(k, x, True))  # noqa: E731
        apply = lambda m: jax.jit(  # noqa: E731
            lambda v, x, m=m: m.apply(v, x, True, mutable=["batch_stats"])[0])
        variables = init(f32)(jax.random.key(0), inp)
        assert jax.tree.leaves(jax.tree.map(lambda a: a.dtype, init(bf16)(
            jax.random.key(0), inp))) == [jnp.float32] * len(jax.tree.leaves(variables))
        want, got = apply(f32)(variables, inp), apply(bf16)(variables, inp)
        assert got.dtype == jnp.float32
        # Batch-normalised features of unit scale: bfloat16 rounding (2^-8 relative) of the
        # inputs and kernels moves them by a few hundredths at most.
        np.testing.assert_allclose(got, want, atol=0.05)
        assert 0 < float(jnp.mean(jnp.abs(got - want))) < 0.01, "bfloat16 must be used"


def test_bfloat16_activations_are_the_batch_norm_and_elu_outputs_and_track_float32():
    """activation_dtype: every batch norm's output (and so each ELU's) is bfloat16, its
    statistics float32; the encoder's feature and the decoder's frames stay float32."""
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.uniform(size=(4, 64, 64, 3)), jnp.float32)
    z = jnp.asarray(rng.normal(size=(4, 5)), jnp.float32)
    bf = jnp.bfloat16
    for mixed, act, inp, n_norms in (
            (ConvEncoder((4, 4, 4, 4), 6, bf), ConvEncoder((4, 4, 4, 4), 6, bf,
                                                           activation_dtype=bf), x, 5),
            (ConvDecoder((4, 4, 4, 4), compute_dtype=bf),
             ConvDecoder((4, 4, 4, 4), compute_dtype=bf, activation_dtype=bf), z, 3)):
        variables = jax.jit(lambda k, x, m=mixed: m.init(k, x, True))(jax.random.key(0), inp)

        def apply(m, v, x):
            return m.apply(v, x, True, mutable=["batch_stats"],
                           capture_intermediates=lambda mdl, _: isinstance(mdl, BatchNorm))
        want, _ = jax.jit(lambda v, x, m=mixed: apply(m, v, x))(variables, inp)
        got, state = jax.jit(lambda v, x, m=act: apply(m, v, x))(variables, inp)
        norms = jax.tree.leaves(state["intermediates"])
        assert len(norms) == n_norms and {n.dtype for n in norms} == {jnp.dtype(bf)}
        assert {a.dtype for a in jax.tree.leaves(state["batch_stats"])} == {jnp.dtype("float32")}
        assert got.dtype == want.dtype == jnp.float32
        np.testing.assert_allclose(got, want, atol=0.05)
        assert 0 < float(jnp.mean(jnp.abs(got - want))) < 0.01


def test_compute_dtype_is_checked_and_reaches_the_learner():
    with pytest.raises(ValueError, match=r"compute_dtype must be one of "
                                         r"\['auto', 'float32', 'bfloat16'\], got 'float16'"):
        learners.make("VAE_rpl", ld_dim=4, compute_dtype="float16")
    with pytest.raises(ValueError, match=r"activation_dtype must be one of"):
        learners.make("PRED", ld_dim=4, activation_dtype="half")
    assert learners.make("PRED", ld_dim=4, compute_dtype="bfloat16").config.conv_dtype \
        == jnp.bfloat16


def test_auto_dtypes_are_bfloat16_off_the_cpu_and_float32_on_it():
    config = learners.make("DSA", ld_dim=4).config
    assert (config.compute_dtype, config.activation_dtype) == ("auto", "auto")
    for backend, name in (("cpu", "float32"), ("gpu", "bfloat16"), ("tpu", "bfloat16")):
        concrete = config.for_backend(backend)
        assert (concrete.compute_dtype, concrete.activation_dtype) == (name, name)
    # A given dtype is kept on every backend.
    assert config.replace(compute_dtype="float32").for_backend("gpu").compute_dtype == "float32"
    # Here, "auto" computes the backend's dtype (the CPU's float32), and a run records it.
    here = "float32" if jax.default_backend() == "cpu" else "bfloat16"
    assert config.conv_dtype == config.act_dtype == getattr(jnp, here)
    run = stream.resolve(stream.for_env("CartPole", "DSA"), 4, jax.default_backend())
    assert run.learner_config.compute_dtype == run.learner_config.activation_dtype == here


def _value_and_grads(f, x, w):
    y, vjp = jax.vjp(f, x, w)
    return (y, *vjp(jnp.asarray(np.random.default_rng(1).normal(size=y.shape), y.dtype)))


@pytest.mark.parametrize("shape, k, strides, padding", [
    ((3, 8, 6, 5), 4, (2, 2), ((1, 1), (1, 1))),  # the encoder's k4 s2 p1 (even sizes: CPU form)
    ((3, 8, 6, 3), 4, (2, 2), ((1, 1), (1, 1))),  # ... on few channels (the frames')
    ((2, 4, 4, 5), 4, (1, 1), ((0, 0), (0, 0))),  # its k4 s1 p0 onto 1×1 (CPU: a matmul)
    ((3, 8, 7, 5), 4, (2, 2), ((1, 1), (1, 1))),  # k4 s2 p1 on an odd width: XLA's own
    ((3, 8, 7, 5), 3, (2, 1), ((0, 1), (2, 0))),  # uneven strides and paddings
])
@pytest.mark.parametrize("cpu_kernels", [True, False])  # False: the GPU's (3 channels padded)
def test_conv2d_matches_xla_conv_and_autodiff(shape, k, strides, padding, cpu_kernels):
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.normal(size=shape), jnp.float32)
    w = jnp.asarray(rng.normal(size=(k, k, shape[-1], 6)), jnp.float32)

    def ref(x, w):
        return jax.lax.conv_general_dilated(x, w, strides, padding,
                                            dimension_numbers=("NHWC", "HWIO", "NHWC"))

    want = _value_and_grads(ref, x, w)
    got = jax.jit(lambda x, w: _value_and_grads(
        lambda x, w: conv2d(x, w, strides, padding, cpu_kernels=cpu_kernels), x, w))(x, w)
    for g, r, what in zip(got, want, ("output", "input gradient", "kernel gradient"),
                          strict=True):
        assert g.shape == r.shape and g.dtype == r.dtype, what
        np.testing.assert_allclose(g, r, rtol=1e-5, atol=1e-4, err_msg=what)


@pytest.mark.parametrize("shape, out", [((2, 4, 3, 5), 6), ((3, 2, 6, 5), 6), ((2, 4, 3, 5), 3)])
def test_upsample2x_phase_matches_lax_conv_transpose_and_the_subpixel_form(shape, out):
    """Values and both gradients of the phase pair (the default form), and of its backward
    under the input-dilated forward ("pair"): against
    `lax.conv_transpose` (ConvTranspose2d(4, 2, 1) is its input-dilated convolution with the
    spatially flipped kernel, padded by k − 1 − p = 2) and its autodiff, and against the
    sub-pixel form; per-phase convolutions (6 outputs) and the four phases in one (3, the
    frames')."""
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.normal(size=shape), jnp.float32)
    w = jnp.asarray(rng.normal(size=(4, 4, 5, out)), jnp.float32)

    def lax_ref(x, w):
        return jax.lax.conv_transpose(x, w[::-1, ::-1], (2, 2), ((2, 2), (2, 2)),
                                      dimension_numbers=("NHWC", "HWIO", "NHWC"))

    for form in ("phase", "pair", "dilated"):
        got = jax.jit(lambda x, w, form=form: _value_and_grads(
            lambda x, w: upsample2x(x, w, form=form), x, w))(x, w)
        for ref in (lax_ref, lambda x, w: upsample2x(x, w, form="subpixel")):
            want = _value_and_grads(ref, x, w)
            for g, r, what in zip(got, want, ("output", "input gradient", "kernel gradient"),
                                  strict=True):
                assert g.shape == r.shape and g.dtype == r.dtype, what
                np.testing.assert_allclose(g, r, rtol=1e-5, atol=1e-4, err_msg=f"{form} {what}")


def test_the_gpu_forms_of_the_frames_layers_match_lax_and_autodiff(monkeypatch):
    """Off the CPU the frames' two layers are reformulated onto channel counts cuDNN takes as
    they are: the encoder's k4 s2 p1 on 3 channels as a k2 convolution of 2×2 blocks, the
    decoder's transposed convolution onto 3 as the phase form with its outputs padded to 16 (its
    backward through the blocks form). Traced as for a GPU, here on the CPU: values and both
    gradients against `lax` and its autodiff."""
    monkeypatch.setattr(networks, "_on_cpu", lambda: False)
    rng = np.random.default_rng(0)
    nhwc = ("NHWC", "HWIO", "NHWC")
    cases = [
        ((2, 8, 6, 3), (4, 4, 3, 6), lambda x, w: conv2d(x, w, (2, 2), ((1, 1), (1, 1))),
         lambda x, w: jax.lax.conv_general_dilated(x, w, (2, 2), ((1, 1), (1, 1)),
                                                   dimension_numbers=nhwc)),
        ((2, 4, 3, 5), (4, 4, 5, 3), lambda x, w: upsample2x(x, w),
         lambda x, w: jax.lax.conv_transpose(x, w[::-1, ::-1], (2, 2), ((2, 2), (2, 2)),
                                             dimension_numbers=nhwc)),
    ]
    for x_shape, w_shape, f, ref in cases:
        x = jnp.asarray(rng.normal(size=x_shape), jnp.float32)
        w = jnp.asarray(rng.normal(size=w_shape), jnp.float32)
        got = jax.jit(lambda x, w, f=f: _value_and_grads(f, x, w))(x, w)
        for g, r, what in zip(got, _value_and_grads(ref, x, w),
                              ("output", "input gradient", "kernel gradient"), strict=True):
            assert g.shape == r.shape and g.dtype == r.dtype, what
            np.testing.assert_allclose(g, r, rtol=1e-5, atol=1e-4, err_msg=what)


def test_an_unknown_upsample_form_is_refused_by_name():
    with pytest.raises(ValueError, match=r"upsample form must be one of \['auto', 'subpixel', "
                                         r"'phase', 'dilated', 'pair'\], got 'fft'"):
        upsample2x(jnp.zeros((1, 2, 2, 1)), jnp.zeros((4, 4, 1, 1)), form="fft")
    with pytest.raises(ValueError, match="upsample_form must be one of"):
        learners.make("VAE_rpl", ld_dim=2, upsample_form="fft")


def test_the_decoder_gives_one_output_and_gradient_in_every_upsample_form():
    """The form is a speed choice: one set of parameters, one output and parameter gradient."""
    z = jnp.asarray(np.random.default_rng(0).normal(size=(2, 5)), jnp.float32)
    variables = jax.jit(lambda key, z: ConvDecoder((8, 6, 6, 4)).init(key, z, True))(
        jax.random.key(0), z)

    def value_and_grad(form):
        decoder = ConvDecoder((8, 6, 6, 4), upsample_form=form)

        def f(params):
            out, _ = decoder.apply({**variables, "params": params}, z, True,
                                   mutable=["batch_stats"])
            return jnp.sum(jnp.sin(3.0 * out)), out
        return jax.jit(jax.value_and_grad(f, has_aux=True))(variables["params"])

    (_, want), want_grad = value_and_grad("dilated")
    for form in ("auto", "subpixel", "phase", "pair"):
        (_, out), grad = value_and_grad(form)
        np.testing.assert_allclose(out, want, rtol=1e-5, atol=1e-6, err_msg=form)
        for g, r in zip(jax.tree.leaves(grad), jax.tree.leaves(want_grad), strict=True):
            np.testing.assert_allclose(g, r, rtol=1e-4, atol=1e-5 * float(jnp.max(jnp.abs(r))),
                                       err_msg=form)


@pytest.mark.parametrize("gpu", [False, True])
def test_auto_is_the_phase_form_on_the_cpu_and_the_pair_for_wide_layers_elsewhere(gpu,
                                                                                 monkeypatch):
    """upsample2x's default traces the program of form="phase" on the CPU; as on a GPU
    (`_on_cpu` False), that of "pair" onto 6 channels and of "phase" onto the frames' 3."""
    if gpu:
        monkeypatch.setattr(networks, "_on_cpu", lambda: False)
    x = jnp.zeros((2, 4, 4, 5))

    def program(outputs, form):
        return str(jax.make_jaxpr(lambda x, w: upsample2x(x, w, form=form))(
            x, jnp.zeros((4, 4, 5, outputs))))

    for outputs, want, other in ((6, "pair" if gpu else "phase", "phase" if gpu else "pair"),
                                 (3, "phase", "pair")):
        assert program(outputs, "auto") == program(outputs, want), outputs
        assert program(outputs, "auto") != program(outputs, other), outputs


@pytest.mark.parametrize("name", ["VAE_rpl", "PRED", "DSA", "SVAE"])
def test_a_learners_upsample_form_reaches_every_transposed_convolution(name, monkeypatch):
    from jaml.learners import networks

    seen, real = [], networks.upsample2x

    def recording(*args, **kwargs):
        seen.append(args[3] if len(args) > 3 else kwargs.get("form"))
        return real(*args, **kwargs)

    monkeypatch.setattr(networks, "upsample2x", recording)
    learner = learners.make(name, ld_dim=2, upsample_form="dilated")
    t = learner.config.seq_len
    jax.eval_shape(lambda: learner.module_init(
        jax.random.key(0), jnp.zeros((1, t, 64, 64, 3)), jnp.zeros((1, t, 1))))
    assert seen and set(seen) == {"dilated"}


def test_cpu_formulation_second_derivatives_match_xla():
    """Each custom backward pass is built from differentiable pieces: a gradient of a gradient
    (through the k4 s2 p1 conv and its transpose) equals XLA's."""
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.normal(size=(2, 4, 4, 3)), jnp.float32)
    w1 = jnp.asarray(rng.normal(size=(4, 4, 3, 5)), jnp.float32)
    w2 = jnp.asarray(rng.normal(size=(4, 4, 5, 3)), jnp.float32)

    def grad_norm(cpu):
        def f(x, w1, w2):
            h = conv2d(x, w1, (2, 2), ((1, 1), (1, 1)), cpu_kernels=cpu)
            return jnp.sum(jnp.sin(upsample2x(h, w2, form="phase" if cpu else "dilated")))
        return lambda *a: sum(jnp.sum(g ** 2) for g in jax.grad(f, argnums=(0, 1, 2))(*a))

    want = jax.grad(grad_norm(False), argnums=(0, 1, 2))(x, w1, w2)
    got = jax.jit(jax.grad(grad_norm(True), argnums=(0, 1, 2)))(x, w1, w2)
    for g, r in zip(got, want, strict=True):  # float32 sums of thousands of terms
        np.testing.assert_allclose(g, r, rtol=1e-4, atol=1e-5 * float(jnp.max(jnp.abs(r))))


def test_conv_module_is_nn_conv_without_bias():
    x = jnp.asarray(np.random.default_rng(0).normal(size=(2, 8, 8, 3)), jnp.float32)
    ours = Conv(4, (4, 4), (2, 2), ((1, 1), (1, 1)), jnp.bfloat16, cpu_kernels=True)
    flax_conv = nn.Conv(4, (4, 4), 2, ((1, 1), (1, 1)), use_bias=False, dtype=jnp.bfloat16)
    variables = ours.init(jax.random.key(0), x)
    assert jax.tree.map(jnp.shape, variables) == jax.tree.map(
        jnp.shape, flax_conv.init(jax.random.key(0), x))
    np.testing.assert_array_equal(variables["params"]["kernel"],
                                  flax_conv.init(jax.random.key(0), x)["params"]["kernel"])
    got, want = ours.apply(variables, x), flax_conv.apply(variables, x)
    assert got.dtype == want.dtype == jnp.bfloat16
    np.testing.assert_allclose(got.astype(jnp.float32), want.astype(jnp.float32), rtol=1e-2,
                               atol=1e-2)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.bfloat16])
@pytest.mark.parametrize("stack", ["encoder", "decoder"])
def test_cpu_stacks_are_the_same_functions_of_the_same_parameters(stack, dtype):
    """Encoder and decoder (train mode, batch norms) with and without the CPU formulation (the
    decoder's: the phase pair, against the sub-pixel form and XLA's autodiff):
    one parameter tree, equal outputs and parameter gradients (float32 gradients either way;
    with bfloat16 convolutions, equal to bfloat16 rounding)."""
    rng = np.random.default_rng(0)
    if stack == "encoder":
        inp = jnp.asarray(rng.uniform(size=(2, 64, 64, 3)), jnp.float32)

        def make(c):
            return ConvEncoder((4, 4, 4, 4), 6, dtype, cpu_kernels=c)
    else:
        inp = jnp.asarray(rng.normal(size=(2, 5)), jnp.float32)

        def make(c):
            return ConvDecoder((4, 4, 4, 4), compute_dtype=dtype,
                               upsample_form="phase" if c else "subpixel")
    # One compiled init (op by op, every operation compiles alone); the other stack's tree by
    # eval_shape, which compiles nothing.
    def init(c):
        return lambda key, x: make(c).init(key, x, True)

    variables = jax.jit(init(False))(jax.random.key(0), inp)
    other = jax.eval_shape(init(True), jax.random.key(0), inp)
    assert jax.tree.structure(other) == jax.tree.structure(variables)

    def loss(params, module):
        out, _ = module.apply({**variables, "params": params}, inp, True, mutable=["batch_stats"])
        return jnp.sum(out * jnp.cos(out)), out

    (g_xla, out_xla), (g_cpu, out_cpu) = (
        jax.jit(jax.grad(loss, has_aux=True), static_argnums=1)(variables["params"], make(c))
        for c in (False, True))
    tol = 1e-4 if dtype == jnp.float32 else 0.05
    np.testing.assert_allclose(out_cpu, out_xla, rtol=tol / 10, atol=tol / 10)
    for a, b in zip(jax.tree.leaves(g_cpu), jax.tree.leaves(g_xla), strict=True):
        assert a.dtype == b.dtype == jnp.float32
        np.testing.assert_allclose(a, b, rtol=tol, atol=tol * max(1.0, float(jnp.max(jnp.abs(b)))))


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.bfloat16])
def test_elu_is_nn_elu_with_nn_elus_gradient_bit_for_bit(dtype):
    """`elu`'s value and gradient (read from its output) are `nn.elu`'s and its autodiff's."""
    x = jnp.concatenate([jnp.asarray([-30.0, -3.0, -1e-3, 0.0, 1e-3, 2.0]),
                         3 * jax.random.normal(jax.random.key(0), (4096,))]).astype(dtype)
    g = jax.random.normal(jax.random.key(1), x.shape).astype(dtype)
    np.testing.assert_array_equal(elu(x), nn.elu(x))
    ours, theirs = (jax.vjp(f, x)[1](g)[0] for f in (elu, nn.elu))
    assert ours.dtype == theirs.dtype == dtype
    np.testing.assert_array_equal(ours.astype(jnp.float32), theirs.astype(jnp.float32))


@pytest.mark.parametrize("stack", ["encoder", "decoder"])
def test_the_stacks_elus_keep_nothing_for_the_backward_beyond_their_outputs(monkeypatch, stack):
    """In the GPU formulation (the CPU's too), the bytes a stack keeps for its backward pass
    with its ELUs are what it keeps with the identity in their place, give or take one small
    output, where `nn.elu`'s autodiff keeps an activation-sized expm1 output (and masks) per
    ELU on top."""
    if stack == "encoder":
        inp = jnp.ones((2, 64, 64, 3))

        def make():
            return ConvEncoder((8, 8, 8, 8), 6, cpu_kernels=False)
    else:
        inp = jnp.ones((2, 5))

        def make():
            return ConvDecoder((8, 8, 8, 8), upsample_form="pair")

    def kept(activation):
        monkeypatch.setattr(networks, "elu", activation)
        module = make()
        variables = module.init(jax.random.key(0), inp, True)

        def out(params):
            return module.apply({**variables, "params": params}, inp, True,
                                mutable=["batch_stats"])[0]
        return sum(a.size * a.dtype.itemsize
                   for a, _ in saved_residuals(out, variables["params"]))

    ours, autodiff, identity = kept(elu), kept(nn.elu), kept(lambda v: v)
    assert autodiff - identity > 2 * 2 * 32 * 32 * 8 * 4  # nn.elu: its widest layers' expm1
    assert ours - identity < (autodiff - identity) / 8


def _ynn_convolutions(hlo: str) -> int:
    """How many convolutions in `hlo` (optimised HLO text) run inside YNNPACK fusions."""
    called = set(re.findall(r'calls=(%[\w.\-]+)[^\n]*"__ynn_fusion"', hlo))
    bodies = re.split(r"\n(?=\S)", hlo)  # one top-level computation per chunk
    return sum(body.count(" convolution(") for body in bodies
               if body.split(" ", 1)[0] in called)


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="CPU compile options")
def test_cpu_compiler_options_put_the_convolutions_on_xla_s_own_path():
    """`learners.compiler_options()` keeps the conv stacks' convolutions (forward, both gradients)
    out of YNNPACK; the compiled program computes the same values."""
    rng = np.random.default_rng(0)
    x = jnp.asarray(rng.normal(size=(4, 16, 16, 32)), jnp.float32)
    w = jnp.asarray(rng.normal(size=(4, 4, 32, 32)), jnp.float32)

    def f(x, w):
        return _value_and_grads(lambda x, w: upsample2x(conv2d(
            x, w, (2, 2), ((1, 1), (1, 1)), cpu_kernels=True), w, form="phase"), x, w)

    options = learners.compiler_options()
    assert options == learners.CPU_COMPILER_OPTIONS
    ours = jax.jit(f, compiler_options=options).lower(x, w).compile()
    assert " convolution(" in ours.as_text() and _ynn_convolutions(ours.as_text()) == 0
    # The control: with XLA's defaults the counter finds YNNPACK's convolutions in the same
    # program (a counter that matched nothing would pass the line above for any options).
    assert _ynn_convolutions(jax.jit(f).lower(x, w).compile().as_text()) > 0
    for a, b in zip(ours(x, w), jax.jit(f)(x, w), strict=True):  # another summation order
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5 * float(jnp.max(jnp.abs(b))))


def _flax_rnn_params(p: dict, name: str, gates: str) -> dict:
    """The hoisted layer's parameters laid out as Flax's cell's (one kernel per gate)."""
    split = lambda w: dict(zip(gates, jnp.split(w, len(gates), axis=-1), strict=True))  # noqa: E731
    w_in, w_rec, bias = (split(p[name][k]) for k in ("input_kernel", "recurrent_kernel", "bias"))
    return {**{f"i{g}": {"kernel": w_in[g]} for g in gates},
            **{f"h{g}": {"kernel": w_rec[g], "bias": bias[g]} for g in gates}}


@pytest.mark.parametrize("unroll", [None, 1, 5])
def test_hoisted_recurrent_layers_are_flax_s_cells_scanned(unroll):
    """`RNNEncoder` (LSTMs both ways, then a tanh RNN) and a lone `LSTM`, with the inputs'
    projection outside the scan, against Flax's `nn.RNN` of its own cells on the same
    parameters: outputs and every gradient (float32, on the CPU)."""

    class Encoder(nn.Module):
        @nn.compact
        def __call__(self, x):
            both = jnp.concatenate([networks.LSTM(6, unroll=unroll, name="forward")(x),
                                    networks.LSTM(6, True, unroll, name="backward")(x)], -1)
            return networks.TanhRNN(6, unroll, name="rnn")(both), \
                networks.LSTM(6, unroll=unroll, name="lone")(x)

    class FlaxEncoder(nn.Module):
        @nn.compact
        def __call__(self, x):
            cell = lambda name: nn.OptimizedLSTMCell(6, name=name)  # noqa: E731
            both = nn.Bidirectional(nn.RNN(cell("forward")), nn.RNN(cell("backward")))(x)
            return nn.RNN(nn.SimpleCell(6, name="rnn"))(both), nn.RNN(cell("lone"))(x)

    x = jax.random.normal(jax.random.key(0), (3, 5, 4))
    params = jax.jit(Encoder().init)(jax.random.key(1), x)["params"]
    theirs = {name: _flax_rnn_params(params, name, "ifgo")
              for name in ("forward", "backward", "lone")}
    theirs["rnn"] = {"i": {"kernel": params["rnn"]["input_kernel"],
                           "bias": params["rnn"]["bias"]},
                     "h": {"kernel": params["rnn"]["recurrent_kernel"]}}
    flax_shapes = jax.eval_shape(FlaxEncoder().init, jax.random.key(1), x)["params"]
    assert jax.tree.structure(flax_shapes) == jax.tree.structure(theirs)

    def loss(module, p, x):
        y, z = module.apply({"params": p}, x)
        return jnp.sum(jnp.sin(y)) + jnp.sum(z ** 2), (y, z)

    # Each side one compiled program (op by op, every operation of the scans compiles alone).
    (ours_v, ours_out), ours_g = jax.jit(jax.value_and_grad(
        lambda p, x: loss(Encoder(), p, x), (0, 1), has_aux=True))(params, x)
    (ref_v, ref_out), ref_g = jax.jit(jax.value_and_grad(
        lambda p, x: loss(FlaxEncoder(), p, x), (0, 1), has_aux=True))(theirs, x)
    np.testing.assert_allclose(ours_v, ref_v, rtol=1e-5)
    np.testing.assert_allclose(ours_out[0], ref_out[0], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ours_out[1], ref_out[1], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(ours_g[1], ref_g[1], rtol=1e-5, atol=1e-6)
    mapped = {name: _flax_rnn_params(ours_g[0], name, "ifgo")
              for name in ("forward", "backward", "lone")}
    mapped["rnn"] = {"i": {"kernel": ours_g[0]["rnn"]["input_kernel"],
                           "bias": ours_g[0]["rnn"]["bias"]},
                     "h": {"kernel": ours_g[0]["rnn"]["recurrent_kernel"]}}
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6),
                 mapped, ref_g[0])


def test_recurrent_layers_unroll_by_a_divisor_up_to_8_off_the_cpu_and_not_on_it(monkeypatch):
    assert networks.scan_unroll(24, None) == 1  # the tests run on the CPU
    assert networks.scan_unroll(24, 3) == 3
    monkeypatch.setattr(networks, "_on_cpu", lambda: False)
    assert [networks.scan_unroll(t, None) for t in (24, 12, 16, 7, 100)] == [8, 6, 8, 7, 5]
