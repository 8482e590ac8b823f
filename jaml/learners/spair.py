"""SPAIR (Crawford & Pineau 2019; paper App. A): a grid of object slots over one 64×64 frame.

A conv backbone maps the frame to a G×G grid of cells; each cell proposes one object with a box
(`where`), a relaxed Bernoulli presence, a depth and an appearance (`what`) read from a glimpse
of the box by a spatial transformer. Objects are decoded to RGB + alpha glimpses, placed back
with the inverse transform and composited over a decoded background. Shapes: B batch, N = G²
cells, g glimpse side, H = W = 64, C = 3, K what size, Q background size.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaml.learners import elbo
from jaml.learners.learner import FRAME_SHAPE, Learner, Outputs, SingleFrameConfig
from jaml.learners.networks import _BN, _HALVE, MLP, Upsample2x

WHERE = 4  # per cell: x, y offset of the box centre in its cell; x, y size (pre-sigmoid)
# Per cell in `encode` / the penalty latent: where (4), presence (1), depth (1), then what (K).
CELL_FIXED = WHERE + 2


@dataclasses.dataclass(frozen=True)
class SPAIRConfig(SingleFrameConfig):
    """SPAIR on single frames (seq_len 1, one latent step); ld_dim / latent_dim are unused.

    grid_size: G, cells per side (4; the paper's other grid is 6); any of 1..8.
    glimpse_size: side g of the object glimpse (the paper's SPAIR used 28); a multiple of 4.
    what_dim: K, appearance latent per cell. bg_dim: Q, background latent.
    prior_presence: p of the Bernoulli presence prior per cell.
    temperature: of the binary-concrete (Gumbel-sigmoid) relaxation of presence in training.
    max_box_scale: box side = max_box_scale · sigmoid(size latent), as a fraction of the frame.
    backbone_filters: the three k4 s2 p1 convs 64 → 8; conv_features: the per-cell feature.
    cell_widths: the per-cell MLP before the where / presence / depth heads.
    object_filters / object_hidden: the glimpse encoder's two convs and dense width (the
      decoder mirrors them). bg_hidden / bg_resolution: background MLP width and the side of
      the decoded background before its bilinear upsampling to 64×64.
    init_logvar: initial bias of every posterior log-variance head (σ ≈ 0.37 at −2): with unit
      variances the sampled boxes and presences made the early loss mostly noise. Presence
      logits start at logit(prior_presence).
    conv_filters / deconv_filters / mu_nl are not used.
    """

    grid_size: int = 4
    glimpse_size: int = 28
    what_dim: int = 16
    bg_dim: int = 4
    prior_presence: float = 0.1
    temperature: float = 0.5
    max_box_scale: float = 0.5
    backbone_filters: tuple[int, ...] = (32, 64, 128)
    cell_widths: tuple[int, ...] = (128,)
    object_filters: tuple[int, int] = (32, 64)
    object_hidden: int = 256
    bg_hidden: int = 128
    bg_resolution: int = 16
    init_logvar: float = -2.0

    def __post_init__(self):
        super().__post_init__()
        checks = [
            ("grid_size", 1 <= self.grid_size <= 8, "in 1..8"),
            ("glimpse_size", self.glimpse_size >= 4 and self.glimpse_size % 4 == 0,
             "a positive multiple of 4"),
            ("what_dim", self.what_dim >= 1, "≥ 1"),
            ("bg_dim", self.bg_dim >= 1, "≥ 1"),
            ("prior_presence", 0.0 < self.prior_presence < 1.0, "in (0, 1)"),
            ("temperature", self.temperature > 0.0, "> 0"),
            ("max_box_scale", 0.0 < self.max_box_scale <= 1.0, "in (0, 1]"),
            ("backbone_filters", len(self.backbone_filters) == 3, "three conv widths"),
            ("object_filters", len(self.object_filters) == 2, "two conv widths"),
            ("bg_resolution", 1 <= self.bg_resolution <= 64, "in 1..64"),
        ]
        for name, ok, what in checks:
            if not ok:
                raise ValueError(f"SPAIRConfig.{name} must be {what}, got {getattr(self, name)!r}")


    @property
    def cells(self) -> int:
        """N = G²."""
        return self.grid_size**2

    @property
    def penalty_dim(self) -> int:
        return self.latent_size

    @property
    def latent_size(self) -> int:
        """N·(4 + 1 + 1 + K) + Q."""
        return self.cells * (CELL_FIXED + self.what_dim) + self.bg_dim


# --- Spatial transformer (axis-aligned boxes: scale + translation, separable) ---------------


def bilinear_weights(coords: jax.Array, n_in: int) -> jax.Array:
    """[..., n_out] pixel coordinates → [..., n_out, n_in] 1-D bilinear (tent) weights.

    Pixel k of the input has centre k; samples outside [0, n_in − 1] fall off towards zeros
    (zero padding), so a sample at −0.25 keeps 0.75 of pixel 0.
    """
    return jax.nn.relu(1.0 - jnp.abs(coords[..., None] - jnp.arange(n_in, dtype=coords.dtype)))


def _glimpse_coords(centre, scale, g: int, n_in: int):
    """[..., g]: input pixel coordinates of the g glimpse pixels along one axis.

    centre, scale [...] in frame units ([0, 1] spans the frame); glimpse pixel u has glimpse
    coordinate (u + ½)/g ∈ (0, 1) and frame coordinate centre + ((u + ½)/g − ½)·scale.
    """
    u = (jnp.arange(g, dtype=centre.dtype) + 0.5) / g - 0.5
    return (centre[..., None] + u * scale[..., None]) * n_in - 0.5


def _frame_coords(centre, scale, n_out: int, g: int):
    """[..., n_out]: glimpse pixel coordinates of the n_out frame pixels (the inverse map)."""
    y = (jnp.arange(n_out, dtype=centre.dtype) + 0.5) / n_out
    return ((y - centre[..., None]) / scale[..., None] + 0.5) * g - 0.5


def extract_glimpses(images: jax.Array, centre: jax.Array, scale: jax.Array, g: int) -> jax.Array:
    """images [B, H, W, C], centre / scale [B, N, 2] as (x, y) → glimpses [B, N, g, g, C].

    Bilinear sampling with zero padding, as two matrix products (the boxes are axis-aligned).
    """
    h, w = images.shape[1:3]
    ky = bilinear_weights(_glimpse_coords(centre[..., 1], scale[..., 1], g, h), h)  # [B,N,g,H]
    kx = bilinear_weights(_glimpse_coords(centre[..., 0], scale[..., 0], g, w), w)  # [B,N,g,W]
    return jnp.einsum("bnuh,bhwc,bnvw->bnuvc", ky, images, kx)


def place_glimpses(glimpses: jax.Array, centre: jax.Array, scale: jax.Array,
                   size: tuple[int, int]) -> jax.Array:
    """glimpses [B, N, g, g, C] → [B, N, H, W, C]: each put back into its box (inverse map).

    Zero outside the box; `extract_glimpses` of the result at the same box returns the glimpse
    where the box covers whole pixels.
    """
    g = glimpses.shape[2]
    ry = bilinear_weights(_frame_coords(centre[..., 1], scale[..., 1], size[0], g), g)
    rx = bilinear_weights(_frame_coords(centre[..., 0], scale[..., 0], size[1], g), g)
    return jnp.einsum("bnhu,bnuvc,bnwv->bnhwc", ry, glimpses, rx)


def composite(rgb: jax.Array, alpha: jax.Array, presence: jax.Array, depth: jax.Array,
              background: jax.Array) -> jax.Array:
    """Objects over a background → [B, H, W, C].

    rgb [B, N, H, W, C], alpha [B, N, H, W] (zero outside each box), presence, depth [B, N],
    background [B, H, W, C]. Object n covers a_n = presence_n·alpha_n; the foreground colour is
    the softmax over objects of depth_n + log a_n (higher depth in front) and the total cover is
    1 − Π_n (1 − a_n): x = cover·foreground + (1 − cover)·background.
    """
    a = presence[:, :, None, None] * alpha
    weights = jax.nn.softmax(depth[:, :, None, None] + jnp.log(a + 1e-8), axis=1)
    foreground = jnp.sum(weights[..., None] * rgb, axis=1)
    cover = (1.0 - jnp.prod(1.0 - a, axis=1))[..., None]
    return cover * foreground + (1.0 - cover) * background


def bernoulli_kl(logit: jax.Array, prior: float) -> jax.Array:
    """[...]: KL(Bern(q) ‖ Bern(p)) = q log(q/p) + (1 − q) log((1 − q)/(1 − p)), q = σ(logit)."""
    q = jax.nn.sigmoid(logit)
    log_q, log_1q = jax.nn.log_sigmoid(logit), jax.nn.log_sigmoid(-logit)
    return q * (log_q - jnp.log(prior)) + (1.0 - q) * (log_1q - jnp.log1p(-prior))


def relaxed_bernoulli(key: jax.Array, logit: jax.Array, temperature: float) -> jax.Array:
    """[...] in (0, 1): binary-concrete sample σ((logit + log u − log(1 − u)) / temperature)."""
    u = jax.random.uniform(key, logit.shape, logit.dtype, 1e-6, 1.0 - 1e-6)
    return jax.nn.sigmoid((logit + jnp.log(u) - jnp.log1p(-u)) / temperature)


def boxes(where: jax.Array, grid: int, max_scale: float) -> tuple[jax.Array, jax.Array]:
    """where [B, N, 4] (pre-sigmoid) → centre, scale [B, N, 2] (x, y) in frame units.

    Cell n = row·G + col; its box centre is ((col, row) + σ(offset)) / G, so it stays in the
    cell, and its side is max_scale·σ(size).
    """
    n = jnp.arange(grid * grid)
    cell = jnp.stack([n % grid, n // grid], axis=-1).astype(where.dtype)  # (col, row)
    centre = (cell + jax.nn.sigmoid(where[..., :2])) / grid
    return centre, max_scale * jax.nn.sigmoid(where[..., 2:])


# --- Networks ------------------------------------------------------------------------------


class GridBackbone(nn.Module):
    """[B, 64, 64, C] → [B, G, G, F]: three k4 s2 p1 convs to 8×8, then a VALID (9 − G)² conv.

    Each conv → BatchNorm → ELU, no biases (as in the shared ConvEncoder).
    """

    filters: Sequence[int]
    features: int
    grid: int

    @nn.compact
    def __call__(self, x: jax.Array, train: bool) -> jax.Array:
        k = 9 - self.grid
        layers = [(f, 4, 2, _HALVE) for f in self.filters] + [(self.features, k, 1, "VALID")]
        for i, (f, size, stride, pad) in enumerate(layers):
            x = nn.Conv(f, (size, size), strides=stride, padding=pad, use_bias=False,
                        name=f"conv{i}")(x)
            x = nn.elu(nn.BatchNorm(use_running_average=not train, name=f"bn{i}", **_BN)(x))
        return x


class GlimpseEncoder(nn.Module):
    """[M, g, g, C] → [M, hidden]: two k4 s2 p1 convs (ELU) and a dense layer (ELU)."""

    filters: Sequence[int]
    hidden: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for i, f in enumerate(self.filters):
            x = nn.elu(nn.Conv(f, (4, 4), strides=2, padding=_HALVE, name=f"conv{i}")(x))
        return nn.elu(nn.Dense(self.hidden, name="dense")(x.reshape(x.shape[0], -1)))


class GlimpseDecoder(nn.Module):
    """[M, K] → [M, g, g, C + 1] in (0, 1): RGB and alpha, mirroring `GlimpseEncoder`."""

    filters: Sequence[int]
    hidden: int
    size: int
    channels: int = 3

    @nn.compact
    def __call__(self, z: jax.Array) -> jax.Array:
        s, (f0, f1) = self.size // 4, self.filters
        x = nn.elu(nn.Dense(self.hidden, name="dense0")(z))
        x = nn.elu(nn.Dense(s * s * f1, name="dense1")(x)).reshape(z.shape[0], s, s, f1)
        x = nn.elu(Upsample2x(f0, name="deconv0")(x))
        return nn.sigmoid(Upsample2x(self.channels + 1, name="deconv1")(x))


class BackgroundDecoder(nn.Module):
    """[B, Q] → [B, 64, 64, C] in (0, 1): an MLP onto an r×r image, bilinearly upsampled."""

    hidden: int
    resolution: int
    channels: int = 3

    @nn.compact
    def __call__(self, z: jax.Array) -> jax.Array:
        r = self.resolution
        x = nn.elu(nn.Dense(self.hidden, name="dense0")(z))
        # Zero kernel: the background starts flat grey whatever its latent, so that the sampled
        # background latent does not dominate the early loss with noise.
        x = nn.Dense(r * r * self.channels, kernel_init=nn.initializers.zeros, name="dense1")(x)
        x = nn.sigmoid(x)
        x = x.reshape(z.shape[0], r, r, self.channels)
        return jax.image.resize(x, (z.shape[0], *FRAME_SHAPE), "bilinear")


class _Gaussian(nn.Module):
    """[..., I] → (μ, logvar) [..., size]; logvar's bias starts at `init_logvar`, clipped ±limit."""

    size: int
    limit: float
    init_logvar: float

    @nn.compact
    def __call__(self, h: jax.Array) -> tuple[jax.Array, jax.Array]:
        mu = nn.Dense(self.size, name="mu")(h)
        logvar = nn.Dense(self.size, bias_init=nn.initializers.constant(self.init_logvar),
                          name="logvar")(h)
        return mu, jnp.clip(logvar, -self.limit, self.limit)


class SPAIR(nn.Module):
    """The SPAIR model over the last (only) frame of x [B, 1, 64, 64, C]; actions are unused."""

    config: Any

    def setup(self):
        c = self.config
        self.backbone = GridBackbone(c.backbone_filters, c.conv_features, c.grid_size)
        self.cell_trunk = MLP(c.cell_widths)
        self.where_head = _Gaussian(WHERE, c.logvar_limit, c.init_logvar)
        self.depth_head = _Gaussian(1, c.logvar_limit, c.init_logvar)
        prior_logit = math.log(c.prior_presence) - math.log1p(-c.prior_presence)
        self.pres_head = nn.Dense(1, bias_init=nn.initializers.constant(prior_logit))
        self.glimpse_encoder = GlimpseEncoder(c.object_filters, c.object_hidden)
        self.what_head = _Gaussian(c.what_dim, c.logvar_limit, c.init_logvar)
        self.glimpse_decoder = GlimpseDecoder(c.object_filters, c.object_hidden, c.glimpse_size)
        self.bg_trunk = MLP((c.bg_hidden,))
        self.bg_head = _Gaussian(c.bg_dim, c.logvar_limit, c.init_logvar)
        self.bg_decoder = BackgroundDecoder(c.bg_hidden, c.bg_resolution)

    def cell_posterior(self, img, train: bool) -> dict[str, Any]:
        """img [B, H, W, C] → the posteriors that need no glimpse.

        where (μ, logvar) [B, N, 4], depth (μ, logvar) [B, N, 1], pres logit [B, N],
        bg (μ, logvar) [B, Q] (from the cell features averaged over the grid).
        """
        feats = self.backbone(img, train)
        feats = feats.reshape(feats.shape[0], -1, feats.shape[-1])  # [B, N, F], row-major cells
        h = self.cell_trunk(feats)
        return {
            "where": self.where_head(h),
            "depth": self.depth_head(h),
            "pres": self.pres_head(h)[..., 0],
            "bg": self.bg_head(self.bg_trunk(feats.mean(axis=1))),
        }

    def what_posterior(self, img, where):
        """img [B, H, W, C], where [B, N, 4] → what (μ, logvar) [B, N, K] from the glimpses."""
        c = self.config
        centre, scale = boxes(where, c.grid_size, c.max_box_scale)
        glimpses = extract_glimpses(img, centre, scale, c.glimpse_size)
        b, n = glimpses.shape[:2]
        feats = self.glimpse_encoder(glimpses.reshape(b * n, *glimpses.shape[2:]))
        mu, logvar = self.what_head(feats)
        return mu.reshape(b, n, -1), logvar.reshape(b, n, -1)

    def render(self, where, what, presence, depth, bg) -> jax.Array:
        """Latents [B, N, ·] (presence, depth [B, N]) and bg [B, Q] → frame [B, H, W, C]."""
        c = self.config
        b, n = what.shape[:2]
        objects = self.glimpse_decoder(what.reshape(b * n, -1))
        objects = objects.reshape(b, n, *objects.shape[1:])  # [B, N, g, g, C + 1]
        centre, scale = boxes(where, c.grid_size, c.max_box_scale)
        placed = place_glimpses(objects, centre, scale, FRAME_SHAPE[:2])
        return composite(placed[..., :-1], placed[..., -1], presence, depth,
                         self.bg_decoder(bg))

    @staticmethod
    def _flat(where, presence, depth, what, bg) -> jax.Array:
        """[B, N·(6 + K) + Q]: per cell (where, presence, depth, what), cells row-major, then bg."""
        cells = jnp.concatenate([where, presence[..., None], depth, what], axis=-1)
        return jnp.concatenate([cells.reshape(cells.shape[0], -1), bg], axis=-1)

    def __call__(self, x, a, key, train: bool = True) -> Outputs:
        c = self.config
        img = x[:, -1]
        post = self.cell_posterior(img, train)
        k_where, k_what, k_depth, k_pres, k_bg = jax.random.split(key, 5)
        where = elbo.reparameterize(k_where, *post["where"])
        what_mu, what_logvar = self.what_posterior(img, where)
        what = elbo.reparameterize(k_what, what_mu, what_logvar)
        depth = elbo.reparameterize(k_depth, *post["depth"])
        presence = relaxed_bernoulli(k_pres, post["pres"], c.temperature)
        bg = elbo.reparameterize(k_bg, *post["bg"])
        recon = self.render(where, what, presence, depth[..., 0], bg)
        kl = {
            "where": elbo.kl_to_standard_normal(*post["where"]).sum(axis=-1),
            "what": elbo.kl_to_standard_normal(what_mu, what_logvar).sum(axis=-1),
            "depth": elbo.kl_to_standard_normal(*post["depth"]).sum(axis=-1),
            "pres": bernoulli_kl(post["pres"], c.prior_presence).sum(axis=-1),
            "bg": elbo.kl_to_standard_normal(*post["bg"]),
        }
        z = self._flat(where, presence, depth, what, bg)[:, None]
        return Outputs(recon=recon[:, None], kl=kl, z=z)

    def _means(self, x):
        img = x[:, -1]
        post = self.cell_posterior(img, False)
        where = post["where"][0]
        what, _ = self.what_posterior(img, where)
        return where, jax.nn.sigmoid(post["pres"]), post["depth"][0], what, post["bg"][0]

    def encode(self, x, a) -> jax.Array:
        """[B, N·(6 + K) + Q]: posterior means (where pre-sigmoid), presence probabilities."""
        return self._flat(*self._means(x))

    def reconstruct(self, x, a) -> jax.Array:
        """[B, 1, H, W, C]: rendered from the means and the presence probabilities."""
        where, presence, depth, what, bg = self._means(x)
        return self.render(where, what, presence, depth[..., 0], bg)[:, None]


def make_spair(name: str, config: SPAIRConfig) -> Learner:
    weights = dict.fromkeys(("where", "what", "depth", "pres", "bg"), config.beta)
    return Learner(name, config, SPAIR(config), weights)
