"""The ray caster: one primary ray per pixel against every geom group, nearest hit shaded."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import mujoco
import numpy as np

from envs_mjx.render import camera as camera_lib
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
    t: jnp.ndarray  # [P] distance in units of the ray direction, +inf on a miss
    geom: jnp.ndarray  # [P] int32 geom id
    normal: jnp.ndarray  # [P, 3] world normal, unnormalised
    uv: jnp.ndarray  # [P, 2] texture coordinates
    uv_ok: jnp.ndarray  # [P] bool, whether uv is meaningful for this surface


def _take(x, k):
    """x: [P, G, ...], k: [P] -> x[p, k[p]]: [P, ...]."""
    idx = k.reshape(k.shape + (1,) * (x.ndim - 1))
    return jnp.take_along_axis(x, idx, axis=1)[:, 0]


def _primitive_group(ctx, gi, gtype, ids, o_l, d_l, rot):
    """Nearest hit among one group of same-type primitives. o_l: [G, 3]; d_l: [P, G, 3]."""
    hit_fn, normal_fn = _PRIMITIVES[gtype]
    size = ctx.group_size[gi]  # [G, 3]
    t_all = hit_fn(o_l[None], d_l, size[None], ctx.znear)  # [P, G]
    k = jnp.argmin(t_all, axis=1)
    t = jnp.min(t_all, axis=1)
    t_safe = jnp.where(jnp.isfinite(t), t, 0.0)
    p_l = o_l[k] + t_safe[:, None] * _take(d_l, k)
    n_w = jnp.sum(rot[k] * normal_fn(p_l, size[k])[:, None, :], axis=-1)
    geom = jnp.asarray(ids, jnp.int32)[k]
    is_plane = gtype == int(_G.mjGEOM_PLANE)
    if is_plane:
        corner = ctx.geom_uvorigin[geom]
        uv = jnp.stack([p_l[:, 0] + corner[:, 0], corner[:, 1] - p_l[:, 1]], -1)
        uv = uv * ctx.geom_uvscale[geom]
    else:
        uv = jnp.zeros_like(p_l[:, :2])
    return _Hit(t, geom, n_w, uv, jnp.full(t.shape, is_plane))


def _mesh_group(ctx, ids, o_l, d_l, rot):
    """Nearest hit among all mesh geoms' triangles. o_l: [Gm, 3]; d_l: [P, Gm, 3]."""
    mesh = ctx.mesh
    p, gm = d_l.shape[0], d_l.shape[1]
    n_tri = mesh.valid.shape[1]
    t_all, _, _ = intersect.hit_triangles(
        o_l[None, :, None, :], d_l[:, :, None, :], mesh.v0[None], mesh.e1[None], mesh.e2[None],
        mesh.valid[None], ctx.znear)  # [P, Gm, T]
    flat = t_all.reshape(p, gm * n_tri)
    best = jnp.argmin(flat, axis=1)
    g, tri = best // n_tri, best % n_tri
    # Re-intersect only the winning triangle to recover barycentrics for uv and the normal.
    d_w = _take(d_l, g)
    t, u, v = intersect.hit_triangles(o_l[g], d_w, mesh.v0[g, tri], mesh.e1[g, tri],
                                      mesh.e2[g, tri], mesh.valid[g, tri], ctx.znear)
    n_l = jnp.cross(mesh.e1[g, tri], mesh.e2[g, tri])
    n_w = jnp.sum(rot[g] * n_l[:, None, :], axis=-1)
    corners = mesh.uv[g, tri]  # [P, 3, 2]
    uv = ((1.0 - u - v)[:, None] * corners[:, 0] + u[:, None] * corners[:, 1]
          + v[:, None] * corners[:, 2])
    geom = jnp.asarray(ids, jnp.int32)[g]
    return _Hit(t, geom, n_w, uv, mesh.has_uv[g])


