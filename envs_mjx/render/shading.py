"""Surface colour: material colour times texture (nearest texel, trilinear from mip levels, or a
box-filtered checker), directional lights, ambient."""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax


def sample_texture(tex_rgb, tex_adr, tex_w, tex_h, tex_id, u, v):
    """Nearest-texel lookup with wrap-around (texrepeat tiles the texture).

    tex_rgb: [N, 3] all 2-D textures' texels, flattened and concatenated, in [0, 1];
    tex_adr, tex_w, tex_h: [ntex] int32 where each texture starts and its size;
    tex_id: [P] int32 (any value where no texture applies, the caller masks it);
    u, v: [P] texture coordinates. Returns [P, 3].
    """
    tid = jnp.clip(tex_id, 0, tex_adr.shape[0] - 1)
    w, h = tex_w[tid], tex_h[tid]
    col = jnp.clip(((u - jnp.floor(u)) * w).astype(jnp.int32), 0, w - 1)
    row = jnp.clip(((v - jnp.floor(v)) * h).astype(jnp.int32), 0, h - 1)
    return tex_rgb[tex_adr[tid] + row * w + col]


def sample_mip(tex_mip, tex_mip_adr, tex_w, tex_h, tex_id, u, v, lod):
    """Bilinear lookup with wrap-around in the mip level nearest `lod` (OpenGL's
    LINEAR_MIPMAP_NEAREST); lod <= 0.5 (magnification, or about one texel per pixel) reads
    level 0.

    Nearly as close to mujoco.Renderer's trilinear (LINEAR_MIPMAP_LINEAR) as trilinear
    sampling, with 4 gathers instead of 8 (docs/notes/render.md).

    tex_mip: [M] int32 packed texels of every level (context.mip_levels, r | g << 8 | b << 16);
    tex_mip_adr: [ntex, L] int32 where each level starts; tex_w, tex_h: [ntex] level-0 size;
    tex_id: [P] int32; u, v, lod: [P]. Returns three [P] channels in [0, 1].
    """
    tid = jnp.clip(tex_id, 0, tex_mip_adr.shape[0] - 1)
    n_levels = tex_mip_adr.shape[1]
    level = jnp.clip((lod + 0.5).astype(jnp.int32), 0, n_levels - 1)
    lw, lh = jnp.maximum(tex_w[tid] >> level, 1), jnp.maximum(tex_h[tid] >> level, 1)
    adr = tex_mip_adr.reshape(-1)[tid * n_levels + level]
    # Texel centres sit at half-integers: x = u w - 1/2 lies between texels x0 and x0 + 1.
    x = (u - jnp.floor(u)) * lw.astype(jnp.float32) - 0.5
    y = (v - jnp.floor(v)) * lh.astype(jnp.float32) - 0.5
    x0, y0 = jnp.floor(x), jnp.floor(y)
    fx, fy = x - x0, y - y0
    x0 = jnp.where(x0 < 0.0, lw - 1, x0.astype(jnp.int32))  # x >= -1/2: only -1 wraps
    y0 = jnp.where(y0 < 0.0, lh - 1, y0.astype(jnp.int32))
    x1 = jnp.where(x0 + 1 >= lw, 0, x0 + 1)
    y1 = jnp.where(y0 + 1 >= lh, 0, y0 + 1)
    out = [0.0, 0.0, 0.0]
    for row, col, weight in ((y0, x0, (1.0 - fx) * (1.0 - fy)), (y0, x1, fx * (1.0 - fy)),
                             (y1, x0, (1.0 - fx) * fy), (y1, x1, fx * fy)):
        # Separate gathers: one gather of stacked indices is slower here (docs/notes/render.md).
        texel = tex_mip[adr + row * lw + col]
        weight = weight * (1.0 / 255.0)
        out = [o + ((texel >> shift) & 0xFF).astype(jnp.float32) * weight
               for o, shift in zip(out, (0, 8, 16), strict=True)]
    return out


