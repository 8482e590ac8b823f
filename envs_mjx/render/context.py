"""Host-side scene extraction: everything static about an MjModel the ray caster needs, once."""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct
from PIL import Image

from envs_mjx.render import camera as camera_lib

_G = mujoco.mjtGeom
# Geom types the ray caster draws, in the (static) order their groups are evaluated.
DRAWABLE = (_G.mjGEOM_PLANE, _G.mjGEOM_SPHERE, _G.mjGEOM_CAPSULE, _G.mjGEOM_ELLIPSOID,
            _G.mjGEOM_CYLINDER, _G.mjGEOM_BOX, _G.mjGEOM_MESH)
_TEX_2D = int(mujoco.mjtTexture.mjTEXTURE_2D)
# Mip levels kept per texture (sides down to 1 texel, or 2^-(MIP_LEVELS - 1) of the texture):
# enough for textures up to 128 x 128.
MIP_LEVELS = 8


@struct.dataclass
class MeshSet:
    """Triangles of all mesh geoms, padded to a common count T, in each geom's local frame."""

    v0: jnp.ndarray  # [Gm, T, 3] first vertex
    e1: jnp.ndarray  # [Gm, T, 3] vertex 1 - vertex 0
    e2: jnp.ndarray  # [Gm, T, 3] vertex 2 - vertex 0
    valid: jnp.ndarray  # [Gm, T] bool, False on padding
    uv: jnp.ndarray  # [Gm, T, 3, 2] per-corner texture coordinates (zeros when absent)
    has_uv: jnp.ndarray  # [Gm] bool
    geom: tuple = struct.field(pytree_node=False)  # [Gm] the mesh geoms' ids


@struct.dataclass
class RenderContext:
    """What `render` needs besides the data. Static fields select the compiled program."""

    rays: jnp.ndarray  # [8, H*W] per-pixel constants, see camera.ray_table
    group_size: tuple  # per group [G, 3] geom_size
    mesh: MeshSet | None
    geom_rgb: jnp.ndarray  # [ngeom, 3] material colour in [0, 1]
    geom_tex: jnp.ndarray  # [ngeom] int32 index into the packed 2-D textures, -1 for none
    geom_uvscale: jnp.ndarray  # [ngeom, 2] plane texture tiles per unit length
    geom_uvorigin: jnp.ndarray  # [ngeom, 2] plane half-sizes the uv origin sits at
    geom_specular: jnp.ndarray  # [ngeom]
    geom_shininess: jnp.ndarray  # [ngeom]
    geom_emission: jnp.ndarray  # [ngeom]
    tex_rgb: jnp.ndarray  # [N, 3] texels of every 2-D texture, in [0, 1]
    tex_adr: jnp.ndarray  # [ntex2d] int32
    tex_w: jnp.ndarray  # [ntex2d] int32
    tex_h: jnp.ndarray  # [ntex2d] int32
    tex_mip: jnp.ndarray  # [M] int32: texels of every mip level, packed r | g << 8 | b << 16
    tex_mip_adr: jnp.ndarray  # [ntex2d, MIP_LEVELS] int32 where each level starts in tex_mip
    light_dir: jnp.ndarray  # [3] direction the model's first light travels (world)
    light_diffuse: jnp.ndarray  # [L, 3] headlight first, then the model light if any
    light_specular: jnp.ndarray  # [L, 3]
    ambient: jnp.ndarray  # [3]
    background: jnp.ndarray  # [3] in [0, 1]
    znear: float
    zfar: float
    cam_id: jnp.ndarray  # int32 scalar; data, not static, so cameras share one compile
    pixel_pitch: jnp.ndarray  # float32 scalar: pixel spacing on the camera-frame plane z = -1
    geom_checker: jnp.ndarray  # [ngeom, 2, 3] checker planes' (c1 + c2) / 2 and (c1 - c2) / 2
    height: int = struct.field(pytree_node=False)
    width: int = struct.field(pytree_node=False)
    group_types: tuple = struct.field(pytree_node=False)  # per group, the mjtGeom int
    group_geoms: tuple = struct.field(pytree_node=False)  # per group, tuple of geom ids
    light_id: int = struct.field(pytree_node=False)  # the model light's id, -1 for none
    # Geoms whose texture is drawn (planes and meshes with uv that have a 2-D texture).
    textured_geoms: tuple = struct.field(pytree_node=False, default=())
    # Textured planes whose texture is a two-colour checker (MuJoCo's builtin="checker"): drawn
    # box-filtered over each pixel's footprint instead of by nearest texel (see raycast).
    checker_geoms: tuple = struct.field(pytree_node=False, default=())
    # Textured meshes, and planes with an image texture: drawn from the texture's mip levels at
    # the level of each pixel's footprint (see raycast._plane_uv, raycast._mesh_hits), as
    # OpenGL draws them.
    mip_geoms: tuple = struct.field(pytree_node=False, default=())


