"""VAE_rpl, PRED and DSA in PyTorch: jaml's networks and losses restated, to time the peer a user
of the field would run (eager, or `torch.compile` with channels_last and bf16 autocast).

The sizes come from jaml's own configs (`jaml.configs.learners`, no JAX imported), so the layer
shapes, latent sizes and sequence lengths are those of `learners.make(name, ld_dim=D)`. The
trainable parameter count equals jaml's: PyTorch's LSTM/RNN carry two bias vectors per gate
where Flax's cells carry one, so the second (`bias_hh_*`, redundant with `bias_ih_*`) is held at
zero and frozen. `useful_flops` counts a step with `torch.utils.flop_counter.FlopCounterMode`
and `benchmarks/flops.py`'s definition of a convolution's work (taps on real input).
Shapes: B batch, T time, N = B·T frames, Z latent, A action; frames uint8 [B, T, 3, 64, 64].
"""

from __future__ import annotations

import contextlib
import dataclasses

import torch
from torch import nn
from torch.nn import functional as F
from torch.utils.flop_counter import FlopCounterMode

from jaml.configs.learners import DSAConfig, LearnerConfig, default_config

# BatchNorm2d's defaults (momentum 0.1, eps 1e-5) are the reference's; jaml's _BN restates them.
LEARNERS = ("VAE_rpl", "PRED", "DSA")


def _check_supported(config: LearnerConfig) -> None:
    """The peer restates the benchmark's settings; other options of the configs are not ported."""
    wanted = {"mu_nl": True, "current_action": "observed", "kl_form": "standard",
              "frame_nll": "sum"}
    got = {k: getattr(config, k) for k in wanted}
    if got != wanted or (config.static_size and not isinstance(config, DSAConfig)):
        raise ValueError(f"the torch peer supports {wanted} and no PRED static part, got {got}")


def conv_encoder(filters, features: int) -> nn.Sequential:
    """[N, 3, 64, 64] → [N, F, 1, 1]: conv k4 s2 p1 → BN → ELU per filter, then k4 s1 p0 → BN →
    ELU (no conv biases: each conv feeds a BatchNorm), as jaml's `ConvEncoder`."""
    layers, fan_in = [], 3
    for f in filters:
        layers += [nn.Conv2d(fan_in, f, 4, 2, 1, bias=False), nn.BatchNorm2d(f), nn.ELU()]
        fan_in = f
    layers += [nn.Conv2d(fan_in, features, 4, 1, 0, bias=False), nn.BatchNorm2d(features),
               nn.ELU()]
    return nn.Sequential(*layers)


def conv_decoder(z: int, filters, channels: int = 3) -> nn.Sequential:
    """[N, Z, 1, 1] → [N, 3, 64, 64] in (0, 1), as jaml's `ConvDecoder`: 1×1 → 4 (k4 s1 p0)
    → ELU → BN, then k4 s2 p1 transposed convolutions (→ ELU → BN in the middle, → ELU at the
    last filter), → channels with a sigmoid."""
    first, *middle, last = filters
    layers = [nn.ConvTranspose2d(z, first, 4, 1, 0), nn.ELU(), nn.BatchNorm2d(first)]
    fan_in = first
    for f in middle:
        layers += [nn.ConvTranspose2d(fan_in, f, 4, 2, 1), nn.ELU(), nn.BatchNorm2d(f)]
        fan_in = f
    layers += [nn.ConvTranspose2d(fan_in, last, 4, 2, 1), nn.ELU(),
               nn.ConvTranspose2d(last, channels, 4, 2, 1), nn.Sigmoid()]
    return nn.Sequential(*layers)


def mlp(fan_in: int, widths) -> nn.Sequential:
    layers = []
    for w in widths:
        layers += [nn.Linear(fan_in, w), nn.ELU()]
        fan_in = w
    return nn.Sequential(*layers)


def _one_bias(rnn: nn.RNNBase) -> nn.RNNBase:
    """Flax's cells have one bias per gate; PyTorch's b_hh (added to b_ih) is held at zero."""
    for name, p in rnn.named_parameters():
        if name.startswith("bias_hh"):
            nn.init.zeros_(p)
            p.requires_grad_(False)
    return rnn


class GaussianHead(nn.Module):
    """[..., I] → (μ, logvar) [..., Z]: two linear maps, μ through `mu_act`, logvar clipped."""

    def __init__(self, fan_in: int, size: int, mu_act, limit: float):
        super().__init__()
        self.mu, self.logvar, self.mu_act, self.limit = (nn.Linear(fan_in, size),
                                                         nn.Linear(fan_in, size), mu_act, limit)

    def forward(self, h):
        return self.mu_act(self.mu(h)), torch.clamp(self.logvar(h), -self.limit, self.limit)


def reparameterize(mu, logvar):
    return mu + torch.randn_like(mu) * torch.exp(0.5 * logvar)


