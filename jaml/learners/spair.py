"""SPAIR (Crawford & Pineau 2019; paper App. A): a grid of object slots over one 64×64 frame.

A conv backbone maps the frame to a G×G grid of cell features. The cells are then inferred one
after another in raster order (a `lax.scan`), each conditioned on the sampled latents of its
already-inferred neighbours (up-left, up, up-right, left; a learned edge element off the grid):
a box (`where`), an appearance (`what`) read from a glimpse of that box by a spatial transformer,
a depth and a relaxed-Bernoulli presence. The presence prior is SPAIR's prior on the object
count, a truncated geometric annealed over training. Objects are decoded to RGB + alpha glimpses,
placed back with the inverse transform and composed over a decoded background by SPAIR's
importance-weighted rule. For the first training steps SPAIR's training wheels hold the box,
depth and presence posteriors out of the gradient; `jaml.experiments.spair_probe` checks that the
presences find objects on a toy task. Shapes: B batch, N = G² cells, g glimpse side,
H = W = 64, C = 3, K what size, Q background size, P = 4 + K + 2 per-cell program (box, what,
depth, presence).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaml.configs.learners import CELL_FIXED, WHERE, SPAIRConfig  # noqa: F401
from jaml.learners import elbo
from jaml.learners.learner import FRAME_SHAPE, Learner, Outputs
from jaml.learners.networks import _HALVE, MLP, Upsample2x, _norm, elu

# Neighbours a cell is conditioned on, as (row, col) offsets, in the order they are concatenated.
NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1))  # up-left, up, up-right, left
MAX_DEPTH = 4.0  # SPAIR's depth z = 4·σ(depth logit) ∈ (0, 4)
MIN_IMPORTANCE = 0.01  # SPAIR's floor on an object's rendering importance α·z


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


# The smallest box side (frame units) the inverse map divides by. A sampled size logit below
# ≈ −44 makes σ(size) so small that d(1/side) overflows float32: the gradient of a box that
# draws nothing became 0·∞ = NaN and poisoned every parameter. A side of 1e-6 of the frame
# (1e-4 pixel at 64×64) draws nothing either, so the forward pass is unchanged.
MIN_SIDE = 1e-6


def _frame_coords(centre, scale, n_out: int, g: int):
    """[..., n_out]: glimpse pixel coordinates of the n_out frame pixels (the inverse map)."""
    y = (jnp.arange(n_out, dtype=centre.dtype) + 0.5) / n_out
    scale = jnp.maximum(scale, MIN_SIDE)
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


def composite(rgb: jax.Array, alpha: jax.Array, importance: jax.Array,
              background: jax.Array) -> jax.Array:
    """SPAIR's rendering rule (its `render_sprites` op) → [B, H, W, C].

    rgb [B, N, H, W, C], alpha, importance [B, N, H, W] (both zero outside each object's box,
    alpha already multiplied by presence), background [B, H, W, C]. Each object over the
    background gives vₙ = αₙ·rgbₙ + (1 − αₙ)·bg; a pixel is the importance-weighted mean
    Σₙ impₙ vₙ / Σₙ impₙ of the objects whose box covers it, and the background where none does.
    """
    values = alpha[..., None] * rgb + (1.0 - alpha[..., None]) * background[:, None]
    total = jnp.sum(importance, axis=1)[..., None]
    covered = total > 0.0
    mixed = jnp.sum(importance[..., None] * values, axis=1) / jnp.where(covered, total, 1.0)
    return jnp.where(covered, mixed, background)


def bernoulli_kl(logit: jax.Array, prior) -> jax.Array:
    """[...]: KL(Bern(q) ‖ Bern(p)) = q log(q/p) + (1 − q) log((1 − q)/(1 − p)), q = σ(logit).

    `prior` p broadcasts against `logit`; it is clipped to [1e-6, 1 − 1e-6].
    """
    q = jax.nn.sigmoid(logit)
    log_q, log_1q = jax.nn.log_sigmoid(logit), jax.nn.log_sigmoid(-logit)
    p = jnp.clip(prior, 1e-6, 1.0 - 1e-6)
    return q * (log_q - jnp.log(p)) + (1.0 - q) * (log_1q - jnp.log1p(-p))


def held(x: jax.Array, wheels) -> jax.Array:
    """x in the forward pass; its gradient scaled by 1 − wheels (0 while the wheels are on)."""
    return wheels * jax.lax.stop_gradient(x) + (1.0 - wheels) * x


def logistic_noise(key: jax.Array, shape) -> jax.Array:
    """log u − log(1 − u), u ~ U(0, 1): the noise of a binary-concrete sample."""
    u = jax.random.uniform(key, shape, jnp.float32, 1e-6, 1.0 - 1e-6)
    return jnp.log(u) - jnp.log1p(-u)


# --- The count prior on presence (SPAIR §3.2) --------------------------------------------------


def count_prior(log_odds, cells: int) -> jax.Array:
    """[N + 1]: P(C = k) ∝ ρ^k, k = 0..N, ρ = σ(log_odds) (a geometric truncated to the grid)."""
    k = jnp.arange(cells + 1, dtype=jnp.float32)
    return jax.nn.softmax(k * jax.nn.log_sigmoid(jnp.asarray(log_odds, jnp.float32)))


def presence_prior(present: jax.Array, log_odds) -> jax.Array:
    """[B, N]: the prior p(zᵢ = 1 | z₁..zᵢ₋₁) of each cell's presence given the earlier cells'.

    present [B, N] are the earlier cells' hard presences (0 or 1), cells in raster order. The
    count C ~ `count_prior` is drawn first and C of the N cells are chosen uniformly, so given C
    and the k present among the first i cells, p(zᵢ = 1) = (C − k)/(N − i); the posterior over C
    is updated with each cell's presence. Π over cells of p(zᵢ | z₍<ᵢ₎) is P(C = c)/binom(N, c)
    for a configuration with c present cells.
    """
    b, n = present.shape
    support = jnp.arange(n + 1, dtype=jnp.float32)
    dist = jnp.broadcast_to(count_prior(log_odds, n), (b, n + 1))

    def step(carry, inputs):
        dist, count = carry
        i, z = inputs
        given = jnp.maximum(support - count[:, None], 0.0) / (n - i)  # p(zᵢ = 1 | C, k)
        p = jnp.sum(dist * given, axis=1)
        dist = dist * jnp.where(z[:, None] > 0.5, given, 1.0 - given)
        dist = dist / jnp.maximum(jnp.sum(dist, axis=1, keepdims=True), 1e-6)
        return (dist, count + (z > 0.5)), p

    _, probs = jax.lax.scan(step, (dist, jnp.zeros((b,), jnp.float32)),
                            (jnp.arange(n, dtype=jnp.float32), present.T))
    return probs.T


def presence_log_prior(present: jax.Array, log_odds) -> jax.Array:
    """[B]: log p(z₁..z_N) of hard presences [B, N] under the count prior."""
    p = jnp.clip(presence_prior(present, log_odds), 1e-12, 1.0 - 1e-12)
    return jnp.sum(jnp.where(present > 0.5, jnp.log(p), jnp.log1p(-p)), axis=1)


# --- Boxes ---------------------------------------------------------------------------------------


def cell_origins(grid: int) -> jax.Array:
    """[N, 2]: (col, row) of each cell, n = row·G + col."""
    n = np.arange(grid * grid)
    return jnp.asarray(np.stack([n % grid, n // grid], axis=-1), jnp.float32)


def box_from_where(where: jax.Array, cell: jax.Array, grid: int, min_yx: float, max_yx: float,
                   anchor: float) -> tuple[jax.Array, jax.Array]:
    """where [..., 4] (pre-sigmoid), cell [..., 2] (col, row) → centre, side [..., 2] (x, y).

    In frame units ([0, 1] spans the frame): centre = (cell + min_yx + (max_yx − min_yx)·
    σ(offset)) / G, side = anchor·σ(size).
    """
    offset = min_yx + (max_yx - min_yx) * jax.nn.sigmoid(where[..., :2])
    return (cell + offset) / grid, anchor * jax.nn.sigmoid(where[..., 2:])


def boxes(where: jax.Array, config: SPAIRConfig) -> tuple[jax.Array, jax.Array]:
    """where [B, N, 4] (pre-sigmoid, cells row-major) → centre, side [B, N, 2] in frame units."""
    g = config.grid_size
    return box_from_where(where, cell_origins(g), g, config.min_yx, config.max_yx,
                          config.anchor_scale)


def pixel_boxes(centre: jax.Array, side: jax.Array, size: int = FRAME_SHAPE[0]) -> jax.Array:
    """[..., 4]: (x0, y0, x1, y1) pixel-edge coordinates of boxes given in frame units."""
    return jnp.concatenate([centre - side / 2, centre + side / 2], axis=-1) * size


# --- Networks ------------------------------------------------------------------------------


def render_objects(rgb: jax.Array, alpha: jax.Array, where: jax.Array, z: jax.Array,
                   presence: jax.Array, background: jax.Array, config: SPAIRConfig) -> jax.Array:
    """Decoded glimpses placed in their boxes and composed over the background → [B, H, W, C].

    rgb [B, N, g, g, C], alpha [B, N, g, g] in [0, 1]; where [B, N, 4] (pre-sigmoid); depth z
    and presence [B, N]; background [B, H, W, C]. An object's alpha is scaled by its presence
    and its importance is max(α·z, 0.01) (SPAIR); both are placed with the inverse transform.
    """
    alpha = alpha * presence[..., None, None]
    importance = jnp.maximum(alpha * z[..., None, None], MIN_IMPORTANCE)
    centre, side = boxes(where, config)
    sprites = jnp.concatenate([rgb, alpha[..., None], importance[..., None]], axis=-1)
    placed = place_glimpses(sprites, centre, side, background.shape[1:3])
    c = rgb.shape[-1]
    return composite(placed[..., :c], placed[..., c], placed[..., c + 1], background)


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
            x = elu(_norm(f"bn{i}", train, None)(x))
        return x


class GlimpseEncoder(nn.Module):
    """[M, g, g, C] → [M, hidden]: two k4 s2 p1 convs (ELU) and a dense layer (ELU)."""

    filters: Sequence[int]
    hidden: int

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for i, f in enumerate(self.filters):
            x = elu(nn.Conv(f, (4, 4), strides=2, padding=_HALVE, name=f"conv{i}")(x))
        return elu(nn.Dense(self.hidden, name="dense")(x.reshape(x.shape[0], -1)))


class GlimpseDecoder(nn.Module):
    """[M, K] → [M, g, g, C + 1] logits of RGB and alpha, mirroring `GlimpseEncoder`."""

    filters: Sequence[int]
    hidden: int
    size: int
    channels: int = 3

    @nn.compact
    def __call__(self, z: jax.Array) -> jax.Array:
        s, (f0, f1) = self.size // 4, self.filters
        x = elu(nn.Dense(self.hidden, name="dense0")(z))
        x = elu(nn.Dense(s * s * f1, name="dense1")(x)).reshape(z.shape[0], s, s, f1)
        x = elu(Upsample2x(f0, name="deconv0")(x))
        return Upsample2x(self.channels + 1, name="deconv1")(x)


def glimpse_rgba(logits: jax.Array) -> tuple[jax.Array, jax.Array]:
    """[..., C + 1] decoder logits → rgb [..., C], alpha [...] (SPAIR's scales: rgb σ(2l),
    alpha σ(0.1 l + 5), so that objects start nearly opaque and alpha changes slowly)."""
    rgb = jax.nn.sigmoid(jnp.clip(2.0 * logits[..., :-1], -10.0, 10.0))
    alpha = jax.nn.sigmoid(jnp.clip(0.1 * logits[..., -1] + 5.0, -10.0, 10.0))
    return rgb, alpha


class BackgroundDecoder(nn.Module):
    """[B, Q] → [B, 64, 64, C] in (0, 1): an MLP onto an r×r image, bilinearly upsampled."""

    hidden: int
    resolution: int
    channels: int = 3

    @nn.compact
    def __call__(self, z: jax.Array) -> jax.Array:
        r = self.resolution
        x = elu(nn.Dense(self.hidden, name="dense0")(z))
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


class _Lateral(nn.Module):
    """[B, I] → [B, out]: SPAIR's per-cell MLP (ELU hidden layers, linear output)."""

    widths: Sequence[int]
    out: int

    @nn.compact
    def __call__(self, h: jax.Array) -> jax.Array:
        return nn.Dense(self.out, name="out")(MLP(self.widths, name="mlp")(h))


