"""Mesh-on-incline: GeomOnIncline with textured object meshes on an image-textured plank and
ground, standing in for the paper's YCB-on-incline (docs/reference/suite.md §1, §6).

Objects. The paper slid textured YCB scans down the plank; those cannot be fetched here, so the
shipped objects are textured meshes from two PyPI wheels (assets/PROVENANCE.md): pybullet_data's
duck and domino, robosuite's cereal box, soda can, bread and lemon (MESH_OBJECTS), each decimated
to at most `max_faces` triangles with its uvs kept, its texture at most 128 x 128, and scaled so
its longest side is OBJECT_SIZES[name] m (the incline's 2.5x YCB scale gives 0.26-0.38 m). The
boxes and the can lie with their long axis downhill, as the reference's YCB objects did.
`object_dir` loads a user's own object from a folder in the YCB google_16k layout
(`textured.obj` + `texture_map.png`).

Several objects per batch. Env slot i of a batch holds objects[i mod N] (`reset_batch`, which
`jaml.stream.collect` uses, so a slot keeps its object across the resets swapped in, as the
reference's 64 envs used object i mod 6); `reset(rng)` alone draws the object uniformly from rng,
`reset(rng, object_slot)` takes it. info["object"] is the slot's index into `objects`, and
info["object_id"] (the LD state's object_id) its index in MESH_OBJECTS (len(MESH_OBJECTS) for a
user's folder). The model holds every object's meshes and texture, and the free body "object"
carries two geoms that show one of them:
- "object", the collision geom: a mesh whose convex hull (at most `max_hull_vertices`
  vertices) MJX collides with the plank through GeomOnIncline's two contact pairs (group 3, not
  drawn);
- "object_visual", the textured mesh, drawn only (massless, not colliding).
The model as compiled shows objects[0]. Per env, batched mjx.Model fields switch them to the
env's object: the two geoms' frames (geom_pos / geom_quat: MuJoCo centres each mesh on its own
frame), body_ipos / body_iquat / body_inertia and the compiler's mass-derived constants (tables
made by compiling the model once per object, then scaled to the drawn mass as GeomOnIncline
scales them), and the hull's vertices in MJX's convex-mesh data (`physics_model`; every hull is
padded to one vertex count by repeating its first vertex, which MJX's plane-mesh contact, the
only collision the hull takes part in, never turns into a second contact). So a step costs one
object's collision and one object's triangles in the renderer (`_render_context` fills its mesh
slot and texture) whatever N is. `mj_model_for(info)` gives C MuJoCo and mujoco.Renderer the same
object by pointing the geoms at its meshes and material. Switching the convex data reaches into
MJX's private `Model._impl.mesh_convex` (mujoco-mjx 3.17); tests/envs_mjx/test_mesh_incline.py
checks each object in a mixed batch against C MuJoCo (agreement: docs/notes/envs.md).

Plank and ground. texture_id (drawn per reset, as in GeomOnIncline) picks one of
SURFACE_PAIRS, image textures from robosuite (tinted where a pair needs a colour) standing in for
the reference's paired (ground, plank) textures: the ground plane repeats its texture every 2 m
(the reference's plane.obj tiles it 15 times over 30 m), and the plank's top is a textured plane
("plank_top", 0.5 m square tiles) 1 mm above the plank box, whose sides take the texture's mean
colour. The renderer draws both from mip levels at each pixel's footprint (docs/render.md);
per env it swaps the geoms' textures (`_render_context`), and `mj_model_for` their materials.
ground="black" keeps the reference Geom variant's black ground.

Everything else (per-reset angle, mass and friction; action; reward; terminations; LD state) is
GeomOnIncline's. Reset lays the object with its modelled "up" (+z of the prepared OBJ; YCB scans
are z-up) away from the plank and its OBJ +x downhill.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco.mjx._src import mesh as mjx_mesh
from PIL import Image

from envs_mjx.base import geom_ids
from envs_mjx.config import MESH_OBJECTS, MeshInclineConfig
from envs_mjx.domains._assets import ASSETS
from envs_mjx.domains.incline import (
    INCLINE_COLOURS,
    GeomOnIncline,
    _normal,
)
from envs_mjx.domains.mesh_object import load_object
from envs_mjx.render.context import mesh_set, texture_index

# Longest side (m) at the incline's scale: the reference's YCB objects at 2.5x measured
# 0.26-0.38 m (sugar box 0.38, chef can 0.33, soup can 0.31; docs/reference/suite.md §6).
OBJECT_SIZES = {
    "duck": 0.3,
    "domino": 0.3,
    "cereal": 0.38,
    "can": 0.33,
    "bread": 0.3,
    "lemon": 0.26,
}
FOLDER_SIZE = 0.3  # a user's object
# OBJ frame (z up) -> object body frame, in which reset points local +x into the plank and local
# +z downhill (GeomOnIncline's convention): body = (-z, y, x). A proper rotation (det +1).
OBJ_TO_BODY = np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]], np.float64)
# (ground, plank) per texture_id: (image in assets/textures/, rgb the image is multiplied by).
# Stand-ins for the reference's pairs, in its order: red_marble / red_metal_strip, blue_bright /
# marble, purple_squares / birch, wood_stripes / green, dark_pattern / retro_purple_long,
# orange_pattern / wood.
_PLAIN = (1.0, 1.0, 1.0)
SURFACE_PAIRS = (
    (("clay", _PLAIN), ("red-wood", _PLAIN)),
    (("blue-wood", _PLAIN), ("cream-plaster", _PLAIN)),
    (("light-gray-floor-tile", (0.75, 0.55, 1.0)), ("light-wood", _PLAIN)),
    (("wood-varnished-panels", _PLAIN), ("green-wood", _PLAIN)),
    (("dirt", _PLAIN), ("gray-woodgrain", (0.75, 0.5, 0.95))),
    (("brass-ambra", _PLAIN), ("dark-wood", _PLAIN)),
)
assert len(SURFACE_PAIRS) == len(INCLINE_COLOURS)  # texture_id ~U{0..5} indexes both
GROUND_TILES = 15  # texture repeats along each side of the 30 m ground: 2 m tiles
PLANK_TILE = 0.5  # m, side of the square texture tiles on the plank's top
PLANK_TOP_GAP = 1e-3  # m: the plank box sits this far below its textured top plane


def default_config() -> MeshInclineConfig:
    return MeshInclineConfig()


@dataclasses.dataclass(frozen=True)
class _Objects:
    """Per-object constants, stacked over the env's objects (leading axis N). The geom fields
    are the collision geom's ([:, 0]) and the visual geom's ([:, 1])."""

    catalogue_id: np.ndarray  # [N] int32, the LD object id
    half_height: np.ndarray  # [N] extent along body +x (into the plank) from the body origin
    mesh: np.ndarray  # [N, 2] int32 geom_dataid
    material: np.ndarray  # [N] int32 the visual geom's geom_matid
    geom_pos: np.ndarray  # [N, 2, 3]
    geom_quat: np.ndarray  # [N, 2, 4]
    geom_size: np.ndarray  # [N, 2, 3]
    geom_rbound: np.ndarray  # [N, 2]
    geom_aabb: np.ndarray  # [N, 2, 6]
    body_ipos: np.ndarray  # [N, 3]
    body_iquat: np.ndarray  # [N, 4]
    body_inertia: np.ndarray  # [N, 3] at the nominal mass
    dof_m0: np.ndarray  # [N, 6] the compiler's constants at the nominal mass
    body_invweight0: np.ndarray  # [N, 2]
    dof_invweight0: np.ndarray  # [N, 6]
    hull_vert: np.ndarray  # [N, V, 3] MJX's convex-hull vertices, padded
    visual: dict  # the renderer's MeshSet fields of each visual mesh, padded: [N, T, ...]


class MeshOnIncline(GeomOnIncline):
    """Textured mesh objects (object i mod N in env slot i) sliding on a randomly tilted,
    image-textured plank, pushed along the slope."""

    def __init__(
        self,
        config: MeshInclineConfig | None = None,
        pixels_fn=None,
        object_dir: str | None = None,
    ):
        config = config or default_config()
        if object_dir is not None:
            config = dataclasses.replace(config, object_dir=str(object_dir))
        super().__init__(config, pixels_fn)
        m = self.mj_model
        self._geoms = geom_ids(m, ["object", "object_visual"])  # collision, visual
        self._plank_top = geom_ids(m, ["plank_top"])[0]
        mat = {mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_MATERIAL, i): i for i in range(m.nmat)}
        self._plank_mats = np.array([mat[f"plank_{t}"] for t in range(len(SURFACE_PAIRS))])
        self._ground_mats = np.array([mat[f"ground_{t}"] for t in range(len(SURFACE_PAIRS))])
        self._textured_ground = self.config.ground == "paired"
        # Per texture_id: the ground's and the plank top's tints (their materials' rgb), and the
        # plank sides' colour, the plank texture's mean colour times its tint.
        self._ground_rgb, self._top_rgb = (
            np.array([pair[j][1] for pair in SURFACE_PAIRS], np.float32) for j in (0, 1)
        )
        mean = [_texture(pair[1][0]).reshape(-1, 3).mean(0) / 255.0 for pair in SURFACE_PAIRS]
        self._side_rgb = np.array(mean, np.float32) * self._top_rgb

    @property
    def num_objects(self) -> int:
        """N: env slot i of a batch holds object i mod N."""
        return len(self._objects.catalogue_id)

    # -- model ------------------------------------------------------------------------------------

    def _add_object(self, spec: mujoco.MjSpec, config: MeshInclineConfig) -> float:
        """Adds every object's meshes, texture and material, the two object geoms (showing
        objects[0]), the textured plank top and the surface materials to `spec`; records the
        per-object tables; returns objects[0]'s extent into the plank."""
        folders, ids, sizes = _resolve_objects(config)
        half_heights = [
            _add_mesh_object(spec, config, k, folder, size)
            for k, (folder, size) in enumerate(zip(folders, sizes, strict=True))
        ]
        hull = spec.geom("object")
        hull.type, hull.meshname = mujoco.mjtGeom.mjGEOM_MESH, "object_hull"
        hull.mass, hull.group, hull.rgba = config.object_mass, 3, [0, 0, 0, 0]
        spec.body("object").add_geom(
            name="object_visual",
            type=mujoco.mjtGeom.mjGEOM_MESH,
            meshname="object_visual",
            material="object",
            contype=0,
            conaffinity=0,
            mass=0,
            group=0,
        )
        _add_surfaces(spec, config)
        self._objects = _object_tables(spec, config, ids, half_heights)
        self._object_index = int(ids[0])
        return half_heights[0]

    def _model_fields(self, info):
        fields = super()._model_fields(info)
        m, o = self.mj_model, self._objects
        slot = info["object"]
        scale = jnp.asarray(info["mass"], jnp.float32) / self._mass0
        body, dofs, geoms = self._object, self._object_dofs, self._geoms

        def put(name, index, table):  # the model's field with this object's rows from a table
            base = jnp.asarray(fields.get(name, getattr(m, name)), jnp.float32)
            return base.at[index].set(jnp.asarray(table, jnp.float32)[slot])

        fields["geom_pos"] = put("geom_pos", geoms, o.geom_pos)
        fields["geom_quat"] = put("geom_quat", geoms, o.geom_quat)
        fields["body_ipos"] = put("body_ipos", body, o.body_ipos)
        fields["body_iquat"] = put("body_iquat", body, o.body_iquat)
        fields["body_inertia"] = put("body_inertia", body, o.body_inertia).at[body].multiply(scale)
        fields["body_invweight0"] = (
            put("body_invweight0", body, o.body_invweight0).at[body].divide(scale)
        )
        fields["dof_M0"] = put("dof_M0", dofs, o.dof_m0).at[dofs].multiply(scale)
        fields["dof_invweight0"] = (
            put("dof_invweight0", dofs, o.dof_invweight0).at[dofs].divide(scale)
        )
        return fields

    def physics_model(self, info):
        """The shared model with this env's fields and its object's hull vertices swapped into
        MJX's convex-mesh data (the plane-mesh contact reads only the vertices)."""
        model = super().physics_model(info)
        if self.num_objects == 1:
            return model
        hull_mesh = int(self.mj_model.geom_dataid[self._geoms[0]])
        convex = list(model._impl.mesh_convex)
        vert = jnp.asarray(self._objects.hull_vert)[info["object"]]
        convex[hull_mesh] = convex[hull_mesh].replace(vert=vert)
        return model.tree_replace({"_impl.mesh_convex": tuple(convex)})

    def mj_model_for(self, info) -> mujoco.MjModel:
        """A C MjModel copy with one env's physics fields and appearance: the object geoms on its
        object's meshes and material, its plank / ground materials and colours."""
        m = super().mj_model_for(info)
        o, slot, tid = self._objects, int(info["object"]), int(info["texture_id"])
        m.geom_dataid[self._geoms] = o.mesh[slot]
        m.geom_matid[self._geoms[1]] = o.material[slot]
        m.geom_size[self._geoms] = o.geom_size[slot]
        m.geom_rbound[self._geoms] = o.geom_rbound[slot]
        m.geom_aabb[self._geoms] = o.geom_aabb[slot]
        m.geom_matid[self._plank_top] = self._plank_mats[tid]
        if self._textured_ground:
            m.geom_matid[self._ground_geom] = self._ground_mats[tid]
        m.geom_rgba[self._plank_geom] = np.asarray(info["geom_rgba"])[self._plank_geom]
        return m

    # -- reset ------------------------------------------------------------------------------------

    def reset(self, rng: jax.Array, object_slot: jax.Array | int | None = None):
        """As Env.reset; object_slot (int32, may be traced) picks objects[object_slot], None
        draws it uniformly from rng."""
        return self._reset_from(*self._sample_reset(rng, object_slot))

    def reset_batch(self, rng: jax.Array, num_envs: int):
        """Env slot i holds objects[i mod N]."""
        slots = jnp.arange(num_envs, dtype=jnp.int32) % self.num_objects
        return jax.vmap(self.reset)(jax.random.split(rng, num_envs), slots)

    def _sample_reset(self, rng, object_slot=None):
        k_object, rng = jax.random.split(rng)
        if object_slot is None:
            slot = jax.random.randint(k_object, (), 0, self.num_objects)
        else:
            slot = jnp.asarray(object_slot, jnp.int32)
        qpos, qvel, info = super()._sample_reset(rng)
        # GeomOnIncline placed objects[0]; lift (or sink) the object to its own extent.
        lift = jnp.asarray(self._objects.half_height)[slot] - self._half_height
        qpos = qpos.at[:3].add(lift * _normal(info["theta"]))
        tid = info["texture_id"]
        rgba = info["geom_rgba"]
        rgba = rgba.at[self._plank_top, :3].set(jnp.asarray(self._top_rgb)[tid])
        rgba = rgba.at[self._plank_geom, :3].set(jnp.asarray(self._side_rgb)[tid])
        if self._textured_ground:
            rgba = rgba.at[self._ground_geom, :3].set(jnp.asarray(self._ground_rgb)[tid])
        info = {
            **info,
            "geom_rgba": rgba,
            "object": slot,
            "object_id": jnp.asarray(self._objects.catalogue_id)[slot],
        }
        return qpos, qvel, info

    # -- rendering --------------------------------------------------------------------------------

    def _render_context(self, ctx, info):
        """The env's object in the renderer's mesh slot, and its surfaces' textures."""
        m = self.mj_model
        if ctx.mesh is None or ctx.mesh.geom != (int(self._geoms[1]),):
            raise ValueError("the render context must draw one mesh, object_visual")
        # Packed texture index of each material's image (numpy: the same in every trace).
        mat_tex = texture_index(m)[m.mat_texid[:, int(mujoco.mjtTextureRole.mjTEXROLE_RGB)]]
        tid, slot = info["texture_id"], info["object"]
        geom_tex = ctx.geom_tex.at[self._plank_top].set(jnp.asarray(mat_tex[self._plank_mats])[tid])
        if self._textured_ground:
            ground = jnp.asarray(mat_tex[self._ground_mats])[tid]
            geom_tex = geom_tex.at[self._ground_geom].set(ground)
        if self.num_objects > 1:
            o = self._objects
            geom_tex = geom_tex.at[self._geoms[1]].set(jnp.asarray(mat_tex[o.material])[slot])
            mesh = {f: jnp.asarray(a)[slot][None] for f, a in o.visual.items()}
            ctx = ctx.replace(mesh=ctx.mesh.replace(**mesh))
        return ctx.replace(geom_tex=geom_tex)