def kl_standard(mu, logvar):
    """[...]: KL(N(μ, σ²) ‖ N(0, I)) summed over the last axis."""
    return 0.5 * (logvar.exp() + mu.square() - 1.0 - logvar).sum(-1)


def gaussian_kl(mu_q, logvar_q, mu_p, logvar_p):
    """[...]: KL(N(μ_q, σ_q²) ‖ N(μ_p, σ_p²)) summed over the last axis (DSA's learned priors)."""
    ratio = (logvar_q.exp() + (mu_q - mu_p).square()) * torch.exp(-logvar_p)
    return 0.5 * (logvar_p - logvar_q + ratio - 1.0).sum(-1)


def _frames(frames, memory_format):
    """uint8 [B, T, 3, 64, 64] → float [B·T, 3, 64, 64] in [0, 1], in `memory_format`."""
    x = frames.flatten(0, 1).float() / 255.0
    return x.contiguous(memory_format=memory_format)


def _nll(x, recon, b: int):
    """−log p(x | x̂) of a unit-variance Gaussian per frame, summed over a sequence's frames: [B]."""
    return 0.5 * (x - recon.float()).square().sum((1, 2, 3)).view(b, -1).sum(1)


class FeedForwardVAE(nn.Module):
    """VAE_rpl (T = 1) and PRED (first `hist` of T frames in, T latent steps decoded): conv
    features ⊕ actions → MLP → Gaussian head (ELU on μ) → sigmoid(z) per step → decoder."""

    def __init__(self, config: LearnerConfig, action_dim: int):
        super().__init__()
        c = config
        self.hist, self.steps, self.z = c.hist, c.latent_steps, c.z_step
        self.beta, self.memory_format = c.beta, torch.contiguous_format
        self.conv = conv_encoder(c.conv_filters, c.conv_features)
        self.trunk = mlp(c.hist * (c.conv_features + action_dim), c.mlp_widths)
        self.head = GaussianHead(c.mlp_widths[-1], c.latent_steps * c.z_step, F.elu,
                                 c.logvar_limit)
        self.decoder = conv_decoder(c.z_step, c.deconv_filters)

    def forward(self, frames, actions):
        """frames uint8 [B, T, 3, 64, 64], actions [B, T, A] → the loss (−ELBO, batch mean)."""
        b, h = frames.shape[0], self.hist
        x = _frames(frames, self.memory_format)
        seen = x if h == frames.shape[1] else _frames(frames[:, :h], self.memory_format)
        feats = self.conv(seen).view(b, h, -1)
        mu, logvar = self.head(self.trunk(torch.cat([feats, actions[:, :h]], -1).flatten(1)))
        z = reparameterize(mu, logvar).view(b * self.steps, self.z, 1, 1)
        recon = self.decoder(torch.sigmoid(z).contiguous(memory_format=self.memory_format))
        kl = kl_standard(mu.view(b, self.steps, self.z), logvar.view(b, self.steps, self.z))
        return (_nll(x, recon, b) + self.beta * kl.sum(1)).mean()