def render(ctx: RenderContext, data) -> RenderOutput:
    """Render one frame from `data` (mjx.Data, mujoco.MjData or anything with geom_xpos,
    geom_xmat, cam_xpos, cam_xmat). Jittable and vmappable over data."""
    geom_xpos = jnp.asarray(data.geom_xpos, jnp.float32)
    geom_xmat = jnp.asarray(data.geom_xmat, jnp.float32).reshape(-1, 3, 3)
    cam_xpos = jnp.asarray(data.cam_xpos, jnp.float32)[ctx.cam_id]
    cam_xmat = jnp.asarray(data.cam_xmat, jnp.float32).reshape(-1, 3, 3)[ctx.cam_id]
    origin, dirs = camera_lib.world_rays(ctx.rays, cam_xpos, cam_xmat)
    n_pix = dirs.shape[0]

    hits = []
    for gi, (gtype, ids) in enumerate(zip(ctx.group_types, ctx.group_geoms, strict=True)):
        sel = np.asarray(ids)
        pos, rot = geom_xpos[sel], geom_xmat[sel]  # [G, 3], [G, 3, 3]
        # R^T (o - p) and R^T d as broadcast sums: XLA:CPU fuses these into the intersection
        # loop, whereas 3x3 dot_generals become separate, slow small-matrix calls.
        o_l = jnp.sum(rot * (origin[None] - pos)[:, :, None], axis=1)  # [G, 3]
        d_l = jnp.sum(rot[None] * dirs[:, None, :, None], axis=2)  # [P, G, 3]
        if gtype == int(_G.mjGEOM_MESH):
            hits.append(_mesh_group(ctx, ids, o_l, d_l, rot))
        else:
            hits.append(_primitive_group(ctx, gi, gtype, ids, o_l, d_l, rot))

    if hits:
        stacked = _Hit(*(jnp.stack(f, axis=1) for f in zip(*hits, strict=True)))  # [P, K, ...]
        k = jnp.argmin(stacked.t, axis=1)
        hit = _Hit(*(_take(f, k) for f in stacked))
    else:
        zeros = jnp.zeros((n_pix, 3))
        hit = _Hit(jnp.full((n_pix,), jnp.inf), jnp.zeros((n_pix,), jnp.int32), zeros,
                   zeros[:, :2], jnp.zeros((n_pix,), bool))
    found = hit.t <= ctx.zfar
    geom = hit.geom

    base = ctx.geom_rgb[geom]
    tex_id = ctx.geom_tex[geom]
    use_tex = hit.uv_ok & (tex_id >= 0)
    texel = shading.sample_texture(ctx.tex_rgb, ctx.tex_adr, ctx.tex_w, ctx.tex_h, tex_id, hit.uv)
    base = jnp.where(use_tex[:, None], base * texel, base)
    light_dirs = [-cam_xmat[:, 2]]  # headlight: travels along the camera's view axis
    if ctx.light_id >= 0:
        xdir = getattr(data, "light_xdir", None)  # MjData has it; mjx.Data does not
        light_dirs.append(ctx.light_dir if xdir is None
                          else jnp.asarray(xdir, jnp.float32).reshape(-1, 3)[ctx.light_id])
    rgb = shading.shade(base, hit.normal, dirs, jnp.stack(light_dirs), ctx.light_diffuse,
                        ctx.light_specular, ctx.ambient, ctx.geom_specular[geom],
                        ctx.geom_shininess[geom], ctx.geom_emission[geom])
    rgb = jnp.where(found[:, None], rgb, ctx.background)
    shape = (ctx.height, ctx.width)
    return RenderOutput(
        rgb=jnp.round(rgb * 255.0).astype(jnp.uint8).reshape(*shape, 3),
        depth=jnp.where(found, hit.t, ctx.zfar).astype(jnp.float32).reshape(shape),
        segmentation=jnp.where(found, geom, -1).astype(jnp.int32).reshape(shape))
