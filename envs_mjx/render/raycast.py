"""The ray caster: one primary ray per pixel against every geom, nearest hit shaded.

Everything runs in the camera frame on component arrays with pixels as the contiguous axis
(feature-major): a pixel's ray is (x, y, -1), so a geom's local ray direction is affine in
(x, y) and each primitive test is one fused elementwise loop over pixels. The nearest hit and
its material are carried through a static loop over geoms with selects (no gathers, no
argmin over a small minor axis). Meshes are tested with camera-space edge functions (see
`_mesh_hits`), a max-reduction over triangles with pixels contiguous.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import mujoco
from jax import lax

from envs_mjx.render import intersect, shading
from envs_mjx.render.context import RenderContext

_G = mujoco.mjtGeom
_PRIMITIVES = {
    int(_G.mjGEOM_PLANE): (intersect.hit_plane, intersect.normal_plane),
    int(_G.mjGEOM_SPHERE): (intersect.hit_sphere, intersect.normal_sphere),
    int(_G.mjGEOM_CAPSULE): (intersect.hit_capsule, intersect.normal_capsule),
    int(_G.mjGEOM_ELLIPSOID): (intersect.hit_ellipsoid, intersect.normal_ellipsoid),
    int(_G.mjGEOM_CYLINDER): (intersect.hit_cylinder, intersect.normal_cylinder),
    int(_G.mjGEOM_BOX): (intersect.hit_box, intersect.normal_box),
}


class RenderOutput(NamedTuple):
    """One frame. rgb: uint8 [H, W, 3]; depth: float32 [H, W] linear depth (zfar where empty);
    segmentation: int32 [H, W] geom id, -1 for background."""

    rgb: jnp.ndarray
    depth: jnp.ndarray
    segmentation: jnp.ndarray


class _Hit(NamedTuple):
    """The nearest hit so far, per pixel; every field is [P] (camera-frame components)."""

    t: jnp.ndarray  # distance in units of the ray direction (= depth), +inf on a miss
    geom: jnp.ndarray  # int32 geom id, -1 on a miss
    nx: jnp.ndarray  # camera-frame normal, unnormalised
    ny: jnp.ndarray
    nz: jnp.ndarray
    u: jnp.ndarray  # texture coordinates, meaningful where tex >= 0
    v: jnp.ndarray
    tex: jnp.ndarray  # int32 packed-texture index, -1 for an untextured surface


def _select(mask, new: _Hit, old: _Hit) -> _Hit:
    return _Hit(*(jnp.where(mask, a, b) for a, b in zip(new, old, strict=True)))


def _primitive(ctx, gtype, size, g, m, o_l, x, y, best: _Hit) -> _Hit:
    """Test geom g (local frame: camera-to-local rotation m [3, 3], ray origin o_l [3])."""
    hit_fn, normal_fn = _PRIMITIVES[gtype]
    # Local direction of the ray (x, y, -1): affine in the pixel coordinates.
    d_l = tuple(m[0, j] * x + m[1, j] * y - m[2, j] for j in range(3))
    o = (o_l[0], o_l[1], o_l[2])
    s = (size[0], size[1], size[2])
    t = hit_fn(o, d_l, s, ctx.znear)
    closer = t < best.t
    t_safe = jnp.where(closer, t, 0.0)
    p_l = tuple(o[j] + t_safe * d_l[j] for j in range(3))
    n_l = normal_fn(p_l, s)
    n_c = [m[i, 0] * n_l[0] + m[i, 1] * n_l[1] + m[i, 2] * n_l[2] for i in range(3)]
    u = v = best.u
    tex = jnp.int32(-1)
    if gtype == int(_G.mjGEOM_PLANE) and g in ctx.textured_geoms:
        corner, scale = ctx.geom_uvorigin[g], ctx.geom_uvscale[g]
        u = (p_l[0] + corner[0]) * scale[0]
        v = (corner[1] - p_l[1]) * scale[1]
        tex = ctx.geom_tex[g]
        if g in ctx.checker_geoms:
            # One texel per pixel aliases a checker into moire at 64 x 64 (MuJoCo mipmaps it);
            # instead average it over the pixel's footprint in uv. The ray (x, y, -1) meets
            # local z = 0 at t = -o_z / d_z, so d p_l / dx = t (m[0, :] - m[0, 2] d_l / d_z) (m[1]
            # for y), with 1 / d_z = -t / o_z; the footprint's extent along u is
            # pitch (|du/dx| + |du/dy|), likewise v. The filtered value goes in u (v unused).
            neg_inv_oz = -1.0 / jnp.where(jnp.abs(o[2]) > 1e-9, o[2], 1e-9)
            k = ctx.pixel_pitch * t_safe
            a0 = d_l[0] * (t_safe * neg_inv_oz)
            a1 = d_l[1] * (t_safe * neg_inv_oz)
            wu = scale[0] * k * (jnp.abs(m[0, 0] - m[0, 2] * a0) + jnp.abs(m[1, 0] - m[1, 2] * a0))
            wv = scale[1] * k * (jnp.abs(m[0, 1] - m[0, 2] * a1) + jnp.abs(m[1, 1] - m[1, 2] * a1))
            u = v = shading.square_wave_mean(u, wu) * shading.square_wave_mean(v, wv)
    new = _Hit(t, jnp.int32(g), *n_c, u, v, tex)
    return _select(closer, new, best)


def _mesh_tables(ctx, geom_xpos, geom_xmat, cam_xpos, cam_xmat):
    """Per-frame triangle data for `_mesh_hits`: edge-function coefficients and a per-triangle
    table (coefficients, camera-frame normal, corner uv, geom id, texture)."""
    mesh = ctx.mesh
    ids = jnp.asarray(mesh.geom)  # [Gm]
    rot = jnp.einsum("ji,gjk->gik", cam_xmat, geom_xmat[ids])  # [Gm, 3, 3] local -> camera
    pos = jnp.einsum("ji,gj->gi", cam_xmat, geom_xpos[ids] - cam_xpos)  # [Gm, 3]
    a = jnp.einsum("gij,gtj->gti", rot, mesh.v0) + pos[:, None]  # [Gm, T, 3]
    e1 = jnp.einsum("gij,gtj->gti", rot, mesh.e1)
    e2 = jnp.einsum("gij,gtj->gti", rot, mesh.e2)
    b, c = a + e1, a + e2
    normal = jnp.cross(e1, e2)
    det = jnp.sum(normal * a, axis=-1)
    # Edge-on triangles (plane through the camera) and padding get all-zero weights: never hit.
    ok = mesh.valid & (jnp.abs(det) > 1e-20)
    inv_det = jnp.where(ok, 1.0 / jnp.where(ok, det, 1.0), 0.0)
    sign_z = jnp.array([1.0, 1.0, -1.0], jnp.float32)
    coef = jnp.stack([jnp.cross(b, c), jnp.cross(c, a), jnp.cross(a, b)], axis=-2)
    coef = coef * (inv_det[..., None, None] * sign_z)  # [Gm, T, 3 corners, (cx, cy, c1)]
    n_tri = coef.shape[0] * coef.shape[1]
    coef = coef.reshape(n_tri, 3, 3)
    geom_of_tri = jnp.repeat(ids, mesh.valid.shape[1])
    tex_of_tri = jnp.where(jnp.repeat(mesh.has_uv, mesh.valid.shape[1]),
                           ctx.geom_tex[geom_of_tri], -1)
    columns = [normal.reshape(n_tri, 3), geom_of_tri[:, None].astype(jnp.float32)]
    if any(g in ctx.textured_geoms for g in mesh.geom):  # uv only where a texture is drawn
        columns += [mesh.uv.reshape(n_tri, 6), tex_of_tri[:, None].astype(jnp.float32)]
    # [Gm*T, 4 or 11]: normal, geom id, then corner uv, texture
    table = jnp.concatenate(columns, axis=1)
    return coef, table


def _mesh_hits(ctx, coef, table, x, y, best: _Hit) -> _Hit:
    """Nearest triangle of every mesh geom by camera-space edge functions.

    With the camera at the origin and triangle corners A, B, C in the camera frame, the ray
    r = (x, y, -1) meets the triangle's plane at t = det(A, B, C) / (N·r), N = (B-A)×(C-A), and
    w_A = (B×C)·r / det, w_B = (C×A)·r / det, w_C = (A×B)·r / det are affine in (x, y), sum to
    1/t, and are all >= 0 exactly when the ray passes through the triangle in front of the
    camera (either side facing it). Per triangle-pixel pair that is 6 multiply-adds and a few
    compares, no division: the nearest hit is the largest 1/t. Barycentrics are w / (1/t).
    """
    # A scan over triangles carrying, per pixel, one int32: the bits of the best 1/t (positive
    # floats order like their bit patterns) with the low bits replaced by the triangle index.
    # One carry keeps each step a single fused elementwise loop with pixels contiguous; two
    # carries (1/t and index) made XLA evaluate the edge functions twice, and a max/argmax
    # reduction over a [T, P] array did not vectorise across pixels (3-4x slower). Triangles
    # closer than 2^-(23 - index bits) relative depth tie-break by index; the winner's exact
    # 1/t is recomputed below.
    n_tri = coef.shape[0]
    bits = max(1, (n_tri - 1).bit_length())
    low = jnp.int32((1 << bits) - 1)
    inv_znear = 1.0 / ctx.znear

    def step(carry, c):
        best_key, i = carry
        w0, w1, w2 = (c[k, 0] * x + c[k, 1] * y + c[k, 2] for k in range(3))
        inv_t = w0 + w1 + w2
        key = (lax.bitcast_convert_type(inv_t, jnp.int32) & ~low) | i
        better = ((jnp.minimum(jnp.minimum(w0, w1), w2) >= 0.0) & (inv_t > 0.0)
                  & (inv_t < inv_znear) & (key > best_key))
        return (jnp.where(better, key, best_key), i + 1), None

    init = (jnp.full(x.shape, -1, jnp.int32), jnp.int32(0))
    (best_key, _), _ = lax.scan(step, init, coef, unroll=min(16, n_tri))
    found = best_key >= 0
    tri = jnp.where(found, best_key & low, 0)
    c = coef.reshape(n_tri, 9)[tri]  # [P, 9] the winner's edge coefficients
    inv_t = sum(c[:, 3 * k] * x + c[:, 3 * k + 1] * y + c[:, 3 * k + 2] for k in range(3))
    t = jnp.where(found, 1.0 / jnp.where(found, inv_t, 1.0), jnp.inf)
    closer = t < best.t

    row = table[tri]  # [P, 4 or 11]: one gather of the winning triangles' data
    u = v = best.u
    tex = jnp.int32(-1)
    if table.shape[1] > 4:
        bary = [(c[:, 3 * k] * x + c[:, 3 * k + 1] * y + c[:, 3 * k + 2]) * t for k in range(3)]
        u = bary[0] * row[:, 4] + bary[1] * row[:, 6] + bary[2] * row[:, 8]
        v = bary[0] * row[:, 5] + bary[1] * row[:, 7] + bary[2] * row[:, 9]
        tex = row[:, 10].astype(jnp.int32)
    new = _Hit(t, row[:, 3].astype(jnp.int32), row[:, 0], row[:, 1], row[:, 2], u, v, tex)
    return _select(closer, new, best)


def render(ctx: RenderContext, data) -> RenderOutput:
    """Render one frame from `data` (mjx.Data, mujoco.MjData or anything with geom_xpos,
    geom_xmat, cam_xpos, cam_xmat). Jittable and vmappable over data."""
    geom_xpos = jnp.asarray(data.geom_xpos, jnp.float32)
    geom_xmat = jnp.asarray(data.geom_xmat, jnp.float32).reshape(-1, 3, 3)
    cam_xpos = jnp.asarray(data.cam_xpos, jnp.float32)[ctx.cam_id]
    cam_xmat = jnp.asarray(data.cam_xmat, jnp.float32).reshape(-1, 3, 3)[ctx.cam_id]
    frames = []  # per primitive geom: (type, group index, index in group, id, m, o_l)
    for gi, (gtype, ids) in enumerate(zip(ctx.group_types, ctx.group_geoms, strict=True)):
        if gtype == int(_G.mjGEOM_MESH):
            continue
        for k, g in enumerate(ids):
            rot, pos = geom_xmat[g], geom_xpos[g]
            m = cam_xmat.T @ rot  # camera frame -> local frame is m.T
            frames.append((gtype, gi, k, g, m, rot.T @ (cam_xpos - pos)))
    mesh = None
    if ctx.mesh is not None:
        mesh = _mesh_tables(ctx, geom_xpos, geom_xmat, cam_xpos, cam_xmat)
    light_dirs = [None]  # None: the headlight, which travels along the camera's view axis
    if ctx.light_id >= 0:
        xdir = getattr(data, "light_xdir", None)  # MjData has it; mjx.Data does not
        ldir = (ctx.light_dir if xdir is None
                else jnp.asarray(xdir, jnp.float32).reshape(-1, 3)[ctx.light_id])
        light_dirs.append(cam_xmat.T @ ldir)

    def pixels(rays):
        """Everything per pixel: rays [8, P] -> packed rgb, depth, geom, each [P]."""
        x, y = rays[0], rays[1]  # camera-frame ray direction (x, y, -1)
        inf = jnp.full(x.shape, jnp.inf, jnp.float32)
        zero = jnp.zeros(x.shape, jnp.float32)
        none = jnp.full(x.shape, -1, jnp.int32)
        best = _Hit(inf, none, zero, zero, zero, zero, zero, none)
        for gtype, gi, k, g, m, o_l in frames:
            best = _primitive(ctx, gtype, ctx.group_size[gi][k], g, m, o_l, x, y, best)
        if mesh is not None:
            best = _mesh_hits(ctx, *mesh, x, y, best)
        found = best.t <= ctx.zfar
        geom = jnp.where(found, best.geom, -1)
        rgb = shading.shade(ctx, best, geom, rays, light_dirs)
        rgb8 = [jnp.round(jnp.where(found, rgb[i], ctx.background[i]) * 255.0)
                .astype(jnp.uint32) for i in range(3)]
        # Channels leave as one packed uint32 per pixel: a [P, 3] stack fused with shading
        # ran unvectorised and recomputed shading per channel (10x slower).
        packed = rgb8[0] | (rgb8[1] << 8) | (rgb8[2] << 16)
        return packed, jnp.where(found, best.t, ctx.zfar), geom

    # (Running pixels through in chunks with lax.map, to keep a chunk's intermediates in cache
    # between XLA's fused loops, measured 5x slower on XLA:CPU.)
    packed, depth, geom = pixels(ctx.rays)
    if ctx.mesh is None:
        # A one-trip loop that XLA cannot prove to be one trip (nor its body the identity)
        # makes `packed` a materialised buffer; otherwise the byte slice below fuses with
        # shading, which then runs unvectorised once per channel. Measured on the 2-core CPU:
        # 1.1-1.2x at batch 64 and ~3x at batch 256 on the primitive-only cartpole, but 1.3-1.5x
        # slower on the mesh scene (and ~20% slower at batch 1), hence primitives only.
        trips = 1 + (ctx.cam_id < 0).astype(jnp.int32)  # cam_id >= 0: always 1
        packed = lax.fori_loop(0, trips, lambda i, p: p | (i < 0).astype(jnp.uint32), packed)
    rgb8 = lax.bitcast_convert_type(packed, jnp.uint8)[:, :3]  # little-endian byte order
    shape = (ctx.height, ctx.width)
    return RenderOutput(rgb=rgb8.reshape(*shape, 3), depth=depth.reshape(shape),
                        segmentation=geom.reshape(shape))