def decimate(verts: np.ndarray, faces: np.ndarray, max_faces: int):
    """Vertex-clustering decimation to at most max_faces triangles.

    verts: [V, 3]; faces: [F, 3] int. Vertices are snapped to the mean of their cell in a grid
    over the bounding box; triangles that collapse are dropped. The grid is refined as far as
    the face budget allows, so silhouettes move by at most about one cell. Returns
    (verts [V', 3], faces [F', 3], kept [F'] indices of the surviving original faces, so their
    texture coordinates can follow).
    """
    if len(faces) <= max_faces:
        return verts, faces, np.arange(len(faces))
    lo, hi = verts.min(0), verts.max(0)
    span = np.maximum(hi - lo, 1e-9)
    best = None
    for cells in range(64, 0, -1):
        key = np.minimum(((verts - lo) / span * cells).astype(np.int64), cells - 1)
        flat = (key[:, 0] * cells + key[:, 1]) * cells + key[:, 2]
        uniq, cluster = np.unique(flat, return_inverse=True)
        f = cluster[faces]
        ok = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
        # Drop duplicate triangles that different originals collapse onto.
        _, first = np.unique(np.sort(f[ok], axis=1), axis=0, return_index=True)
        kept = np.flatnonzero(ok)[np.sort(first)]
        if len(kept) <= max_faces:
            best = (cluster, len(uniq), kept)
            break
    if best is None:
        raise ValueError(f"cannot decimate a mesh of {len(faces)} faces to {max_faces}")
    cluster, n, kept = best
    sums = np.zeros((n, 3))
    np.add.at(sums, cluster, verts)
    counts = np.bincount(cluster, minlength=n)[:, None]
    return sums / counts, cluster[faces[kept]], kept


def mesh_set(m: mujoco.MjModel, geoms: Sequence[int], max_faces: int = 300) -> MeshSet:
    """The triangles `make_context` draws for mesh geoms `geoms`, in each geom's local frame
    (for a context whose mesh slots are filled per env, as MeshOnIncline's object is)."""
    return _mesh_set(m, geoms, max_faces)


def _mesh_set(m: mujoco.MjModel, geoms: Sequence[int], max_faces: int) -> MeshSet:
    tris, uvs, has_uv = [], [], []
    for g in geoms:
        mid = m.geom_dataid[g]
        va, vn = m.mesh_vertadr[mid], m.mesh_vertnum[mid]
        fa, fn = m.mesh_faceadr[mid], m.mesh_facenum[mid]
        verts = m.mesh_vert[va:va + vn].astype(np.float64)
        faces = m.mesh_face[fa:fa + fn].astype(np.int64)
        verts, faces, kept = decimate(verts, faces, max_faces)
        tris.append(verts[faces])  # [F, 3, 3]
        ta = m.mesh_texcoordadr[mid]
        if ta >= 0:
            tcoord = m.mesh_texcoord[ta:ta + m.mesh_texcoordnum[mid]]
            uvs.append(tcoord[m.mesh_facetexcoord[fa:fa + fn][kept]])  # [F, 3, 2]
            has_uv.append(True)
        else:
            uvs.append(np.zeros((len(faces), 3, 2)))
            has_uv.append(False)
    t = max(len(x) for x in tris)
    pad = np.zeros((len(geoms), t, 3, 3))
    pad_uv = np.zeros((len(geoms), t, 3, 2))
    valid = np.zeros((len(geoms), t), bool)
    for i, (tr, uv) in enumerate(zip(tris, uvs, strict=True)):
        pad[i, :len(tr)], pad_uv[i, :len(tr)], valid[i, :len(tr)] = tr, uv, True
    f32 = np.float32
    return MeshSet(
        v0=jnp.asarray(pad[:, :, 0], f32), e1=jnp.asarray(pad[:, :, 1] - pad[:, :, 0], f32),
        e2=jnp.asarray(pad[:, :, 2] - pad[:, :, 0], f32), valid=jnp.asarray(valid),
        uv=jnp.asarray(pad_uv, f32), has_uv=jnp.asarray(np.array(has_uv)),
        geom=tuple(int(g) for g in geoms))