# -- building the model ---------------------------------------------------------------------------


def _name(base: str, k: int) -> str:
    return base if k == 0 else f"{base}_{k}"


def _resolve_objects(config: MeshInclineConfig):
    """(folders, LD object ids, sizes) of the env's objects, in slot order."""
    if config.object_dir is not None:
        size = config.object_size or FOLDER_SIZE
        return [config.object_dir], [len(MESH_OBJECTS)], [size]
    names = (config.object,) if config.object is not None else tuple(config.objects)
    bad = [n for n in names if n not in MESH_OBJECTS]
    if bad or not names:
        raise ValueError(f"object must be one of {MESH_OBJECTS}, got {bad or names!r}")
    folders = [ASSETS / "meshes" / n for n in names]
    sizes = [config.object_size or OBJECT_SIZES[n] for n in names]
    return folders, [MESH_OBJECTS.index(n) for n in names], sizes


def _add_mesh_object(spec: mujoco.MjSpec, config, k: int, folder, size: float) -> float:
    """Adds object k's visual mesh "object_visual[_k]", hull mesh "object_hull[_k]", texture
    and material "object[_k]"; returns its extent along body +x (into the plank)."""
    mesh = load_object(folder, size, max_faces=config.max_faces)
    verts = mesh.verts @ OBJ_TO_BODY.T
    # MuJoCo's texcoords have v = 0 at the image's top row (its OBJ loader flips v too).
    uv = mesh.uv.reshape(-1, 2) * [1.0, -1.0] + [0.0, 1.0]
    spec.add_mesh(
        name=_name("object_visual", k),
        uservert=verts.ravel(),
        userface=mesh.faces.ravel(),
        usertexcoord=uv.ravel(),
        userfacetexcoord=np.arange(len(uv)),
    )
    spec.add_mesh(
        name=_name("object_hull", k), uservert=verts.ravel(), maxhullvert=config.max_hull_vertices
    )
    name = _name("object", k)
    _add_texture(spec, name, mesh.texture)
    material = spec.add_material(name=name)
    material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = name
    # The farthest point along local +x is the one that touches the plank.
    return float(np.max(verts[:, 0]))