def neighbour_context(grid: jax.Array, row, col) -> jax.Array:
    """[B, 4·P]: the programs of cell (row, col)'s up-left, up, up-right and left neighbours.

    grid [B, G + 1, G + 2, P] holds cell (r, c) at [r + 1, c + 1] and the edge element in its
    padding (row 0, the first and last columns) and wherever no cell has been inferred yet.
    """
    return jnp.concatenate([grid[:, row + 1 + dr, col + 1 + dc] for dr, dc in NEIGHBOURS],
                           axis=-1)


class CellStep(nn.Module):
    """One cell of the raster-order inference, scanned over the N cells by `nn.scan`.

    carry: the program grid [B, G + 1, G + 2, P], cell (r, c) at [r + 1, c + 1], padded with
    the edge element above and to both sides and holding the edge element where no cell has
    been inferred yet. xs per cell: feature [B, F], index n, the Gaussian noises of where
    [B, 4], what [B, K] and depth [B, 1] and the presence's logistic noise [B] (all zero for the
    posterior means). Broadcast: the frame [B, H, W, C], the presence temperature and the
    training wheels (1.0: no gradient into the box, depth and presence posteriors; 0.0: off).
    """

    config: Any

    @nn.compact
    def __call__(self, grid, xs, img, temperature, wheels):
        c = self.config
        feat, n, eps_where, eps_what, eps_depth, noise_pres = xs
        row, col = n // c.grid_size, n % c.grid_size
        context = neighbour_context(grid, row, col)
        # Offsets so that a zero network output means μ at the prior mean and logvar at
        # init_logvar (SPAIR starts boxes at the prior size, a tenth of the anchor).
        where_mu0 = jnp.asarray([0.0, 0.0, c.hw_prior_mean, c.hw_prior_mean])

        out = _Lateral(c.lateral_widths, 2 * WHERE + c.passthrough, name="box")(
            jnp.concatenate([feat, context], axis=-1))
        where_mu = held(out[:, :WHERE] + where_mu0, wheels)
        where_logvar = held(jnp.clip(out[:, WHERE:2 * WHERE] + c.init_logvar, -c.logvar_limit,
                                     c.logvar_limit), wheels)
        features = out[:, 2 * WHERE:]
        where = where_mu + eps_where * jnp.exp(0.5 * where_logvar)
        cell = jnp.stack([col, row]).astype(jnp.float32)
        centre, side = box_from_where(where, cell, c.grid_size, c.min_yx, c.max_yx,
                                      c.anchor_scale)
        glimpse = extract_glimpses(img, centre[:, None], side[:, None], c.glimpse_size)[:, 0]
        what_mu, what_logvar = _Gaussian(c.what_dim, c.logvar_limit, c.init_logvar,
                                         name="what_head")(
            GlimpseEncoder(c.object_filters, c.object_hidden, name="glimpse_encoder")(glimpse))
        what = what_mu + eps_what * jnp.exp(0.5 * what_logvar)
        program = jnp.concatenate([jax.nn.sigmoid(where), what], axis=-1)

        out = _Lateral(c.lateral_widths, 2 + c.passthrough, name="depth")(
            jnp.concatenate([feat, context, features, program], axis=-1))
        depth_mu = held(out[:, :1], wheels)
        depth_logvar = held(jnp.clip(out[:, 1:2] + c.init_logvar, -c.logvar_limit,
                                     c.logvar_limit), wheels)
        features = out[:, 2:]
        depth = depth_mu + eps_depth * jnp.exp(0.5 * depth_logvar)
        z = MAX_DEPTH * jax.nn.sigmoid(jnp.clip(depth, -10.0, 10.0))
        program = jnp.concatenate([program, z], axis=-1)

        pres_logit = _Lateral(c.lateral_widths, 1, name="pres")(
            jnp.concatenate([feat, context, features, program], axis=-1))[:, 0]
        pres_logit = held(jnp.clip(pres_logit, -10.0, 10.0), wheels)
        pres = jax.nn.sigmoid((pres_logit + noise_pres) / temperature)
        program = jnp.concatenate([program, pres[:, None]], axis=-1)

        grid = jax.lax.dynamic_update_slice(grid, program[:, None, None, :],
                                            (0, row + 1, col + 1, 0))
        latents = {
            "where_mu": where_mu, "where_logvar": where_logvar, "where": where,
            "what_mu": what_mu, "what_logvar": what_logvar, "what": what,
            "depth_mu": depth_mu, "depth_logvar": depth_logvar, "depth": depth, "z": z[:, 0],
            "pres_logit": pres_logit, "pres": pres,
        }
        return grid, latents