def texture_index(m: mujoco.MjModel) -> np.ndarray:
    """[ntex] int32: each MuJoCo texture's index among the packed 2-D textures (the values
    `RenderContext.geom_tex` holds), -1 for cube and skybox textures."""
    is_2d = np.asarray(m.tex_type) == _TEX_2D
    return np.where(is_2d, np.cumsum(is_2d) - 1, -1).astype(np.int32)


def mip_levels(rgb: np.ndarray) -> list[np.ndarray]:
    """[h, w, 3] uint8 -> MIP_LEVELS images: the texture, then box-filtered halvings (sides
    max(1, side >> level), each level averaged from the full texture), as glGenerateMipmap
    builds them for power-of-two sides."""
    h, w, _ = rgb.shape
    image = Image.fromarray(rgb)
    levels = [rgb]
    for level in range(1, MIP_LEVELS):
        size = (max(1, w >> level), max(1, h >> level))
        levels.append(np.asarray(image.resize(size, Image.Resampling.BOX), np.uint8))
    return levels


def _textures(m: mujoco.MjModel):
    """Pack every 2-D texture's texels into one [N, 3] array and its mip levels into one packed
    int32 array (see RenderContext); cube/skybox textures get -1."""
    index = texture_index(m)
    chunks, adr, ws, hs, n = [], [], [], [], 0
    mips, mip_adr, n_mip = [], [], 0
    for t in range(m.ntex):
        if m.tex_type[t] != _TEX_2D:
            continue
        w, h, c = m.tex_width[t], m.tex_height[t], m.tex_nchannel[t]
        a = m.tex_adr[t]
        texels = m.tex_data[a:a + w * h * c].reshape(h * w, c)
        rgb = np.repeat(texels[:, :1], 3, axis=1) if c < 3 else texels[:, :3]
        chunks.append(rgb.astype(np.float32) / 255.0)
        adr.append(n)
        ws.append(w)
        hs.append(h)
        n += w * h
        starts = []
        for level in mip_levels(np.ascontiguousarray(rgb.reshape(h, w, 3), np.uint8)):
            starts.append(n_mip)
            px = level.reshape(-1, 3).astype(np.uint32)
            mips.append((px[:, 0] | (px[:, 1] << 8) | (px[:, 2] << 16)).astype(np.int32))
            n_mip += len(px)
        mip_adr.append(starts)
    if not chunks:  # keep shapes non-empty so gathers compile; geom_tex is -1 everywhere
        chunks, adr, ws, hs = [np.zeros((1, 3), np.float32)], [0], [1], [1]
        mips, mip_adr = [np.zeros(1, np.int32)], [[0] * MIP_LEVELS]
    i32 = np.int32
    return (index, np.concatenate(chunks), np.array(adr, i32), np.array(ws, i32),
            np.array(hs, i32), np.concatenate(mips), np.array(mip_adr, i32))