def square_wave_mean(u, width, min_width=1e-2):
    """Mean of the period-1 square wave (+1 on [0, 1/2), -1 on [1/2, 1)) over
    [u - width / 2, u + width / 2]: one axis of a box-filtered checker. Its integral is the
    triangle wave 1/2 - |frac(x) - 1/2|, so the mean is a difference of two of those over width.
    Below min_width (a hundredth of a period) it is the point sample, where float32 u (up to a
    few hundred periods) would leave the difference mostly rounding error."""
    def ramp(x):
        return 0.5 - jnp.abs(x - jnp.floor(x) - 0.5)

    w = jnp.maximum(width, min_width)
    box = (ramp(u + 0.5 * w) - ramp(u - 0.5 * w)) / w
    point = jnp.where(u - jnp.floor(u) < 0.5, 1.0, -1.0)
    return jnp.where(width > min_width, box, point)


def rsqrt(v):
    """1/sqrt(v) for v > 0 to float32 precision (relative error < 3e-7).

    XLA:CPU rewrites 1/sqrt(v) into an rsqrt that runs far slower than a multiply; an initial
    guess from the float's bits and three Newton steps stay vectorised.
    """
    i = lax.bitcast_convert_type(v, jnp.int32)
    y = lax.bitcast_convert_type(jnp.int32(0x5F375A86) - (i >> 1), jnp.float32)
    for _ in range(3):
        y = y * (1.5 - 0.5 * v * y * y)
    return y


# Least-squares polynomial fits (Chebyshev nodes): log2(1 + m) on m in [0, 1) to 2.2e-6 absolute,
# 2^f on f in [0, 1) to 1.1e-7 relative. Highest degree first.
_LOG2 = (-2.51232033e-02, 1.19298238e-01, -2.74623258e-01, 4.55527088e-01, -7.17557872e-01,
         1.44247531e+00, 2.12374089e-06)
_EXP2 = (0.00189511, 0.00894621, 0.05586328, 0.24014077, 0.69315462, 0.9999999)


def _horner(coefs, x):
    acc = coefs[0]
    for c in coefs[1:]:
        acc = acc * x + c
    return acc


def log2(x):
    """log2(x) for normal positive float32 x, to 2.2e-6 absolute, through the exponent bits and
    a polynomial (XLA:CPU's log costs as much as the rest of a shading loop, see spec_pow)."""
    i = lax.bitcast_convert_type(x, jnp.int32)
    mant = lax.bitcast_convert_type((i & 0x7FFFFF) | 0x3F800000, jnp.float32) - 1.0
    return ((i >> 23) - 127).astype(jnp.float32) + _horner(_LOG2, mant)


def spec_pow(base, expo):
    """base ** expo for base in (0, 1], expo >= 0, to ~3e-4 relative for expo <= 128.

    Through the float's exponent bits and two short polynomials: XLA:CPU's exp and log inside
    the shading loop cost as much as the rest of shading together.
    """
    y = jnp.maximum(expo * log2(base), -126.0)
    yi = jnp.floor(y)
    frac = _horner(_EXP2, y - yi)  # in [1, 2)
    bits = lax.bitcast_convert_type(frac, jnp.int32) + (yi.astype(jnp.int32) << 23)
    return lax.bitcast_convert_type(bits, jnp.float32)


def _unit(x, y, z):
    inv = rsqrt(jnp.maximum(x * x + y * y + z * z, 1e-24))
    return x * inv, y * inv, z * inv


def _materials(ctx, geom):
    """Per-pixel material constants by a select chain over the drawable geoms (no gathers):
    base rgb, specular, shininess exponent, emission, each [P]."""
    zero = jnp.zeros(geom.shape, jnp.float32)
    out = [zero] * 6
    for ids in ctx.group_geoms:
        for g in ids:
            mask = geom == g
            vals = (ctx.geom_rgb[g, 0], ctx.geom_rgb[g, 1], ctx.geom_rgb[g, 2],
                    ctx.geom_specular[g],
                    # MuJoCo scales shininess in [0, 1] to an OpenGL exponent in [0, 128].
                    jnp.maximum(ctx.geom_shininess[g] * 128.0, 1.0), ctx.geom_emission[g])
            out = [jnp.where(mask, val, o) for val, o in zip(vals, out, strict=True)]
    return out