def _object_tables(spec, config, ids, half_heights) -> _Objects:
    """Compiles the model once per object, its two geoms on that object's meshes, and reads
    what differs: geom frames and sizes, inertia and the compiler's constants, MJX's hull
    vertices and the renderer's triangles. Leaves the spec showing objects[0]."""
    hull, visual = spec.geom("object"), spec.geom("object_visual")
    rows, verts, tris = [], [], []
    for k in range(len(ids)):
        hull.meshname, visual.meshname = _name("object_hull", k), _name("object_visual", k)
        visual.material = _name("object", k)
        m = spec.compile()
        g = np.array(
            [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n) for n in ("object", "object_visual")]
        )
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "object")
        dofs = slice(m.body_dofadr[b], m.body_dofadr[b] + m.body_dofnum[b])
        rows.append(
            (
                m.geom_dataid[g],
                m.geom_matid[g[1]],
                m.geom_pos[g],
                m.geom_quat[g],
                m.geom_size[g],
                m.geom_rbound[g],
                m.geom_aabb[g],
                m.body_ipos[b],
                m.body_iquat[b],
                m.body_inertia[b],
                m.dof_M0[dofs],
                m.body_invweight0[b],
                m.dof_invweight0[dofs],
            )
        )
        verts.append(np.asarray(mjx_mesh.convex(m, m.geom_dataid[g[0]]).vert))
        ms = mesh_set(m, [int(g[1])], config.max_faces)
        tris.append({f: np.asarray(getattr(ms, f))[0] for f in ("v0", "e1", "e2", "valid", "uv")})
    hull.meshname, visual.meshname, visual.material = "object_hull", "object_visual", "object"
    cols = [np.array(c) for c in zip(*rows, strict=True)]
    n_vert = max(len(v) for v in verts)
    # Padding repeats vertex 0: MJX's plane-mesh contact picks distinct indices, and on ties
    # the first, so a copy never becomes a second contact at the same point.
    hull_vert = np.stack(
        [np.concatenate([v, np.repeat(v[:1], n_vert - len(v), 0)]) for v in verts]
    ).astype(np.float32)
    n_tri = max(len(t["valid"]) for t in tris)
    visual_sets = {f: np.stack([_pad(t[f], n_tri) for t in tris]) for f in tris[0]}
    visual_sets["has_uv"] = np.ones(len(ids), bool)
    f32 = np.float32
    return _Objects(
        np.array(ids, np.int32),
        np.array(half_heights, f32),
        cols[0].astype(np.int32),
        cols[1].astype(np.int32),
        *(c.astype(f32) for c in cols[2:]),
        hull_vert,
        visual_sets,
    )