class SPAIR(nn.Module):
    """The SPAIR model over the last (only) frame of x [B, 1, 64, 64, C]; actions are unused."""

    config: Any

    def setup(self):
        c = self.config
        self.backbone = GridBackbone(c.backbone_filters, c.conv_features, c.grid_size)
        self.cells = nn.scan(CellStep, variable_broadcast="params", split_rngs={"params": False},
                             in_axes=(0, nn.broadcast, nn.broadcast, nn.broadcast),
                             out_axes=0)(c)
        # The program of a missing neighbour (off the grid or not yet inferred); box and
        # presence parts pass through a sigmoid like a cell's (SPAIR's edge element).
        self.edge = self.param("edge", nn.initializers.zeros, (c.program_size,))
        self.glimpse_decoder = GlimpseDecoder(c.object_filters, c.object_hidden, c.glimpse_size)
        self.bg_trunk = MLP((c.bg_hidden,))
        self.bg_head = _Gaussian(c.bg_dim, c.logvar_limit, c.init_logvar)
        self.bg_decoder = BackgroundDecoder(c.bg_hidden, c.bg_resolution)
        # Training steps taken, for the count prior's annealing: kept with the BatchNorm
        # statistics, the one collection the shared train step threads through.
        self.steps = self.variable("batch_stats", "count_prior_step",
                                   lambda: jnp.zeros((), jnp.float32))

    def edge_program(self) -> jax.Array:
        """[P]: the edge element with σ on its box (4) and presence (last) entries."""
        e, w = self.edge, WHERE
        return jnp.concatenate([jax.nn.sigmoid(e[:w]), e[w:-1], jax.nn.sigmoid(e[-1:])])

    def infer(self, img, noise, temperature, train: bool, wheels=0.0) -> tuple[dict, tuple]:
        """img [B, H, W, C] → per-cell latents (each [B, N, ·]; z, pres, pres_logit [B, N]) and
        the background posterior (μ, logvar) [B, Q].

        noise: (where [B, N, 4], what [B, N, K], depth [B, N, 1], presence [B, N]) standard
        normal / logistic draws, zeros for the posterior means (with temperature 1). wheels:
        1.0 holds the box, depth and presence posteriors out of the gradient (`CellStep`).
        """
        feats = self.backbone(img, train)
        feats = feats.reshape(feats.shape[0], -1, feats.shape[-1])  # [B, N, F], row-major cells
        bg = self.bg_head(self.bg_trunk(feats.mean(axis=1)))
        return self.infer_cells(feats, img, noise, temperature, wheels), bg

    def infer_cells(self, feats, img, noise, temperature, wheels=0.0) -> dict:
        """The raster-order scan over cells: feats [B, N, F] (the backbone's), img, noise,
        wheels as in `infer` → per-cell latents [B, N, ·]."""
        c = self.config
        b = img.shape[0]
        grid = jnp.broadcast_to(self.edge_program(),
                                (b, c.grid_size + 1, c.grid_size + 2, c.program_size))
        xs = (feats, *noise)
        xs = jax.tree.map(lambda v: jnp.swapaxes(v, 0, 1), xs)  # cells first
        xs = (xs[0], jnp.arange(c.cells), *xs[1:])
        _, latents = self.cells(grid, xs, img, jnp.asarray(temperature, jnp.float32),
                                jnp.asarray(wheels, jnp.float32))
        return jax.tree.map(lambda v: jnp.swapaxes(v, 0, 1), latents)

    def render(self, where, what, z, presence, bg) -> jax.Array:
        """where [B, N, 4], what [B, N, K], z, presence [B, N], bg [B, Q] → frame [B, H, W, C]."""
        b, n = what.shape[:2]
        logits = self.glimpse_decoder(what.reshape(b * n, -1))
        rgb, alpha = glimpse_rgba(logits.reshape(b, n, *logits.shape[1:]))
        return render_objects(rgb, alpha, where, z, presence, self.bg_decoder(bg), self.config)

    @staticmethod
    def _flat(where, presence, depth, what, bg) -> jax.Array:
        """[B, N·(6 + K) + Q]: per cell (where, presence, depth, what), cells row-major, then bg."""
        cells = jnp.concatenate([where, presence[..., None], depth, what], axis=-1)
        return jnp.concatenate([cells.reshape(cells.shape[0], -1), bg], axis=-1)

    def __call__(self, x, a, key, train: bool = True) -> Outputs:
        c = self.config
        img = x[:, -1]
        b, n = img.shape[0], c.cells
        k_where, k_what, k_depth, k_pres, k_bg = jax.random.split(key, 5)
        noise = (jax.random.normal(k_where, (b, n, WHERE)),
                 jax.random.normal(k_what, (b, n, c.what_dim)),
                 jax.random.normal(k_depth, (b, n, 1)),
                 logistic_noise(k_pres, (b, n)))
        # Training steps so far: they drive the training wheels and the count prior's annealing.
        step = self.steps.value
        if train and self.is_mutable_collection("batch_stats") and not self.is_initializing():
            self.steps.value = step + 1.0
        wheels = c.training_wheels(step) if train else 0.0
        lat, (bg_mu, bg_logvar) = self.infer(img, noise, c.temperature, train, wheels)
        bg = elbo.reparameterize(k_bg, bg_mu, bg_logvar)
        recon = self.render(lat["where"], lat["what"], lat["z"], lat["pres"], bg)

        # The count prior of the presences (SPAIR): each cell's prior given the earlier cells'
        # hard presences, under the annealed geometric prior on the number of objects.
        hard = jax.lax.stop_gradient((lat["pres"] > 0.5).astype(jnp.float32))
        prior = presence_prior(hard, c.count_prior_log_odds(step))
        pres = lat["pres"]  # SPAIR weighs each object's KLs by its (relaxed) presence
        hw_logvar = 2.0 * math.log(c.hw_prior_std)
        where_prior_mu = jnp.asarray([0.0, 0.0, c.hw_prior_mean, c.hw_prior_mean])
        where_prior_logvar = jnp.asarray([0.0, 0.0, hw_logvar, hw_logvar])
        kl = {
            "where": jnp.sum(pres * elbo.gaussian_kl(lat["where_mu"], lat["where_logvar"],
                                                     where_prior_mu, where_prior_logvar), -1),
            "what": jnp.sum(pres * elbo.kl_to_standard_normal(lat["what_mu"],
                                                              lat["what_logvar"]), -1),
            "depth": jnp.sum(pres * elbo.kl_to_standard_normal(lat["depth_mu"],
                                                               lat["depth_logvar"]), -1),
            "pres": jnp.sum(bernoulli_kl(lat["pres_logit"], prior), axis=-1),
            "bg": elbo.kl_to_standard_normal(bg_mu, bg_logvar),
        }
        z = self._flat(lat["where"], lat["pres"], lat["depth"], lat["what"], bg)[:, None]
        return Outputs(recon=recon[:, None], kl=kl, z=z)

    def _means(self, x):
        """Posterior means through the same raster-order inference (zero noise, presence
        probabilities σ(logit) passed to the neighbours)."""
        c = self.config
        img = x[:, -1]
        b, n = img.shape[0], c.cells
        zeros = (jnp.zeros((b, n, WHERE)), jnp.zeros((b, n, c.what_dim)), jnp.zeros((b, n, 1)),
                 jnp.zeros((b, n)))
        lat, (bg, _) = self.infer(img, zeros, 1.0, False)
        return lat, bg

    def encode(self, x, a) -> jax.Array:
        """[B, N·(6 + K) + Q]: posterior means (where, depth pre-sigmoid), presence
        probabilities, what means, then the background mean."""
        lat, bg = self._means(x)
        return self._flat(lat["where"], lat["pres"], lat["depth"], lat["what"], bg)

    def reconstruct(self, x, a) -> jax.Array:
        """[B, 1, H, W, C]: rendered from the means and the presence probabilities."""
        lat, bg = self._means(x)
        return self.render(lat["where"], lat["what"], lat["z"], lat["pres"], bg)[:, None]

    def pixel_boxes(self, x, a) -> tuple[jax.Array, jax.Array]:
        """([B, N, 4] (x0, y0, x1, y1) in pixels, [B, N] presence probabilities), means."""
        lat, _ = self._means(x)
        return pixel_boxes(*boxes(lat["where"], self.config)), lat["pres"]