def shade(ctx, hit, geom, rays, light_dirs):
    """Blinn–Phong in the camera frame, in the spirit of MuJoCo's fixed-function lights.

    hit: the renderer's per-pixel nearest hit (camera-frame normal nx, ny, nz; texture u, v,
    tex); geom: [P] int32 geom id (-1 for none); rays: [8, P] the pixels' rows of ctx.rays;
    light_dirs: per light, the camera-frame direction it travels, or None for the headlight
    (travelling along the view axis, whose half vectors are per-pixel constants in rays).
    Returns three [P] channels in [0, 1].
    """
    vx, vy, vz = rays[2], rays[3], rays[4]  # unit view direction, camera to surface
    nx, ny, nz = _unit(hit.nx, hit.ny, hit.nz)
    # Surfaces are lit on the side the camera sees (planes and meshes are two-sided).
    flip = jnp.where(nx * vx + ny * vy + nz * vz > 0.0, -1.0, 1.0)
    nx, ny, nz = nx * flip, ny * flip, nz * flip
    r, g, b, specular, expo, emission = _materials(ctx, geom)
    if ctx.textured_geoms:
        texel = [jnp.ones_like(r)] * 3
        filtered = set(ctx.checker_geoms) | set(ctx.mip_geoms)
        if any(g not in filtered for g in ctx.textured_geoms):
            rgb = sample_texture(ctx.tex_rgb, ctx.tex_adr, ctx.tex_w, ctx.tex_h, hit.tex, hit.u,
                                 hit.v)
            texel = [rgb[:, i] for i in range(3)]
        if ctx.mip_geoms:
            mip = sample_mip(ctx.tex_mip, ctx.tex_mip_adr, ctx.tex_w, ctx.tex_h, hit.tex, hit.u,
                             hit.v, hit.lod)
            on = geom == ctx.mip_geoms[0]
            for gid in ctx.mip_geoms[1:]:
                on = on | (geom == gid)
            texel = [jnp.where(on, a, b) for a, b in zip(mip, texel, strict=True)]
        for gid in ctx.checker_geoms:  # u carries the filtered checker value in [-1, 1]
            mask = geom == gid
            mid, half = ctx.geom_checker[gid, 0], ctx.geom_checker[gid, 1]
            texel = [jnp.where(mask, mid[i] + half[i] * hit.u, t) for i, t in enumerate(texel)]
        use = hit.tex >= 0
        r, g, b = (jnp.where(use, c * texel[i], c) for i, c in enumerate((r, g, b)))
    diffuse = [ctx.ambient[i] + emission for i in range(3)]
    highlight = [0.0, 0.0, 0.0]
    for i, ldir in enumerate(light_dirs):
        if ldir is None:  # headlight: towards the light is +z, the half vector is precomputed
            lambert = jnp.maximum(nz, 0.0)
            n_h = nx * rays[5] + ny * rays[6] + nz * rays[7]
        else:
            lx, ly, lz = _unit(-ldir[0], -ldir[1], -ldir[2])
            lambert = jnp.maximum(nx * lx + ny * ly + nz * lz, 0.0)
            hx, hy, hz = _unit(lx - vx, ly - vy, lz - vz)
            n_h = nx * hx + ny * hy + nz * hz
        n_h = jnp.maximum(n_h, 1e-30)
        spec = jnp.where(lambert > 0.0, spec_pow(n_h, expo), 0.0)
        for c in range(3):
            diffuse[c] = diffuse[c] + lambert * ctx.light_diffuse[i, c]
            highlight[c] = highlight[c] + spec * ctx.light_specular[i, c]
    return [jnp.clip(base * diffuse[c] + specular * highlight[c], 0.0, 1.0)
            for c, base in enumerate((r, g, b))]