def _add_surfaces(spec: mujoco.MjSpec, config) -> None:
    """Surface textures and the materials ground_t / plank_t per texture_id; the textured plank
    top; the ground shows pair 0 (per env: `_render_context`, `mj_model_for`)."""
    for name in sorted({p[j][0] for p in SURFACE_PAIRS for j in (0, 1)}):
        _add_texture(spec, f"surface_{name}", _texture(name))
    plank = spec.geom("plank")
    half_x, half_y = plank.size[0], plank.size[1]
    for t, ((ground, ground_rgb), (top, top_rgb)) in enumerate(SURFACE_PAIRS):
        for kind, image, rgb, repeat in (
            ("ground", ground, ground_rgb, [GROUND_TILES, GROUND_TILES]),
            ("plank", top, top_rgb, [2 * half_x / PLANK_TILE, 2 * half_y / PLANK_TILE]),
        ):
            material = spec.add_material(name=f"{kind}_{t}", rgba=[*rgb, 1.0], texrepeat=repeat)
            material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = f"surface_{image}"
    plank.pos = [plank.pos[0], plank.pos[1], plank.pos[2] - PLANK_TOP_GAP]
    spec.body("plank").add_geom(
        name="plank_top",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[half_x, half_y, 0.01],
        material="plank_0",
        contype=0,
        conaffinity=0,
        group=0,
    )
    if config.ground == "paired":
        ground = spec.geom("ground")
        # MuJoCo draws a geom's material colour only while its rgba is the default.
        ground.material, ground.rgba = "ground_0", [0.5, 0.5, 0.5, 1.0]


def _texture(name: str) -> np.ndarray:
    """uint8 [H, W, 3] of assets/textures/NAME.png."""
    return np.asarray(Image.open(ASSETS / "textures" / f"{name}.png").convert("RGB"), np.uint8)


def _add_texture(spec: mujoco.MjSpec, name: str, image: np.ndarray) -> None:
    h, w, _ = image.shape
    spec.add_texture(
        name=name,
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        width=w,
        height=h,
        nchannel=3,
        data=image.ravel().tolist(),
    )


def _pad(a: np.ndarray, n: int) -> np.ndarray:
    """a padded with zeros (False) along axis 0 to n rows."""
    return np.concatenate([a, np.zeros((n - len(a), *a.shape[1:]), a.dtype)])
