"""Mesh-on-incline: GeomOnIncline with a textured object mesh in place of the primitive.

The paper's YCB-on-incline (suite_reference.md §1, §6) slid textured YCB scans down the plank;
those cannot be fetched here, so the shipped objects are textured meshes from pybullet_data
(assets/PROVENANCE.md), and `object_dir` loads a user's own object from a folder in the YCB
google_16k layout (`textured.obj` + `texture_map.png`). Either is decimated to at most
`max_faces` triangles (the renderer ray-casts each) with its uvs kept, its texture shrunk to at
most 128 x 128, re-centred and scaled so its longest side is `object_size` m (the incline's 2.5x
YCB scale gives 0.26-0.38 m).

The object body carries two geoms built from the same vertices:
- "object": the collision geom, a mesh whose convex hull (MuJoCo's, at most `max_hull_vertices`
  vertices) is what MJX collides; group 3, not drawn. The contact pairs of GeomOnIncline name it,
  so the friction randomization and the frictionless pair carry over unchanged. It carries the
  mass; inertia follows the hull's shape.
- "object_visual": the textured mesh, drawn only (contype = conaffinity = 0, massless, group 0).

The object is chosen per env (`object` / `object_dir`), not per reset: switching meshes per reset
would need every object's geoms in the model and batched geom / inertia fields. Everything else
(per-reset angle, mass, friction and colours; action; reward; terminations; LD state with
object_id = the object's index in MESH_OBJECTS, len(MESH_OBJECTS) for a user folder) is
GeomOnIncline's. Reset lays the object with its modelled "up" (+z of the OBJ after the y-up ->
z-up turn the shipped assets got; YCB scans are z-up) away from the plank and its OBJ +x downhill.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from envs_mjx.domains._assets import ASSETS
from envs_mjx.domains.incline import GeomOnIncline, InclineConfig
from envs_mjx.domains.mesh_object import load_object

MESH_OBJECTS = ("duck", "domino")
# OBJ frame (z up) -> object body frame, in which reset points local +x into the plank and local
# +z downhill (GeomOnIncline's convention): body = (-z, y, x). A proper rotation (det +1).
OBJ_TO_BODY = np.array([[0, 0, -1], [0, 1, 0], [1, 0, 0]], np.float64)


@dataclasses.dataclass(frozen=True)
class MeshInclineConfig(InclineConfig):
    """object: a name in MESH_OBJECTS; object_dir, when set, a YCB-layout folder used instead.
    (The inherited object_id is unused: the LD object id is the mesh's index.)"""

    object: str = "duck"
    object_dir: str | None = None
    object_size: float = 0.3
    object_mass: float = 0.05
    max_faces: int = 300
    max_hull_vertices: int = 32


def default_config() -> MeshInclineConfig:
    return MeshInclineConfig()


class MeshOnIncline(GeomOnIncline):
    """A textured mesh object sliding on a randomly tilted plank, pushed along the slope."""

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

    def _add_object(self, spec: mujoco.MjSpec, config: MeshInclineConfig) -> float:
        if config.object_dir is not None:
            folder, self._object_index = config.object_dir, len(MESH_OBJECTS)
        elif config.object in MESH_OBJECTS:
            folder = ASSETS / "meshes" / config.object
            self._object_index = MESH_OBJECTS.index(config.object)
        else:
            raise ValueError(f"object must be one of {MESH_OBJECTS}, got {config.object!r}")
        mesh = load_object(folder, config.object_size, max_faces=config.max_faces)
        verts = (mesh.verts @ OBJ_TO_BODY.T).ravel()
        # MuJoCo's texcoords have v = 0 at the image's top row (its OBJ loader flips v too).
        uv = mesh.uv.reshape(-1, 2) * [1.0, -1.0] + [0.0, 1.0]
        spec.add_mesh(
            name="object_visual",
            uservert=verts,
            userface=mesh.faces.ravel(),
            usertexcoord=uv.ravel(),
            userfacetexcoord=np.arange(len(uv)),
        )
        spec.add_mesh(name="object_hull", uservert=verts, maxhullvert=config.max_hull_vertices)
        h, w, _ = mesh.texture.shape
        spec.add_texture(
            name="object",
            type=mujoco.mjtTexture.mjTEXTURE_2D,
            width=w,
            height=h,
            nchannel=3,
            data=mesh.texture.ravel().tolist(),
        )
        material = spec.add_material(name="object")
        material.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "object"
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
        # The farthest point along local +x is the one that touches the plank.
        return float(np.max(mesh.verts @ OBJ_TO_BODY[0]))
