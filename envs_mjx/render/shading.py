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


def _unit(x, y, z):
    inv = 1.0 / jnp.sqrt(jnp.maximum(x * x + y * y + z * z, 1e-24))
    return x * inv, y * inv, z * inv


def shade(base, normal, view_dir, light_dirs, light_diffuse, light_specular, ambient, specular,
          shininess, emission):
    """Blinn–Phong with a few directional lights, in the spirit of MuJoCo's fixed-function lights.

    base: [P, 3] material colour in [0, 1]; normal: [P, 3] world normals (any length, any side);
    view_dir: [P, 3] ray directions (camera to surface); light_dirs: [L, 3] directions the
    lights travel; light_diffuse, light_specular: [L, 3]; ambient: [3]; specular, shininess,
    emission: [P] material scalars (MuJoCo's mat_*). Returns [P, 3] in [0, 1].
    """
    # Per-component [P] arrays and a static loop over the few lights: XLA:CPU fuses this into
    # one elementwise loop, where reductions over size-3 minor axes ran several times slower.
    vx, vy, vz = _unit(view_dir[:, 0], view_dir[:, 1], view_dir[:, 2])
    nx, ny, nz = _unit(normal[:, 0], normal[:, 1], normal[:, 2])
    # Surfaces are lit on the side the camera sees (planes and meshes are two-sided).
    flip = jnp.where(nx * vx + ny * vy + nz * vz > 0.0, -1.0, 1.0)
    nx, ny, nz = nx * flip, ny * flip, nz * flip
    # MuJoCo scales shininess in [0, 1] to an OpenGL exponent in [0, 128].
    expo = jnp.maximum(shininess * 128.0, 1.0)
    diffuse = jnp.zeros_like(base)
    highlight = jnp.zeros_like(base)
    for i in range(light_dirs.shape[0]):
        lx, ly, lz = _unit(-light_dirs[i, 0], -light_dirs[i, 1], -light_dirs[i, 2])
        lambert = jnp.maximum(nx * lx + ny * ly + nz * lz, 0.0)
        hx, hy, hz = _unit(lx - vx, ly - vy, lz - vz)
        n_h = jnp.maximum(nx * hx + ny * hy + nz * hz, 1e-30)
        spec = jnp.where(lambert > 0.0, jnp.exp(expo * jnp.log(n_h)), 0.0)
        diffuse = diffuse + lambert[:, None] * light_diffuse[i]
        highlight = highlight + spec[:, None] * light_specular[i]
    rgb = base * (ambient + diffuse + emission[:, None]) + specular[:, None] * highlight
    return jnp.clip(rgb, 0.0, 1.0)
