"""Surface colour: material colour times texture (nearest texel), one directional light, ambient."""

from __future__ import annotations

import jax.numpy as jnp


def sample_texture(tex_rgb, tex_adr, tex_w, tex_h, tex_id, uv):
    """Nearest-texel lookup with wrap-around (texrepeat tiles the texture).

    tex_rgb: [N, 3] all 2-D textures' texels, flattened and concatenated, in [0, 1];
    tex_adr, tex_w, tex_h: [ntex] int32 where each texture starts and its size;
    tex_id: [P] int32 (any value where no texture applies, the caller masks it);
    uv: [P, 2] texture coordinates. Returns [P, 3].
    """
    tid = jnp.clip(tex_id, 0, tex_adr.shape[0] - 1)
    w, h = tex_w[tid], tex_h[tid]
    frac = uv - jnp.floor(uv)
    col = jnp.clip((frac[:, 0] * w).astype(jnp.int32), 0, w - 1)
    row = jnp.clip((frac[:, 1] * h).astype(jnp.int32), 0, h - 1)
    return tex_rgb[tex_adr[tid] + row * w + col]


def _normalize(v):
    return v / jnp.maximum(jnp.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def shade(base, normal, view_dir, light_dirs, light_diffuse, light_specular, ambient, specular,
          shininess, emission):
    """Blinn–Phong with a few directional lights, in the spirit of MuJoCo's fixed-function lights.

    base: [P, 3] material colour in [0, 1]; normal: [P, 3] world normals (any length, any side);
    view_dir: [P, 3] ray directions (camera to surface); light_dirs: [L, 3] directions the
    lights travel; light_diffuse, light_specular: [L, 3]; ambient: [3]; specular, shininess,
    emission: [P] material scalars (MuJoCo's mat_*). Returns [P, 3] in [0, 1].
    """
    v = _normalize(view_dir)
    n = _normalize(normal)
    # Surfaces are lit on the side the camera sees (planes and meshes are two-sided).
    n = jnp.where(jnp.sum(n * v, axis=-1, keepdims=True) > 0.0, -n, n)
    to_light = -_normalize(light_dirs)  # [L, 3]
    lambert = jnp.maximum(n @ to_light.T, 0.0)  # [P, L]
    half = _normalize(to_light[None] - v[:, None])  # [P, L, 3]
    # MuJoCo scales shininess in [0, 1] to an OpenGL exponent in [0, 128].
    expo = jnp.maximum(shininess * 128.0, 1.0)[:, None]
    n_h = jnp.maximum(jnp.sum(n[:, None] * half, axis=-1), 0.0)
    spec = jnp.where(lambert > 0.0, n_h ** expo, 0.0)  # [P, L]
    rgb = (base * (ambient + lambert @ light_diffuse + emission[:, None])
           + specular[:, None] * (spec @ light_specular))
    return jnp.clip(rgb, 0.0, 1.0)
