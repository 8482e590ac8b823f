"""DSA (Li & Mandt 2018; docs/reference/suite.md §4): a static latent f per sequence, a dynamic z_t
per step.

q(f | half the frames) via an LSTM, q(z_t | f, x, a) via bi-LSTM → RNN, learned priors p(f) and
p(z_t | z_{t−1}, f, a_t), decoder p(x_t | f, z_t). Shapes: B batch, T time, F static size,
Z dynamic size per step, A action.
"""

from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaml.configs.learners import DSAConfig
from jaml.learners import elbo
from jaml.learners.learner import FRAME_SHAPE, Learner, Outputs
from jaml.learners.networks import LSTM, ConvDecoder, ConvEncoder, GaussianHead, RNNEncoder


def _random_half(key, b: int, t: int) -> jax.Array:
    """[B, T//2] int: for each sequence, a random half of the time indices in increasing order."""
    keys = jax.random.split(key, b)
    return jax.vmap(lambda k: jnp.sort(jax.random.permutation(k, t)[: t // 2]))(keys)


def _even_half(b: int, t: int) -> jax.Array:
    """[B, T//2] int: evenly spaced time indices, the deterministic half `encode` uses."""
    return jnp.broadcast_to((jnp.arange(t // 2) * t) // (t // 2), (b, t // 2))


class DisentangledSequentialAE(nn.Module):
    """DSA rebuilt from the reference description (its released constructor has a size bug)."""

    config: DSAConfig

    def setup(self):
        c = self.config
        mu_act = "elu" if c.mu_nl else "none"
        self.conv = ConvEncoder(c.conv_filters, c.conv_features, c.conv_dtype,
                                activation_dtype=c.act_dtype)
        self.static_rnn = LSTM(c.rnn_hidden)
        self.static_head = GaussianHead(c.f_size, "sigmoid", c.logvar_limit)
        self.dynamic_rnn = RNNEncoder(c.rnn_hidden)
        self.dynamic_head = GaussianHead(c.z_step, mu_act, c.logvar_limit)
        self.prior_f_mu = self.param("prior_f_mu", nn.initializers.zeros, (c.f_size,))
        self.prior_f_logvar = self.param("prior_f_logvar", nn.initializers.zeros, (c.f_size,))
        self.prior_rnn = LSTM(c.prior_hidden)
        self.prior_fc = nn.Dense(c.prior_hidden)
        self.prior_head = GaussianHead(c.z_step, "sigmoid", c.logvar_limit)
        self.decoder = ConvDecoder(c.deconv_filters, compute_dtype=c.conv_dtype,
                                   activation_dtype=c.act_dtype,
                                   upsample_form=c.upsample_form)

    def features(self, x, train: bool):
        b, t = x.shape[:2]
        return self.conv(x.reshape(b * t, *FRAME_SHAPE), train).reshape(b, t, -1)

    def static_posterior(self, feats, half):
        """feats [B, T, Fc], half [B, T//2] → μ_f, logvar_f [B, F] from the LSTM's last output."""
        picked = jnp.take_along_axis(feats, half[..., None], axis=1)
        return self.static_head(self.static_rnn(picked)[:, -1])

    def dynamic_posterior(self, feats, a, f):
        """f [B, F] (squashed, no gradient) ⊕ feats ⊕ a → μ_z, logvar_z [B, T, Z]."""
        f_seq = jnp.broadcast_to(jax.lax.stop_gradient(f)[:, None], (*feats.shape[:2], f.shape[-1]))
        a = elbo.encoder_actions(a, feats.shape[1], self.config.current_action)
        return self.dynamic_head(self.dynamic_rnn(jnp.concatenate([f_seq, feats, a], axis=-1)))

    def dynamic_prior(self, z, f, a):
        """p(z_t | z_{t−1}, f, a_t) for all t, z_0 = 0 and a zero LSTM state → μ, logvar [B, T, Z].

        z [B, T, Z] are posterior samples (squashed as the decoder sees them), teacher-forced.
        """
        z_prev = jnp.concatenate([jnp.zeros_like(z[:, :1]), z[:, :-1]], axis=1)
        f_seq = jnp.broadcast_to(f[:, None], (*z.shape[:2], f.shape[-1]))
        h = self.prior_rnn(jnp.concatenate([z_prev, f_seq, a], axis=-1))
        return self.prior_head(nn.relu(self.prior_fc(h)))

    def decode(self, f, z, train: bool):
        """f [B, F] (squashed), z [B, T, Z] → [B, T, H, W, C] from [f ⊕ z_t] per step."""
        b, t = z.shape[:2]
        if self.config.mu_nl:
            z = nn.sigmoid(z)
        f_seq = jnp.broadcast_to(f[:, None], (b, t, f.shape[-1]))
        inputs = jnp.concatenate([f_seq, z], axis=-1).reshape(b * t, -1)
        return self.decoder(inputs, train).reshape(b, t, *FRAME_SHAPE)

    def __call__(self, x, a, key, train: bool = True) -> Outputs:
        half_key, f_key, z_key = jax.random.split(key, 3)
        b, t = x.shape[:2]
        feats = self.features(x, train)
        mu_f, logvar_f = self.static_posterior(feats, _random_half(half_key, b, t))
        f_sample = elbo.reparameterize(f_key, mu_f, logvar_f)
        f = nn.sigmoid(f_sample)
        mu_z, logvar_z = self.dynamic_posterior(feats, a, f)
        z = elbo.reparameterize(z_key, mu_z, logvar_z)
        z_in = nn.sigmoid(z) if self.config.mu_nl else z
        mu_p, logvar_p = self.dynamic_prior(z_in, f, a)
        kl = {
            "kl_static": elbo.gaussian_kl(mu_f, logvar_f, self.prior_f_mu, self.prior_f_logvar),
            "kl_dynamic": elbo.gaussian_kl(mu_z, logvar_z, mu_p, logvar_p).sum(axis=-1),
        }
        # The penalty sees the whole per-step latent [f ⊕ z_t] (pre-sigmoid samples).
        f_seq = jnp.broadcast_to(f_sample[:, None], (b, t, f_sample.shape[-1]))
        return Outputs(
            recon=self.decode(f, z, train), kl=kl, z=jnp.concatenate([f_seq, z], axis=-1)
        )

    def _posterior_means(self, x, a):
        b, t = x.shape[:2]
        feats = self.features(x, False)
        mu_f, _ = self.static_posterior(feats, _even_half(b, t))
        mu_z, _ = self.dynamic_posterior(feats, a, nn.sigmoid(mu_f))
        return mu_f, mu_z

    def encode(self, x, a) -> jax.Array:
        mu_f, mu_z = self._posterior_means(x, a)
        return jnp.concatenate([mu_f, mu_z.reshape(mu_z.shape[0], -1)], axis=-1)

    def reconstruct(self, x, a) -> jax.Array:
        mu_f, mu_z = self._posterior_means(x, a)
        return self.decode(nn.sigmoid(mu_f), mu_z, False)


def make_dsa(name: str, config: DSAConfig) -> Learner:
    return Learner(
        name,
        config,
        DisentangledSequentialAE(config),
        {"kl_static": 1.0, "kl_dynamic": config.beta},
    )