# --- Boxes over frames -------------------------------------------------------------------------


def draw_boxes(frames, box_px, presence, threshold: float = 0.5,
               colour=(255, 0, 0)) -> np.ndarray:
    """uint8 [M, H, W, 3] frames with 1-pixel outlines of the boxes whose presence > threshold.

    box_px [M, N, 4]: (x0, y0, x1, y1) pixel-edge coordinates; the outline runs along the
    pixels just inside the box, clipped to the frame (a box wholly outside draws nothing).
    """
    out = np.array(frames, dtype=np.uint8, copy=True)
    box_px, presence = np.asarray(box_px, np.float64), np.asarray(presence)
    h, w = out.shape[1:3]
    for m, n in zip(*np.nonzero(presence > threshold), strict=True):
        x0, y0, x1, y1 = box_px[m, n]
        c0, r0 = int(np.floor(x0)), int(np.floor(y0))
        c1, r1 = int(np.ceil(x1)) - 1, int(np.ceil(y1)) - 1
        if c1 < 0 or r1 < 0 or c0 >= w or r0 >= h:
            continue
        cs, ce = max(c0, 0), min(max(c1, c0), w - 1)
        rs, re = max(r0, 0), min(max(r1, r0), h - 1)
        for r in (r0, max(r1, r0)):
            if 0 <= r < h:
                out[m, r, cs:ce + 1] = colour
        for col in (c0, max(c1, c0)):
            if 0 <= col < w:
                out[m, rs:re + 1, col] = colour
    return out