def checker_colours(rgb: np.ndarray, w: int, h: int):
    """(c1, c2) if the [h * w, 3] texels are MuJoCo's builtin 2-D checker (c1 in the top-left and
    bottom-right quadrants, c2 in the others, no marks), else None."""
    if w < 2 or h < 2 or w % 2 or h % 2:
        return None
    img = rgb.reshape(h, w, 3)
    c1, c2 = img[0, 0], img[0, w // 2]
    if np.array_equal(c1, c2):
        return None
    want = np.empty_like(img)
    want[: h // 2, : w // 2] = want[h // 2:, w // 2:] = c1
    want[: h // 2, w // 2:] = want[h // 2:, : w // 2] = c2
    return (c1, c2) if np.array_equal(img, want) else None


def make_context(mj_model: mujoco.MjModel, camera: str | int, height: int = 64, width: int = 64,
                 *, background: Sequence[float] = (1.0, 1.0, 1.0), max_mesh_faces: int = 300,
                 geom_groups: Sequence[int] = (0, 1, 2)) -> RenderContext:
    """Build the static scene description for rendering `mj_model` from `camera`.

    Draws the geoms MuJoCo's default visual options draw: those in `geom_groups` whose alpha is
    not zero. Raises ValueError for an unknown camera, a camera model the ray caster does not
    implement, or a visible geom of a type it cannot draw (hfield, sdf).
    """
    m = mj_model
    cam = camera_lib.camera_id(m, camera)
    if hasattr(m, "cam_orthographic") and m.cam_orthographic[cam]:
        raise ValueError(f"camera {camera!r} is orthographic; only perspective cameras are drawn")
    if hasattr(m, "cam_sensorsize") and m.cam_sensorsize[cam][1] > 0:
        raise ValueError(f"camera {camera!r} uses sensor intrinsics; only fovy cameras are drawn")

    rgba = m.geom_rgba.copy()
    has_mat = m.geom_matid >= 0
    rgba[has_mat] = m.mat_rgba[m.geom_matid[has_mat]]
    visible = np.isin(m.geom_group, list(geom_groups)) & (rgba[:, 3] > 0)

    drawable = {int(t) for t in DRAWABLE}
    bad = [g for g in np.flatnonzero(visible) if int(m.geom_type[g]) not in drawable]
    if bad:
        desc = ", ".join(
            f"{g} ({mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g)!r}, "
            f"{mujoco.mjtGeom(int(m.geom_type[g])).name})" for g in bad)
        raise ValueError(f"the renderer cannot draw geom(s) {desc}; drawable types are "
                         + ", ".join(mujoco.mjtGeom(int(t)).name for t in DRAWABLE))

    types, groups, sizes, mesh = [], [], [], None
    for t in DRAWABLE:
        ids = tuple(int(g) for g in np.flatnonzero(visible & (m.geom_type == t)))
        if not ids:
            continue
        types.append(int(t))
        groups.append(ids)
        sizes.append(jnp.asarray(m.geom_size[list(ids)], jnp.float32))
        if t == _G.mjGEOM_MESH:
            mesh = _mesh_set(m, ids, max_mesh_faces)

    tex_index, tex_rgb, tex_adr, tex_w, tex_h, tex_mip, tex_mip_adr = _textures(m)
    matid = np.where(has_mat, m.geom_matid, 0)
    mat_tex = m.mat_texid[:, 1] if m.mat_texid.ndim == 2 else m.mat_texid  # mjTEXROLE_RGB
    tex_of_geom = np.where(has_mat, mat_tex[matid], -1) if m.nmat else -np.ones(m.ngeom, int)
    geom_tex = -np.ones(m.ngeom, np.int32)
    if m.ntex:
        geom_tex = np.where(tex_of_geom >= 0, tex_index[np.maximum(tex_of_geom, 0)], -1)
    # Textures are drawn on planes and on meshes with texture coordinates.
    with_uv = [g for t, ids in zip(types, groups, strict=True) for g in ids
               if t == _G.mjGEOM_PLANE
               or (t == _G.mjGEOM_MESH and m.mesh_texcoordadr[m.geom_dataid[g]] >= 0)]
    textured = tuple(g for g in with_uv if geom_tex[g] >= 0)
    geom_checker = np.zeros((m.ngeom, 2, 3), np.float32)
    checker, mip = [], []
    for g in textured:
        if m.geom_type[g] != _G.mjGEOM_PLANE:
            mip.append(g)  # a mesh with uv
            continue
        t = int(geom_tex[g])
        a, w, h = int(tex_adr[t]), int(tex_w[t]), int(tex_h[t])
        colours = checker_colours(tex_rgb[a:a + w * h], w, h)
        if colours is not None:
            geom_checker[g] = [(colours[0] + colours[1]) / 2, (colours[0] - colours[1]) / 2]
            checker.append(g)
        else:
            mip.append(g)
    extent = m.stat.extent
    zfar = m.vis.map.zfar * extent
    if m.nmat:
        repeat = m.mat_texrepeat[matid]
        uniform = m.mat_texuniform[matid].astype(bool)
        spec, shin, emis = m.mat_specular[matid], m.mat_shininess[matid], m.mat_emission[matid]
    else:
        repeat = np.ones((m.ngeom, 2))
        uniform = np.zeros(m.ngeom, bool)
        spec = shin = emis = np.zeros(m.ngeom)
    # Without a material MuJoCo uses its default material: specular 0.5, shininess 0.5.
    spec = np.where(has_mat, spec, 0.5)
    shin = np.where(has_mat, shin, 0.5)
    emis = np.where(has_mat, emis, 0.0)
    # Planes map local (x, y) to uv = ((x + sx) * cx, (sy - y) * cy): the texture starts at the
    # plane's (-x, +y) corner and tiles texrepeat times across the plane's full width 2*s, or
    # with texuniform texrepeat times per 2 length units (both checked against mujoco.Renderer);
    # MuJoCo maps an infinite plane as if its half-size were 1.
    plane_size = np.where(m.geom_size[:, :2] > 0, m.geom_size[:, :2], 1.0)
    uvscale = np.where(uniform[:, None], repeat / 2.0, repeat / (2.0 * plane_size))

    # Lights: the model's first active light (treated as directional) and MuJoCo's headlight,
    # which shines along the camera axis; both are summed as mjr does.
    head = m.vis.headlight
    ambient = np.array(head.ambient) if head.active else np.zeros(3)
    diffuse = [np.array(head.diffuse) if head.active else np.zeros(3)]
    specular = [np.array(head.specular) if head.active else np.zeros(3)]
    light_id, light_dir = -1, np.array([0.0, 0.0, -1.0])
    active = np.flatnonzero(m.light_active) if m.nlight else []
    if len(active):
        light_id = int(active[0])
        light_dir = m.light_dir[light_id]
        ambient = ambient + m.light_ambient[light_id]
        diffuse.append(m.light_diffuse[light_id])
        specular.append(m.light_specular[light_id])

    f32 = jnp.float32
    return RenderContext(
        rays=jnp.asarray(camera_lib.ray_table(m.cam_fovy[cam], height, width)),
        group_size=tuple(sizes), mesh=mesh,
        geom_rgb=jnp.asarray(rgba[:, :3], f32), geom_tex=jnp.asarray(geom_tex, jnp.int32),
        geom_uvscale=jnp.asarray(uvscale, f32), geom_uvorigin=jnp.asarray(plane_size, f32),
        geom_specular=jnp.asarray(spec, f32),
        geom_shininess=jnp.asarray(shin, f32), geom_emission=jnp.asarray(emis, f32),
        tex_rgb=jnp.asarray(tex_rgb), tex_adr=jnp.asarray(tex_adr), tex_w=jnp.asarray(tex_w),
        tex_h=jnp.asarray(tex_h), tex_mip=jnp.asarray(tex_mip),
        tex_mip_adr=jnp.asarray(tex_mip_adr), light_dir=jnp.asarray(light_dir, f32),
        light_diffuse=jnp.asarray(np.array(diffuse), f32),
        light_specular=jnp.asarray(np.array(specular), f32),
        ambient=jnp.asarray(ambient, f32), background=jnp.asarray(background, f32),
        znear=float(m.vis.map.znear * extent), zfar=float(zfar),
        cam_id=jnp.asarray(cam, jnp.int32),
        pixel_pitch=jnp.asarray(2.0 * np.tan(np.deg2rad(m.cam_fovy[cam]) / 2.0) / height, f32),
        geom_checker=jnp.asarray(geom_checker), height=height, width=width,
        group_types=tuple(types), group_geoms=tuple(groups), light_id=light_id,
        textured_geoms=textured, checker_geoms=tuple(checker), mip_geoms=tuple(mip))
