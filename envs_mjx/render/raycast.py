"""The ray caster: one primary ray per pixel against every geom, nearest hit shaded.

Everything runs in the camera frame on component arrays with pixels as the contiguous axis
(feature-major): a pixel's ray is (x, y, -1), so a geom's local ray direction is affine in
(x, y) and each primitive test is one fused elementwise loop over pixels. Primitives take two
passes: the first carries only the nearest distance and geom index through a static loop over
geoms (one packed int32, see `_nearest_primitive`), the second selects the winner's frame and
computes its normal once (`_primitive_hit`); no gathers, no argmin over a small minor axis.
Meshes are tested with camera-space edge functions (see `_mesh_hits`), a max-reduction over
triangles with pixels contiguous. Under vmap on the CPU, frames go in chunks (`_render_batch`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
from jax import custom_batching, lax

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
    lod: jnp.ndarray  # mip level of the pixel's footprint (log2 texels per pixel), mip planes


def _select(mask, new: _Hit, old: _Hit) -> _Hit:
    return _Hit(*(jnp.where(mask, a, b) for a, b in zip(new, old, strict=True)))


def _nearest_primitive(ctx, frames, x, y, never):
    """Pass 1: distance and index (into `frames`) of the nearest primitive per pixel, -1 if none.

    The chain over geoms carries one int32 per pixel: the bits of t (positive floats order like
    their bit patterns) with the low bits replaced by the geom's index, so the whole chain is a
    single fused loop with one output. Carrying normals and uv as well made XLA:CPU fuse the
    chain into every carried field's loop and re-run it per field (docs/notes/render.md);
    carrying t and the index as two arrays made it split the chain
    into a buffer per geom. The cost: t loses its low bits (relative 2^-(23 - index bits)), and
    surfaces that close in depth tie-break by index."""
    bits = max(1, (len(frames) - 1).bit_length())
    low = jnp.int32((1 << bits) - 1)
    key = jnp.full(x.shape, jnp.iinfo(jnp.int32).max, jnp.int32)  # above any t, +inf included
    for i, (gtype, size, _, m, o_l) in enumerate(frames):
        d_l = tuple(m[0, j] * x + m[1, j] * y - m[2, j] for j in range(3))
        t = _PRIMITIVES[gtype][0]((o_l[0], o_l[1], o_l[2]), d_l, (size[0], size[1], size[2]),
                                  ctx.znear)
        key = jnp.minimum(key, (lax.bitcast_convert_type(t, jnp.int32) & ~low) | i)
    # Into a buffer: pass 2 and shading read the winner many times, and would otherwise each
    # re-run the whole chain.
    key = _materialise(key, never)
    t = lax.bitcast_convert_type(key & ~low, jnp.float32)
    found = t < jnp.inf
    return jnp.where(found, t, jnp.inf), jnp.where(found, key & low, -1)


def _materialise(a, never):
    """`a`, forced into a buffer: a one-trip loop XLA cannot prove to be one trip (nor its body
    the identity) stops consumers from fusing (and so re-running) its producers.

    `never` is a bool scalar that is always False but must not be known at compile time, so it
    comes from the data: the context is often a compile-time constant (the envs close over it),
    and a trip count XLA can fold removes the loop (see docs/notes/render.md)."""
    trips = 1 + never.astype(jnp.int32)

    def identity(i, v):  # one trip, but XLA cannot tell
        return jax.tree.map(lambda x: jnp.where(i < 0, x + x, x), v)

    if isinstance(a, jnp.ndarray) and a.dtype == jnp.int32:
        return lax.fori_loop(0, trips, lambda i, v: v | (i < 0).astype(v.dtype), a)
    return lax.fori_loop(0, trips, identity, a)


def _primitive_hit(ctx, frames, t, idx, x, y) -> _Hit:
    """Pass 2: normal (and checker / texture coordinates) of each pixel's nearest primitive.

    The winner's frame (m, o_l, size) and geom id reach each pixel by a select chain over the
    primitives (a gather of table rows is slower on XLA:CPU); its normal is then
    computed once per type present, and chosen by the index range the type occupies."""
    found = idx >= 0
    fields = [jnp.zeros_like(x)] * 15
    geom = jnp.full(x.shape, -1, jnp.int32)
    for i, (_, size_i, g, m_i, o_i) in enumerate(frames):
        here = idx == i
        vals = [m_i[a, b] for a in range(3) for b in range(3)] + [o_i[j] for j in range(3)] + [
            size_i[j] for j in range(3)]
        fields = [jnp.where(here, val, f) for val, f in zip(vals, fields, strict=True)]
        geom = jnp.where(here, jnp.int32(g), geom)
    m = [[fields[3 * a + b] for b in range(3)] for a in range(3)]
    t_safe = jnp.where(found, t, 0.0)
    d_l = [m[0][j] * x + m[1][j] * y - m[2][j] for j in range(3)]
    p_l = tuple(fields[9 + j] + t_safe * d_l[j] for j in range(3))
    size = (fields[12], fields[13], fields[14])
    n_l = None
    start = 0
    for gtype, ids in zip(ctx.group_types, ctx.group_geoms, strict=True):
        if gtype == int(_G.mjGEOM_MESH):
            continue  # frames list the primitive groups in this order (see _render_frame)
        count = len(ids)
        n = _PRIMITIVES[gtype][1](p_l, size)
        if n_l is None:
            n_l = n
        else:
            here = idx >= start
            n_l = tuple(jnp.where(here, a, b) for a, b in zip(n, n_l, strict=True))
        start += count
    n_c = [m[i][0] * n_l[0] + m[i][1] * n_l[1] + m[i][2] * n_l[2] for i in range(3)]
    u = v = lod = jnp.zeros_like(x)
    tex = jnp.full(x.shape, -1, jnp.int32)
    for gtype, _, g, m_g, o_g in frames:
        if gtype == int(_G.mjGEOM_PLANE) and g in ctx.textured_geoms:
            on = geom == g
            u_g, v_g, lod_g = _plane_uv(ctx, g, m_g, o_g, t_safe, x, y)
            u, v = jnp.where(on, u_g, u), jnp.where(on, v_g, v)
            if g in ctx.mip_geoms:
                lod = jnp.where(on, lod_g, lod)
            tex = jnp.where(on, ctx.geom_tex[g], tex)
    return _Hit(t, geom, *n_c, u, v, tex, lod)


def _plane_uv(ctx, g, m, o, t, x, y):
    """Texture coordinates where the rays meet textured plane g (frame m, o_l) at distance t,
    and for an image texture (ctx.mip_geoms) the mip level of each pixel's footprint (else 0).
    For a checker texture, u carries the checker's value box-filtered over the pixel (v unused).
    """
    # Recomputed from the plane's own (scalar) frame: cheaper on the CPU than reusing pass 2's
    # per-pixel d_l and p_l, which are equal where the plane wins.
    d_l = tuple(m[0, j] * x + m[1, j] * y - m[2, j] for j in range(3))
    p_l = tuple(o[j] + t * d_l[j] for j in range(3))
    corner, scale = ctx.geom_uvorigin[g], ctx.geom_uvscale[g]
    u = (p_l[0] + corner[0]) * scale[0]
    v = (corner[1] - p_l[1]) * scale[1]
    if g not in ctx.checker_geoms and g not in ctx.mip_geoms:
        return u, v, None
    # One texel per pixel aliases a fine texture into moire at 64 x 64 (MuJoCo mipmaps it);
    # instead filter it over the pixel's footprint in uv. The ray (x, y, -1) meets local z = 0
    # at t = -o_z / d_z, so d p_l / dx = t (m[0, :] - m[0, 2] d_l / d_z) (m[1] for y), with
    # 1 / d_z = -t / o_z; one pixel step is pixel_pitch in x and y.
    neg_inv_oz = -1.0 / jnp.where(jnp.abs(o[2]) > 1e-9, o[2], 1e-9)
    k = ctx.pixel_pitch * t
    a0 = d_l[0] * (t * neg_inv_oz)
    a1 = d_l[1] * (t * neg_inv_oz)
    du_dx, du_dy = scale[0] * k * (m[0, 0] - m[0, 2] * a0), scale[0] * k * (m[1, 0] - m[1, 2] * a0)
    dv_dx, dv_dy = scale[1] * k * (m[0, 1] - m[0, 2] * a1), scale[1] * k * (m[1, 1] - m[1, 2] * a1)
    if g in ctx.mip_geoms:
        # OpenGL's level of detail: log2 of the longer of the footprint's two edges, in texels
        # of the texture this env draws on the plane (geom_tex may differ per env).
        tex = jnp.maximum(ctx.geom_tex[g], 0)
        w2, h2 = jnp.square(ctx.tex_w[tex].astype(jnp.float32)), jnp.square(
            ctx.tex_h[tex].astype(jnp.float32))
        rho2 = jnp.maximum(w2 * du_dx * du_dx + h2 * dv_dx * dv_dx,
                           w2 * du_dy * du_dy + h2 * dv_dy * dv_dy)
        return u, v, 0.5 * shading.log2(jnp.maximum(rho2, 1e-12))
    # The checker: the mean of its square waves over the footprint's extent along u and v.
    wu = jnp.abs(du_dx) + jnp.abs(du_dy)
    wv = jnp.abs(dv_dx) + jnp.abs(dv_dy)
    filtered = shading.square_wave_mean(u, wu) * shading.square_wave_mean(v, wv)
    return filtered, filtered, None


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
    # reduction over a [T, P] array did not vectorise across pixels. Triangles
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
    lod = best.lod
    if table.shape[1] > 4:
        bary = [(c[:, 3 * k] * x + c[:, 3 * k + 1] * y + c[:, 3 * k + 2]) * t for k in range(3)]
        u = bary[0] * row[:, 4] + bary[1] * row[:, 6] + bary[2] * row[:, 8]
        v = bary[0] * row[:, 5] + bary[1] * row[:, 7] + bary[2] * row[:, 9]
        tex = row[:, 10].astype(jnp.int32)
        if any(g in ctx.mip_geoms for g in ctx.mesh.geom):
            # The footprint for mip sampling: bary_k = w_k t with t = 1 / sum(w), so
            # d bary_k / dx = t (c_kx - bary_k sum_j c_jx), and du/dx = t (sum_k c_kx u_k - u S_x)
            # (likewise y, v); one pixel step is pixel_pitch on the camera-frame plane.
            k = t * ctx.pixel_pitch
            derivs = []
            for axis in (0, 1):
                s_axis = c[:, axis] + c[:, 3 + axis] + c[:, 6 + axis]
                for coord, col in ((u, 4), (v, 5)):
                    weighted = sum(c[:, 3 * j + axis] * row[:, col + 2 * j] for j in range(3))
                    derivs.append(k * (weighted - s_axis * coord))
            du_dx, dv_dx, du_dy, dv_dy = derivs
            tid = jnp.maximum(tex, 0)
            w2 = jnp.square(ctx.tex_w[tid].astype(jnp.float32))
            h2 = jnp.square(ctx.tex_h[tid].astype(jnp.float32))
            rho2 = jnp.maximum(w2 * du_dx * du_dx + h2 * dv_dx * dv_dx,
                               w2 * du_dy * du_dy + h2 * dv_dy * dv_dy)
            lod = 0.5 * shading.log2(jnp.maximum(rho2, 1e-12))
    new = _Hit(t, row[:, 3].astype(jnp.int32), row[:, 0], row[:, 1], row[:, 2], u, v, tex, lod)
    return _select(closer, new, best)


class _Pose(NamedTuple):
    """What the renderer reads from the data, float32, world frame."""

    geom_xpos: jnp.ndarray  # [ngeom, 3]
    geom_xmat: jnp.ndarray  # [ngeom, 3, 3]
    cam_xpos: jnp.ndarray  # [3] the rendering camera's
    cam_xmat: jnp.ndarray  # [3, 3]
    light_dir: jnp.ndarray | None  # [3] direction the model light travels; None: no light


def render(ctx: RenderContext, data) -> RenderOutput:
    """Render one frame from `data` (mjx.Data, mujoco.MjData or anything with geom_xpos,
    geom_xmat, cam_xpos, cam_xmat). Jittable and vmappable over data (and over ctx's arrays).

    Under vmap on the CPU, frames are rendered in chunks of `CPU_BATCH_CHUNK` (see
    `_render_batch`)."""
    light_dir = None
    if ctx.light_id >= 0:
        xdir = getattr(data, "light_xdir", None)  # MjData has it; mjx.Data does not
        light_dir = (ctx.light_dir if xdir is None
                     else jnp.asarray(xdir, jnp.float32).reshape(-1, 3)[ctx.light_id])
    pose = _Pose(geom_xpos=jnp.asarray(data.geom_xpos, jnp.float32),
                 geom_xmat=jnp.asarray(data.geom_xmat, jnp.float32).reshape(-1, 3, 3),
                 cam_xpos=jnp.asarray(data.cam_xpos, jnp.float32)[ctx.cam_id],
                 cam_xmat=jnp.asarray(data.cam_xmat, jnp.float32).reshape(-1, 3, 3)[ctx.cam_id],
                 light_dir=light_dir)
    return _render_pose(ctx, pose)


# Frames per chunk when a batch is rendered on the CPU. XLA:CPU runs each fused loop over the
# whole batch before the next, so a large batch streams every intermediate [B, H*W] buffer
# through memory; in chunks they stay in cache (docs/notes/render.md).
CPU_BATCH_CHUNK = 32


@custom_batching.custom_vmap
def _render_pose(ctx: RenderContext, pose: _Pose) -> RenderOutput:
    return _render_frame(ctx, pose)


@_render_pose.def_vmap
def _render_batch(axis_size, in_batched, ctx, pose):
    """vmap rule: the batch in chunks of CPU_BATCH_CHUNK on the CPU (lax.map over vmapped
    chunks), all at once elsewhere (a GPU wants every frame in flight)."""
    leaves, treedef = jax.tree.flatten((ctx, pose))
    flags = jax.tree.leaves(in_batched)
    batched = [leaf for leaf, b in zip(leaves, flags, strict=True) if b]

    def one(xs):
        it = iter(xs)
        return _render_frame(*treedef.unflatten(
            [next(it) if b else leaf for leaf, b in zip(leaves, flags, strict=True)]))

    if not batched:
        out = one([])
        return out, jax.tree.map(lambda _: False, out)
    if jax.default_backend() == "cpu" and axis_size > CPU_BATCH_CHUNK:
        out = lax.map(one, batched, batch_size=CPU_BATCH_CHUNK)
    else:
        out = jax.vmap(one)(batched)
    return out, jax.tree.map(lambda _: True, out)


def _render_frame(ctx: RenderContext, pose: _Pose) -> RenderOutput:
    geom_xpos, geom_xmat, cam_xpos, cam_xmat = pose[:4]
    never = jnp.isnan(cam_xpos[0])  # False, but only the data says so (see _materialise)
    frames = []  # per primitive geom: (type, size, id, m, o_l)
    for gi, (gtype, ids) in enumerate(zip(ctx.group_types, ctx.group_geoms, strict=True)):
        if gtype == int(_G.mjGEOM_MESH):
            continue
        for k, g in enumerate(ids):
            rot, pos = geom_xmat[g], geom_xpos[g]
            m = cam_xmat.T @ rot  # camera frame -> local frame is m.T
            frames.append((gtype, ctx.group_size[gi][k], g, m, rot.T @ (cam_xpos - pos)))
    mesh = None
    if ctx.mesh is not None:
        mesh = _mesh_tables(ctx, geom_xpos, geom_xmat, cam_xpos, cam_xmat)
    light_dirs = [None]  # None: the headlight, which travels along the camera's view axis
    if pose.light_dir is not None:
        light_dirs.append(cam_xmat.T @ pose.light_dir)

    def pixels(rays):
        """Everything per pixel: rays [8, P] -> packed rgb, depth, geom, each [P]."""
        x, y = rays[0], rays[1]  # camera-frame ray direction (x, y, -1)
        inf = jnp.full(x.shape, jnp.inf, jnp.float32)
        zero = jnp.zeros(x.shape, jnp.float32)
        none = jnp.full(x.shape, -1, jnp.int32)
        best = _Hit(inf, none, zero, zero, zero, zero, zero, none, zero)
        if frames:
            t, idx = _nearest_primitive(ctx, frames, x, y, never)
            best = _primitive_hit(ctx, frames, t, idx, x, y)
        if mesh is not None:
            best = _mesh_hits(ctx, *mesh, x, y, best)
        if ctx.mip_geoms:
            # Mip sampling reads the hit's uv and level in several gathers; without a buffer
            # XLA re-runs the selects that produce them inside each.
            u, v, lod, tex = _materialise((best.u, best.v, best.lod, best.tex), never)
            best = best._replace(u=u, v=v, lod=lod, tex=tex)
        found = best.t <= ctx.zfar
        geom = jnp.where(found, best.geom, -1)
        rgb = shading.shade(ctx, best, geom, rays, light_dirs)
        rgb8 = [jnp.round(jnp.where(found, rgb[i], ctx.background[i]) * 255.0)
                .astype(jnp.uint32) for i in range(3)]
        # Channels leave as one packed uint32 per pixel: a [P, 3] stack fused with shading
        # ran unvectorised and recomputed shading per channel.
        packed = rgb8[0] | (rgb8[1] << 8) | (rgb8[2] << 16)
        return packed, jnp.where(found, best.t, ctx.zfar), geom

    # One frame's pixels are not chunked (slower on XLA:CPU); chunks of whole frames, in
    # _render_batch, pay.
    packed, depth, geom = pixels(ctx.rays)
    if jax.default_backend() == "cpu":
        # The frame leaves as bytes ([P, 4] -> [P, 3]); a consumer of those bytes, such as
        # env.step's select of the new or the previous frame, fused the shading into its own
        # per-byte loop, re-running it per channel, unvectorised, so a buffer goes in between.
        # Not on a GPU, where the buffer costs frames/s (docs/notes/render.md).
        packed = _materialise(packed, never)
    rgb8 = lax.bitcast_convert_type(packed, jnp.uint8)[:, :3]  # little-endian byte order
    shape = (ctx.height, ctx.width)
    return RenderOutput(rgb=rgb8.reshape(*shape, 3), depth=depth.reshape(shape),
                        segmentation=geom.reshape(shape))