@dataclasses.dataclass(frozen=True)
class SPAIRLearner(Learner):
    """A `Learner` with SPAIR's boxes: `boxes` and `draw_boxes` (the stream's analysis PNGs)."""

    def boxes(self, variables, frames) -> tuple[jax.Array, jax.Array]:
        """frames uint8 [M, 64, 64, 3] → ([M, N, 4] boxes (x0, y0, x1, y1) in pixels, [M, N]
        presence probabilities), from the posterior means (BatchNorm in eval mode). One jitted
        program (eagerly, the cell scan's ops would compile one by one)."""
        return self._jit_boxes(variables, frames)

    def _boxes(self, variables, frames):
        frames = jnp.asarray(frames)[:, None]
        x, a = self.check_batch(frames, jnp.zeros((frames.shape[0], 1, 1), jnp.float32))
        return self.module.apply(variables, x, a, method="pixel_boxes")

    @functools.cached_property
    def _jit_boxes(self):
        return jax.jit(self._boxes)

    def draw_boxes(self, variables, frames, threshold: float = 0.5) -> np.ndarray:
        """uint8 [M, 64, 64, 3]: the frames with the boxes of present objects drawn in red."""
        box_px, presence = self.boxes(variables, frames)
        return draw_boxes(frames, box_px, presence, threshold)


def make_spair(name: str, config: SPAIRConfig) -> Learner:
    weights = dict.fromkeys(("where", "what", "depth", "pres", "bg"), config.beta)
    return SPAIRLearner(name, config, SPAIR(config), weights)