class DSA(nn.Module):
    """DSA as jaml's `DisentangledSequentialAE`: q(f | a random half of the frames) by an LSTM,
    q(z_t | f, x, a) by a bi-LSTM → tanh RNN, learned priors p(f) and p(z_t | z_{t−1}, f, a_t)
    (LSTM → ReLU linear), decoder p(x_t | f, z_t)."""

    def __init__(self, config: DSAConfig, action_dim: int):
        super().__init__()
        c = config
        hid, fs, zs = c.rnn_hidden, c.f_size, c.z_step
        self.beta, self.memory_format = c.beta, torch.contiguous_format
        self.conv = conv_encoder(c.conv_filters, c.conv_features)
        self.static_rnn = _one_bias(nn.LSTM(c.conv_features, hid, batch_first=True))
        self.static_head = GaussianHead(hid, fs, torch.sigmoid, c.logvar_limit)
        self.dynamic_bilstm = _one_bias(nn.LSTM(fs + c.conv_features + action_dim, hid,
                                                batch_first=True, bidirectional=True))
        self.dynamic_rnn = _one_bias(nn.RNN(2 * hid, hid, batch_first=True))
        self.dynamic_head = GaussianHead(hid, zs, F.elu, c.logvar_limit)
        self.prior_f_mu = nn.Parameter(torch.zeros(fs))
        self.prior_f_logvar = nn.Parameter(torch.zeros(fs))
        self.prior_rnn = _one_bias(nn.LSTM(zs + fs + action_dim, c.prior_hidden,
                                           batch_first=True))
        self.prior_fc = nn.Linear(c.prior_hidden, c.prior_hidden)
        self.prior_head = GaussianHead(c.prior_hidden, zs, torch.sigmoid, c.logvar_limit)
        self.decoder = conv_decoder(fs + zs, c.deconv_filters)

    def forward(self, frames, actions):
        """frames uint8 [B, T, 3, 64, 64], actions [B, T, A] → the loss (−ELBO, batch mean)."""
        b, t = frames.shape[:2]
        x = _frames(frames, self.memory_format)
        feats = self.conv(x).view(b, t, -1)  # [B, T, Fc]
        half = torch.rand(b, t, device=feats.device).argsort(1)[:, : t // 2].sort(1).values
        picked = feats.gather(1, half[..., None].expand(-1, -1, feats.shape[-1]))
        mu_f, logvar_f = self.static_head(self.static_rnn(picked)[0][:, -1])
        f = torch.sigmoid(reparameterize(mu_f, logvar_f))  # [B, F]
        f_seq = f[:, None].expand(b, t, f.shape[-1])
        h = self.dynamic_bilstm(torch.cat([f_seq.detach(), feats, actions], -1))[0]
        mu_z, logvar_z = self.dynamic_head(self.dynamic_rnn(h)[0])  # [B, T, Z]
        z = torch.sigmoid(reparameterize(mu_z, logvar_z))  # as the prior and decoder see it
        z_prev = torch.cat([torch.zeros_like(z[:, :1]), z[:, :-1]], 1)
        h = self.prior_rnn(torch.cat([z_prev, f_seq, actions], -1))[0]
        mu_p, logvar_p = self.prior_head(F.relu(self.prior_fc(h)))
        kl = (gaussian_kl(mu_f, logvar_f, self.prior_f_mu, self.prior_f_logvar)
              + self.beta * gaussian_kl(mu_z, logvar_z, mu_p, logvar_p).sum(1))
        latent = torch.cat([f_seq, z], -1).reshape(b * t, -1, 1, 1)
        recon = self.decoder(latent.contiguous(memory_format=self.memory_format))
        return (_nll(x, recon, b) + kl).mean()


def build(name: str, ld_dim: int = 4, action_dim: int = 1) -> nn.Module:
    """The peer of `jaml.learners.make(name, ld_dim=ld_dim)` for actions of `action_dim`."""
    if name not in LEARNERS:
        raise ValueError(f"the torch peer has {LEARNERS}, not {name!r}")
    config = default_config(name, ld_dim=ld_dim)
    _check_supported(config)
    return (DSA if name == "DSA" else FeedForwardVAE)(config, action_dim)


def seq_len(name: str, ld_dim: int = 4) -> int:
    return default_config(name, ld_dim=ld_dim).seq_len


def trainable_parameters(model: nn.Module) -> list[nn.Parameter]:
    return [p for p in model.parameters() if p.requires_grad]


@dataclasses.dataclass(frozen=True)
class Variant:
    """How the peer runs: eager or `torch.compile(mode=compile_mode)`; channels_last activations
    and conv weights; "bfloat16": the forward pass under `torch.autocast(bfloat16)`."""

    compile_mode: str | None = None
    channels_last: bool = False
    dtype: str = "float32"

    @property
    def label(self) -> str:
        run = "eager" if self.compile_mode is None else f"compiled {self.compile_mode}"
        return run + (", channels_last" if self.channels_last else "")


class Peer:
    """A model, its Adam and one train step (zero_grad, forward, backward, Adam), as a user
    writes it; compiled as a whole when `variant.compile_mode` is set (Dynamo breaks the graph
    at `backward()`: AOTAutograd compiles forward and backward together, the optimizer step is
    its own graph; cuDNN's LSTMs stay eager, as Dynamo leaves RNN modules by default)."""

    def __init__(self, name: str, variant: Variant = Variant(), *, ld_dim: int = 4,
                 action_dim: int = 1, device: str | torch.device = "cpu", seed: int = 0):
        self.name, self.variant, self.device = name, variant, torch.device(device)
        torch.manual_seed(seed)
        self.memory_format = (torch.channels_last if variant.channels_last
                              else torch.contiguous_format)
        self.model = build(name, ld_dim, action_dim).to(self.device,
                                                        memory_format=self.memory_format)
        self.model.memory_format = self.memory_format
        config = default_config(name, ld_dim=ld_dim)
        # Eager on a GPU: the single-kernel (fused) Adam a careful user picks; compiled: the
        # default implementation, which Inductor fuses itself (PyTorch's compiled-optimizer
        # recipe).
        fused = self.device.type == "cuda" and variant.compile_mode is None
        self.opt = torch.optim.Adam(trainable_parameters(self.model), lr=config.learning_rate,
                                    **({"fused": True} if fused else {}))
        self.step = (self._step if variant.compile_mode is None else
                     torch.compile(self._step, mode=variant.compile_mode, dynamic=False))

    def autocast(self):
        if self.variant.dtype == "bfloat16":
            return torch.autocast(self.device.type, dtype=torch.bfloat16)
        return contextlib.nullcontext()

    def host_context(self):
        """Around the steps: a bfloat16 DSA on a CPU runs its LSTMs on ATen's own kernels
        (oneDNN's bf16 LSTM wants AVX-512 BF16 and fails to build on hosts without it)."""
        if self.device.type == "cpu" and self.variant.dtype == "bfloat16" and self.name == "DSA":
            return torch.backends.mkldnn.flags(enabled=False)
        return contextlib.nullcontext()

    def _step(self, frames, actions):
        self.opt.zero_grad(set_to_none=True)
        with self.autocast():
            loss = self.model(frames, actions)
        loss.backward()
        self.opt.step()
        return loss.detach()

    def batch(self, frames, actions):
        """numpy uint8 [B, T, 64, 64, 3], float [B, T, A] → the peer's tensors on its device:
        frames [B, T, 3, 64, 64], channels_last strides (the NHWC data as is) or contiguous."""
        x = torch.from_numpy(frames).permute(0, 1, 4, 2, 3)
        if not self.variant.channels_last:
            x = x.contiguous()
        return x.to(self.device), torch.from_numpy(actions).to(self.device)


# --- FLOPs: FlopCounterMode with benchmarks/flops.py's count of a convolution -------------------


def _valid_pairs(size_in: int, kernel: int, size_out: int, stride: int, pad: int,
                 dilation: int, transposed: bool) -> int:
    """Σ (input position, kernel tap) pairs of one spatial dimension that meet a real input and a
    real output element: padding, and the outputs a transposed convolution crops, are no work."""
    count = 0
    if transposed:  # out[stride·i − pad + dilation·k] += x[i]·w[k]
        for i in range(size_in):
            for k in range(kernel):
                count += 0 <= i * stride - pad + k * dilation < size_out
    else:  # out[o] += x[stride·o − pad + dilation·k]·w[k]
        for o in range(size_out):
            for k in range(kernel):
                count += 0 <= o * stride - pad + k * dilation < size_in
    return count


def _conv_useful(x_shape, w_shape, stride, padding, dilation, transposed, out_shape) -> int:
    """2 · batch · (C_out · C_in per group) · Π_d valid pairs: `flops.conv_flops`'s count
    (FlopCounterMode's default counts every tap, padding included)."""
    pairs = 1
    for d in range(len(x_shape) - 2):
        pairs *= _valid_pairs(x_shape[2 + d], w_shape[2 + d], out_shape[2 + d], stride[d],
                              padding[d], dilation[d], transposed)
    return 2 * x_shape[0] * w_shape[0] * w_shape[1] * pairs


def _conv_forward(x_shape, w_shape, _bias, stride, padding, dilation, transposed, *args,
                  out_shape=None, **kwargs) -> int:
    return _conv_useful(x_shape, w_shape, stride, padding, dilation, transposed, out_shape)


def _conv_backward(grad_out_shape, x_shape, w_shape, _bias, stride, padding, dilation,
                   transposed, _output_padding, _groups, output_mask, out_shape=None,
                   **kwargs) -> int:
    # The input and the kernel gradient each take the forward's multiply pairs once.
    forward = _conv_useful(x_shape, w_shape, stride, padding, dilation, transposed,
                           grad_out_shape)
    return forward * (int(output_mask[0]) + int(output_mask[1]))


def _flop_counter() -> FlopCounterMode:
    aten = torch.ops.aten
    forward = {op: _conv_forward for op in (aten.convolution, aten._convolution,
                                            aten.cudnn_convolution, aten._slow_conv2d_forward,
                                            aten.convolution_overrideable)}
    return FlopCounterMode(
        display=False, custom_mapping={**forward, aten.convolution_backward: _conv_backward})


def useful_flops(name: str, batch: int = 2, backward: bool = True, ld_dim: int = 4,
                 action_dim: int = 1) -> dict[str, int]:
    """{aten op: FLOPs} of the peer's loss (and its gradient, `backward`) for `batch` ≥ 2
    sequences (BatchNorm trains on batch statistics): convolutions counted by real taps,
    matmuls 2·M·N·K, nothing else.

    Run on the meta device (shapes only, nothing computed), where the LSTMs decompose into the
    matmuls they execute (cuDNN's fused RNN kernels are not counted by FlopCounterMode)."""
    torch.manual_seed(0)
    t = seq_len(name, ld_dim)
    with torch.device("meta"):
        model = build(name, ld_dim, action_dim)
        frames = torch.empty((batch, t, 3, 64, 64), dtype=torch.uint8)
        actions = torch.empty((batch, t, action_dim))
    counter = _flop_counter()
    with counter:
        loss = model(frames, actions)
        if backward:
            loss.backward()
    return {str(op): n for op, n in counter.get_flop_counts()["Global"].items()}
