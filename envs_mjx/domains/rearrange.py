"""Rearrange (docs/reference/suite.md §1-2 "Rearrange", "Rearrange-Reacher", "-Franka", §6):
four free objects in a walled tray, pushed by a 2-link reacher or a Franka Panda.

`envs_mjx.make("RearrangeGeom" | "RearrangeYCB", arm="reacher" | "franka", version=...)`.

Versions 0-11 (the reference's -v0..11): the object set and colours of v mod 6, the tray texture of
v (v6-11: a black tray). `version=v` gives every env version v; by default (`version=None`) env
slot i of a batch uses `versions[i mod len(versions)]` with versions (0, 1, 2, 3), as the reference
trained its 64 envs (`reset_batch`, which `jaml.stream.collect` uses); `reset(rng)` alone draws the
slot uniformly, `reset(rng, slot)` takes it. info["version"] is the slot, the LD state's first entry
versions[slot] / 10.

One model per version, one structure. The env compiles the scene once per version in `versions`;
every compiled model has the same bodies, geoms and meshes in the same order (an object slot holds
one collision geom per shape it takes in any of the versions; a shape a version does not use is
shrunk to 1 mm, massless, at the body's centre, where it never touches anything). The fields
that differ between the versions' models (masses, inertias, geom sizes, frames and friction, the
compiler's mass-derived constants, MJX's convex-hull data of a can whose size varies) become
per-env mjx.Model fields indexed by info["version"] (`physics_model`); C MuJoCo and
mujoco.Renderer get the version's compiled model itself (`mj_model_for`), and the renderer gets
its colours, textures, primitive sizes and object meshes (`_render_context`).

Objects. Geom: the reference's cylinder (r 0.03, 0.13 long, 0.2 kg), cube (0.05 x 0.10 x 0.15,
0.05 kg, friction 1), sphere (r 0.04, 0.1 kg) and sphere1 (r 0.06, 0.3 kg), coloured per version.
YCB: the YCB scans are not available here; each YCB object is a textured stand-in of the scan's
extent and mass (§6): cans are robosuite's soda can, boxes the cereal box or pybullet's domino,
fruit robosuite's lemon tinted (assets/meshes, PROVENANCE.md). They collide as their proxy shape:
a can as a 16-sided prism, a box as a box, a fruit as a sphere of its mean radius. MJX has no
cylinder-box collision, so every cylinder collides as the prism (drawn as a true cylinder for
Geom).

Arms. reacher: torque 3 a N m per joint (a in [-1, 1]); each action is 4 repeats of one Bullet step
(2 substeps of 5 ms), after each of which the reference's software limits |q0| <= 31 pi / 32,
|q1| <= 26 pi / 32 set q to the limit and reverse qdot. franka: torque clip(limit a + qfrc_bias,
+-limit) with limits (87, 87, 87, 87, 12, 12, 12) N m (gravity and Coriolis compensation; the bias
is the one MJX computed at the previous substep's state), joint limits by hard reset with qdot 0;
the fingers are passive.

Reset: arm pose (reacher q ~U(+-0.75 pi); franka by IK to a gripper-down end-effector pose drawn in
x, y ~U(-0.5, 0.5), z ~U(0.05, 0.35), as the reference), objects at xy ~U(+-0.15), z ~U(z_lo,
0.075) (z_lo 0.04 Geom, 0.03 YCB) with quaternion normalize(U[0, 1]^4), then 20 Bullet steps of
zero action and 10 of random torques U(+-0.5 limit).

Reward (per step, times reward_scale, by default 1 / episode_length):
1 - mean_i min(|obj_i,xy - target_i|, 1), target (0.2, -0.2) for boxes and cans, (0.2, 0.2)
for everything else (fruit and all Geom shapes).
Done when an object leaves [-0.45, 0.45]^2 x [-0.05, 0.20]; franka also when the end effector
rises above 0.2 m + the highest object or leaves |x|, |y| <= 0.5. Episodes last 50 steps.

LD state (reacher 53, franka 63): version / 10; sin, cos of each arm joint; per object its position
normalised to [-1, 1] over the workspace (clipped) and its rotation matrix, row-major.

Deviations from the reference are listed in docs/rearrange.md.
"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco.mjx._src import mesh as mjx_mesh

from envs_mjx.base import Env, drawn_rgba, physics_step
from envs_mjx.c_physics import CPhysics
from envs_mjx.config import ARMS, PHYSICS, RearrangeConfig
from envs_mjx.domains._assets import ASSETS, asset
from envs_mjx.domains.mesh_incline import _add_texture, _pad, _texture
from envs_mjx.domains.mesh_object import load_object
from envs_mjx.render.context import mesh_set, texture_index

# What physics="c" brings back after an env step besides qpos / qvel: what the LD state, reward
# (the Franka's end-effector site) and renderer (geom and camera poses) read.
C_POSES = ("geom_xpos", "geom_xmat", "site_xpos", "cam_xpos", "cam_xmat")
VERSIONS = tuple(range(12))
NUM_OBJECTS = 4
WORKSPACE_LO = np.array([-0.45, -0.45, -0.05], np.float32)
WORKSPACE_HI = np.array([0.45, 0.45, 0.20], np.float32)
TARGET_BOX_CAN = (0.2, -0.2)
TARGET_OTHER = (0.2, 0.2)
SPAWN_XY = 0.15
SPAWN_Z_HI = 0.075


@dataclasses.dataclass(frozen=True)
class ObjectKind:
    """shape: "cylinder" | "box" | "sphere"; extent: full size along x, y, z (m); target: "box_can"
    or "other" (which reward target); mesh: a textured mesh in assets/meshes (YCB stand-ins) or
    None (drawn as the shape); tint: rgb the mesh's texture is multiplied by."""

    shape: str
    extent: tuple[float, float, float]
    mass: float
    friction: float = 0.5
    target: str = "other"
    mesh: str | None = None
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)


GEOM_KINDS = {
    "cylinder": ObjectKind("cylinder", (0.06, 0.06, 0.13), 0.2),
    "cube": ObjectKind("box", (0.05, 0.10, 0.15), 0.05, friction=1.0),
    "sphere": ObjectKind("sphere", (0.08, 0.08, 0.08), 0.1),
    "sphere1": ObjectKind("sphere", (0.12, 0.12, 0.12), 0.3),
}
# The reference's YCB objects at their Rearrange scale (extent x scale, mass; §6), as stand-ins.
YCB_KINDS = {
    "chef_can": ObjectKind("cylinder", (0.103, 0.102, 0.133), 0.2, target="box_can", mesh="can"),
    "tuna_can": ObjectKind(
        "cylinder", (0.094, 0.094, 0.060), 0.2, target="box_can", mesh="can", tint=(0.7, 0.8, 1.0)
    ),
    "soup_can": ObjectKind(
        "cylinder", (0.088, 0.088, 0.122), 0.2, target="box_can", mesh="can", tint=(1.0, 0.5, 0.45)
    ),
    "sugar_box": ObjectKind("box", (0.050, 0.106, 0.151), 0.05, target="box_can", mesh="cereal"),
    "pudding_box": ObjectKind(
        "box", (0.046, 0.109, 0.135), 0.05, target="box_can", mesh="cereal", tint=(0.8, 0.6, 0.4)
    ),
    "gelatin_box": ObjectKind("box", (0.043, 0.103, 0.126), 0.05, target="box_can", mesh="domino"),
    "apple": ObjectKind("sphere", (0.083, 0.082, 0.079), 0.1, mesh="lemon", tint=(1.0, 0.25, 0.2)),
    "pear": ObjectKind("sphere", (0.073, 0.111, 0.072), 0.1, mesh="lemon", tint=(0.75, 0.9, 0.3)),
    "orange": ObjectKind("sphere", (0.079, 0.081, 0.078), 0.1, mesh="lemon", tint=(1.0, 0.6, 0.1)),
    "lemon": ObjectKind("sphere", (0.079, 0.077, 0.069), 0.1, mesh="lemon"),
    "plum": ObjectKind("sphere", (0.080, 0.077, 0.074), 0.1, mesh="lemon", tint=(0.55, 0.2, 0.6)),
}
# Object sets of v mod 6 (§1).
GEOM_SETS = (("cylinder", "cube", "sphere", "sphere1"),) * 5 + (
    ("cube", "sphere", "sphere", "cube"),
)
YCB_SETS = (
    ("chef_can", "gelatin_box", "apple", "pear"),
    ("tuna_can", "gelatin_box", "lemon", "orange"),
    ("chef_can", "sugar_box", "pear", "lemon"),
    ("soup_can", "sugar_box", "lemon", "apple"),
    ("chef_can", "pudding_box", "orange", "plum"),
    ("sugar_box", "orange", "plum", "pudding_box"),
)
_B, _M, _R, _Y, _C, _G = (0, 0, 1), (1, 0, 1), (1, 0, 0), (1, 1, 0), (0, 1, 1), (0, 1, 0)
GEOM_COLOURS = np.array(
    [
        [_B, _M, _R, _Y],
        [_Y, _C, _M, _G],
        [_G, _B, _Y, _C],
        [_R, _Y, _G, _M],
        [_M, _Y, _R, (0.9, 0.9, 0.9)],
        [_C, _G, _Y, _B],
    ],
    np.float32,
)
# Tray texture of v0-5 (birch, gray, orange, blue, green, birch in the reference): stand-ins from
# assets/textures (image, rgb it is multiplied by). v6-11: black.
TRAY_TEXTURES = (
    ("light-wood", (1.0, 1.0, 1.0)),
    ("light-gray-floor-tile", (1.0, 1.0, 1.0)),
    ("clay", (1.0, 0.75, 0.4)),
    ("blue-wood", (1.0, 1.0, 1.0)),
    ("green-wood", (1.0, 1.0, 1.0)),
    ("light-wood", (1.0, 1.0, 1.0)),
)
BLACK = "black"  # the v6-11 tray: an 8 x 8 black image, so every version's tray is textured
TRAY_PANELS = ("panel_left", "panel_box", "panel_fruit")
WALLS = ("wall_px", "wall_nx", "wall_py", "wall_ny")
TRAY_TILE = 0.4  # m, side of a texture tile on the tray
PRISM_SIDES = 16
INACTIVE = 1e-3  # m, size of a slot's collision geom for a shape the version does not use
# Arms: per-joint torque limits (N m) and software joint limits.
REACHER_TORQUE = (3.0, 3.0)
REACHER_LIMITS = (31 * np.pi / 32, 26 * np.pi / 32)
FRANKA_TORQUE = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
FRANKA_REST = (-0.0412, 0.5043, 0.0048, -2.6232, -0.1651, 3.1273, 0.9135)
FRANKA_CHAIN = ("link1", "link2", "link3", "link4", "link5", "link6", "link7", "hand")
BULLET_SUBSTEPS = 2  # MJX substeps (5 ms) per Bullet step (10 ms)


def default_config() -> RearrangeConfig:
    return RearrangeConfig()


class Rearrange(Env):
    """Four objects in a walled tray and an arm; subclasses pick the object catalogue."""

    objects_kind = "geom"

    def __init__(self, config: RearrangeConfig | None = None, pixels_fn=None):
        config = config or default_config()
        if config.arm not in ARMS:
            raise ValueError(f"arm must be one of {ARMS}, got {config.arm!r}")
        versions = (config.version,) if config.version is not None else tuple(config.versions)
        bad = [v for v in versions if v not in VERSIONS]
        if bad or not versions:
            raise ValueError(f"version must be in {list(VERSIONS)}, got {bad or versions!r}")
        if config.physics not in PHYSICS:
            raise ValueError(f"physics must be one of {PHYSICS}, got {config.physics!r}")
        if config.max_contacts is not None and (
            isinstance(config.max_contacts, bool) or not isinstance(config.max_contacts, int)
            or config.max_contacts < 1
        ):
            raise ValueError(
                f"max_contacts must be a positive int or None, got {config.max_contacts!r}"
            )
        if config.n_frames != config.repeats * BULLET_SUBSTEPS:
            config = dataclasses.replace(config, n_frames=config.repeats * BULLET_SUBSTEPS)
        self._versions = versions
        self._kinds = GEOM_KINDS if self.objects_kind == "geom" else YCB_KINDS
        self._sets = GEOM_SETS if self.objects_kind == "geom" else YCB_SETS
        self._models = [self._compile(config, v) for v in versions]
        mj_model = self._models[0]
        self._check_structure()
        self._c = CPhysics(self._models) if config.physics == "c" else None
        m = mj_model
        self._franka = config.arm == "franka"
        n_arm = 7 if self._franka else 2
        self._arm_qpos = np.arange(n_arm)
        self._torque = np.array(FRANKA_TORQUE if self._franka else REACHER_TORQUE, np.float32)
        if self._franka:
            self._qlo = np.asarray(m.jnt_range[:n_arm, 0], np.float32)
            self._qhi = np.asarray(m.jnt_range[:n_arm, 1], np.float32)
        else:
            self._qhi = np.array(REACHER_LIMITS, np.float32)
            self._qlo = -self._qhi
        bodies = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"obj{k}") for k in range(4)]
        self._obj_qpos = np.array([m.jnt_qposadr[m.body_jntadr[b]] for b in bodies])
        self._ee_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "ee")
        self._tables = self._version_tables()
        names = ["version"]
        for j in range(n_arm):
            names += [f"sin_q{j}", f"cos_q{j}"]
        for k in range(NUM_OBJECTS):
            names += [f"obj{k}_{a}" for a in "xyz"]
            names += [f"obj{k}_r{i}{j}" for i in range(3) for j in range(3)]
        super().__init__(config, mj_model, tuple(names), pixels_fn)

    # -- the model per version --------------------------------------------------------------------

    def _slot_shapes(self) -> list[list[str]]:
        """Per object slot, the shapes it takes over the env's versions (first-seen order)."""
        out = [[] for _ in range(NUM_OBJECTS)]
        for v in self._versions:
            for k, name in enumerate(self._sets[v % 6]):
                if self._kinds[name].shape not in out[k]:
                    out[k].append(self._kinds[name].shape)
        return out

    def _compile(self, config: RearrangeConfig, version: int) -> mujoco.MjModel:
        """The scene with version `version`'s tray and objects; the same structure for every
        version of the env (see the module docstring)."""
        spec = mujoco.MjSpec.from_file(asset(f"rearrange_{config.arm}.xml"))
        if config.max_contacts is not None:
            spec.add_numeric(name="max_contact_points", data=[config.max_contacts])
        # Tray: every texture any of the env's versions uses, then this version's on the panels.
        trays = sorted({_tray_name(v) for v in self._versions})
        for name in trays:
            image = np.zeros((8, 8, 3), np.uint8) if name == BLACK else _texture(name)
            _add_texture(spec, f"tray_{name}", image)
            rgb = (0.0, 0.0, 0.0) if name == BLACK else dict(TRAY_TEXTURES)[name]
            mat = spec.add_material(
                name=f"tray_{name}", rgba=[*rgb, 1.0], texuniform=True, specular=0.2
            )
            mat.texrepeat = [2.0 / TRAY_TILE, 2.0 / TRAY_TILE]
            mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = f"tray_{name}"
        tray = _tray_name(version)
        for p in TRAY_PANELS:
            spec.geom(p).material = f"tray_{tray}"
        wall_rgb = _tray_mean_rgb(tray)
        for w in WALLS:
            spec.geom(w).rgba = [*wall_rgb, 1.0]
        # Object meshes and textures (YCB): every (version, slot) mesh in every model.
        if self.objects_kind == "ycb":
            for mesh_name in sorted({k.mesh for k in self._kinds.values()}):
                mesh = _object_mesh(mesh_name, config.max_faces)
                _add_texture(spec, f"objtex_{mesh_name}", mesh.texture)
            for v in self._versions:
                for k, name in enumerate(self._sets[v % 6]):
                    kind = self._kinds[name]
                    verts, uv, faces = _fit_mesh(_object_mesh(kind.mesh, config.max_faces), kind)
                    spec.add_mesh(
                        name=f"obj{k}_visual_v{v}",
                        uservert=verts.ravel(),
                        userface=faces.ravel(),
                        usertexcoord=uv.ravel(),
                        userfacetexcoord=np.arange(len(uv)),
                    )
                    mat = spec.add_material(name=f"obj{k}_v{v}", rgba=[*kind.tint, 1.0])
                    mat.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = f"objtex_{kind.mesh}"
        shapes = self._slot_shapes()
        names = self._sets[version % 6]
        for k in range(NUM_OBJECTS):
            kind = self._kinds[names[k]]
            colour = GEOM_COLOURS[version % 6][k] if self.objects_kind == "geom" else (1, 1, 1)
            visible = self.objects_kind == "geom"
            body = spec.worldbody.add_body(name=f"obj{k}", pos=[0.0, 0.1 * k, 0.1])
            body.add_freejoint(name=f"obj{k}")
            # Explicit inertia about the body frame (the shape's centre and axes): every version's
            # model then has the same inertial-frame flags and sparse mass-matrix layout.
            body.explicitinertial = True
            body.mass, body.inertia = kind.mass, _inertia(kind)
            body.ipos, body.iquat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
            for shape in shapes[k]:
                _add_collision_geom(spec, body, k, shape, kind, colour, visible)
            if visible and "cylinder" in shapes[k]:
                on = kind.shape == "cylinder"
                r, h = (kind.extent[0] / 2, kind.extent[2] / 2) if on else (INACTIVE, INACTIVE)
                body.add_geom(
                    name=f"obj{k}_cylinder_visual",
                    type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                    size=[r, h, 0.0],
                    rgba=[*colour, 1.0],
                    contype=0,
                    conaffinity=0,
                    mass=0,
                )
            if not visible:
                body.add_geom(
                    name=f"obj{k}_visual",
                    type=mujoco.mjtGeom.mjGEOM_MESH,
                    meshname=f"obj{k}_visual_v{version}",
                    material=f"obj{k}_v{version}",
                    contype=0,
                    conaffinity=0,
                    mass=0,
                )
        return spec.compile()

    def _check_structure(self) -> None:
        """Every version's model has the same bodies, joints, geoms (types, collision bits,
        meshes of colliding geoms): only then can one MJX program step them all."""
        m0 = self._models[0]
        for m in self._models[1:]:
            for field in (
                "geom_type",
                "geom_contype",
                "geom_conaffinity",
                "body_parentid",
                "jnt_type",
            ):
                if not np.array_equal(getattr(m, field), getattr(m0, field)):
                    raise AssertionError(f"version models differ in {field}")
            colliding = (m0.geom_contype | m0.geom_conaffinity) > 0
            if not np.array_equal(m.geom_dataid[colliding], m0.geom_dataid[colliding]):
                raise AssertionError("version models differ in a colliding geom's mesh")

    def _version_tables(self) -> dict[str, Any]:
        """Per-version tables ([V, ...]) of everything that differs between the versions."""
        ms = self._models
        physics = {}
        for field in PHYSICS_FIELDS:
            values = [np.asarray(getattr(m, field)) for m in ms]
            if any(not np.array_equal(values[0], v) for v in values[1:]):
                physics[field] = np.stack(values).astype(np.float32)
        # MJX's convex data of colliding meshes (a can's prism scaled per version).
        convex = {}
        m0 = ms[0]
        for g in np.flatnonzero(
            (m0.geom_type == mujoco.mjtGeom.mjGEOM_MESH) & (m0.geom_contype > 0)
        ):
            mid = int(m0.geom_dataid[g])
            hulls = [mjx_mesh.convex(m, mid) for m in ms]
            if any(not np.array_equal(h.vert, hulls[0].vert) for h in hulls[1:]):
                for h in hulls[1:]:
                    for f in ("face_normal", "edge", "edge_face_normal"):
                        if np.shape(getattr(h, f)) != np.shape(getattr(hulls[0], f)):
                            raise AssertionError(f"hull topology differs between versions ({f})")
                convex[mid] = {
                    f: np.stack([np.asarray(getattr(h, f)) for h in hulls]).astype(np.float32)
                    for f in ("vert", "face", "face_normal", "edge_face_normal")
                }

        rgb_role = int(mujoco.mjtTextureRole.mjTEXROLE_RGB)
        geom_tex = []
        for m in ms:
            tex = np.full(m.ngeom, -1, np.int32)
            has = m.geom_matid >= 0
            texid = m.mat_texid[m.geom_matid[has], rgb_role]
            tex[has] = np.where(texid >= 0, texture_index(m)[texid], -1)
            geom_tex.append(tex)
        targets = []
        for v in self._versions:
            kinds = [self._kinds[n] for n in self._sets[v % 6]]
            targets.append(
                [TARGET_BOX_CAN if k.target == "box_can" else TARGET_OTHER for k in kinds]
            )
        return {
            "physics": physics,
            "convex": convex,
            "rgba": np.stack([drawn_rgba(m) for m in ms]),
            "geom_tex": np.stack(geom_tex),
            "target": np.array(targets, np.float32),
            "version": np.array(self._versions, np.float32),
            "spawn_z": np.array(
                [0.04 if self.objects_kind == "geom" else 0.03 for _ in self._versions], np.float32
            ),
        }

    @property
    def versions(self) -> tuple[int, ...]:
        """Env slot i of a batch uses versions[i mod len(versions)]."""
        return self._versions

    def _ld_groups(self):
        groups = []
        for n in self.ld_state_names:
            if n == "version":
                groups.append("other")
            elif "_r" in n:
                groups.append("orientation")
            else:
                groups.append("position")
        return tuple(groups)

    # -- per-env model ----------------------------------------------------------------------------

    def _model_fields(self, info):
        slot = info["version"]
        return {f: jnp.asarray(t)[slot] for f, t in self._tables["physics"].items()}

    def physics_model(self, info):
        model = super().physics_model(info)
        if not self._tables["convex"]:
            return model
        convex = list(model._impl.mesh_convex)
        for mid, table in self._tables["convex"].items():
            fields = {f: jnp.asarray(t)[info["version"]] for f, t in table.items()}
            convex[mid] = convex[mid].replace(**fields)
        return model.tree_replace({"_impl.mesh_convex": tuple(convex)})

    def mj_model_for(self, info) -> mujoco.MjModel:
        """The C MjModel of this env's version (its compiled model)."""
        return copy.deepcopy(self._models[int(info["version"])])

    # -- reset ------------------------------------------------------------------------------------

    def reset(self, rng: jax.Array, version_slot: jax.Array | int | None = None):
        """As Env.reset; version_slot (may be traced) picks versions[version_slot], None draws it
        uniformly from rng."""
        return self._reset_from(*self._sample_reset(rng, version_slot))

    def reset_batch(self, rng: jax.Array, num_envs: int):
        """Env slot i uses versions[i mod len(versions)]."""
        slots = jnp.arange(num_envs, dtype=jnp.int32) % len(self._versions)
        return jax.vmap(self.reset)(jax.random.split(rng, num_envs), slots)

    def _sample_reset(self, rng, version_slot=None):
        k_slot, k_arm, k_xy, k_z, k_quat, k_torque = jax.random.split(rng, 6)
        if version_slot is None:
            slot = jax.random.randint(k_slot, (), 0, len(self._versions))
        else:
            slot = jnp.asarray(version_slot, jnp.int32)
        qpos = jnp.zeros(self.mj_model.nq)
        if self._franka:
            qpos = qpos.at[:7].set(self._franka_ik(k_arm))
        else:
            r = self.config.reacher_init_range
            qpos = qpos.at[:2].set(jax.random.uniform(k_arm, (2,), minval=-r, maxval=r))
        xy = jax.random.uniform(k_xy, (NUM_OBJECTS, 2), minval=-SPAWN_XY, maxval=SPAWN_XY)
        z_lo = jnp.asarray(self._tables["spawn_z"])[slot]
        z = jax.random.uniform(k_z, (NUM_OBJECTS,), minval=z_lo, maxval=SPAWN_Z_HI)
        quat = jax.random.uniform(k_quat, (NUM_OBJECTS, 4), minval=1e-6, maxval=1.0)
        quat = quat / jnp.linalg.norm(quat, axis=1, keepdims=True)
        obj = jnp.concatenate([xy, z[:, None], quat], axis=1)  # [4, 7]
        idx = self._obj_qpos[:, None] + np.arange(7)[None]
        qpos = qpos.at[idx].set(obj)
        steps = self.config.random_torque_steps
        torque = jax.random.uniform(k_torque, (steps, len(self._torque)), minval=-0.5, maxval=0.5)
        info = {
            "geom_rgba": jnp.asarray(self._tables["rgba"])[slot],
            "version": slot,
            "reset_action": torque,  # reset only: taken out by _settle
        }
        return qpos, jnp.zeros(self.mj_model.nv), info

    def _settle(self, model, data, info):
        info = dict(info)
        # Settle steps (zero action), then the random torques: one scan, one compiled step.
        if self.config.settle_steps + self.config.random_torque_steps == 0:
            del info["reset_action"]
            return data, info  # no physics in reset (a cheaper compile; tests use it)
        actions = jnp.concatenate(
            [jnp.zeros((self.config.settle_steps, len(self._torque))), info.pop("reset_action")]
        )
        slot = info["version"]
        data, _ = jax.lax.scan(
            lambda d, a: (self._bullet_step(model, d, a, slot), None), data, actions
        )
        return self._refreshed(data, slot), info

    def _franka_ik(self, rng):
        """Joint angles that put the gripper, pointing down, at a random point x, y ~U(-0.5, 0.5),
        z ~U(0.05, 0.35) (the reference's random init; see `franka_ik`)."""
        k_xy, k_z = jax.random.split(rng)
        target = jnp.concatenate(
            [
                jax.random.uniform(k_xy, (2,), minval=-0.5, maxval=0.5),
                jax.random.uniform(k_z, (1,), minval=0.05, maxval=0.35),
            ]
        )
        return self.franka_ik(target)

    def franka_ik(self, target: jax.Array) -> jax.Array:
        """Joint angles [7] that put the end effector at `target` (world, m) with the gripper
        pointing down: damped least squares from the rest pose, clipped to the joint limits; an
        unreachable target ends at a nearby reachable pose."""
        down = jnp.array([0.0, 0.0, -1.0])
        fk = self._franka_fk()

        def residual(q):
            pos, z_axis = fk(q)
            return jnp.concatenate([pos - target, 0.3 * (z_axis - down)])

        def body(_, q):
            r = residual(q)
            jac = jax.jacfwd(residual)(q)
            step = jac.T @ jnp.linalg.solve(jac @ jac.T + 1e-3 * jnp.eye(6), r)
            return jnp.clip(q - step, self._qlo, self._qhi)

        q0 = jnp.asarray(FRANKA_REST, jnp.float32)
        return jax.lax.fori_loop(0, self.config.ik_iterations, body, q0)

    def _franka_fk(self):
        """q [7] -> (end-effector site position, hand z axis), world frame: the model's body
        chain (body_pos / body_quat, hinge about local z) in closed form."""
        m = self.mj_model
        ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in FRANKA_CHAIN]
        base = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "link0")
        pos = [np.asarray(m.body_pos[i], np.float32) for i in ids]
        rot = [_quat_to_mat_np(m.body_quat[i]) for i in ids]
        site_pos = np.asarray(m.site_pos[self._ee_site], np.float32)
        base_pos = np.asarray(m.body_pos[base], np.float32)

        def fk(q):
            r, p = jnp.eye(3), jnp.asarray(base_pos)
            for j in range(len(ids)):
                p = p + r @ pos[j]
                r = r @ rot[j]
                if j < 7:
                    c, s = jnp.cos(q[j]), jnp.sin(q[j])
                    rz = jnp.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
                    r = r @ rz
            return p + r @ site_pos, r[:, 2]

        return fk

    # -- stepping ---------------------------------------------------------------------------------

    def _bullet_step(self, model, data, action, slot):
        """One reference Bullet step (10 ms): the arm's torque (franka: plus the bias), 2
        substeps (MJX, or C MuJoCo with physics="c"), then the software joint limits."""
        torque = jnp.asarray(self._torque) * jnp.clip(action, -1.0, 1.0)
        if self._franka:
            torque = torque + data.qfrc_bias[:7]
        ctrl = jnp.clip(torque, -self._torque, self._torque)
        data = data.replace(ctrl=ctrl)
        if self._c is None:
            data = jax.lax.fori_loop(
                0, BULLET_SUBSTEPS, lambda _, d: physics_step(model, d), data
            )
        else:
            data = self._c_substeps(model, data, slot)
        q = data.qpos[self._arm_qpos]
        qd = data.qvel[self._arm_qpos]
        over = (q < self._qlo) | (q > self._qhi)
        new_qd = jnp.where(over, 0.0 if self._franka else -qd, qd)
        if self.config.max_joint_velocity is not None:
            new_qd = jnp.clip(new_qd, -self.config.max_joint_velocity,
                              self.config.max_joint_velocity)
        qpos = data.qpos.at[self._arm_qpos].set(jnp.clip(q, self._qlo, self._qhi))
        qvel = data.qvel.at[self._arm_qpos].set(new_qd)
        return data.replace(qpos=qpos, qvel=qvel)

    def _c_substeps(self, model, data, slot):
        """The Bullet step's substeps in C MuJoCo; for the Franka, qfrc_bias as the last substep
        computed it (as mjx.step leaves it)."""
        out = self._c.step(
            slot, data.qpos, data.qvel, data.ctrl, BULLET_SUBSTEPS, bias=self._franka
        )
        time = data.time + BULLET_SUBSTEPS * model.opt.timestep
        return data.replace(time=time, **out)

    def _refreshed(self, data, slot):
        """With physics="c": the poses the LD state, reward and pixels read, from C MuJoCo at the
        final qpos (MJX's substeps leave them at the state before its last substep, 5 ms
        earlier)."""
        if self._c is None:
            return data
        return data.replace(**self._c.poses(slot, data.qpos, C_POSES))

    def _advance(self, model, data, action, info):
        slot = info["version"]
        data = jax.lax.fori_loop(
            0, self.config.repeats, lambda _, d: self._bullet_step(model, d, action, slot), data
        )
        return self._refreshed(data, slot)

    # -- LD state, reward, done -------------------------------------------------------------------

    def object_poses(self, qpos) -> tuple[jax.Array, jax.Array]:
        """(positions [4, 3], rotation matrices [4, 3, 3]) of the objects, from qpos."""
        idx = self._obj_qpos[:, None] + np.arange(7)[None]
        obj = qpos[idx]
        return obj[:, :3], jax.vmap(_quat_to_mat)(obj[:, 3:])

    def _ld_state(self, data, info):
        q = data.qpos[self._arm_qpos]
        arm = jnp.stack([jnp.sin(q), jnp.cos(q)], axis=1).reshape(-1)
        pos, rot = self.object_poses(data.qpos)
        lo, hi = jnp.asarray(WORKSPACE_LO), jnp.asarray(WORKSPACE_HI)
        pos = jnp.clip(2.0 * (pos - lo) / (hi - lo) - 1.0, -1.0, 1.0)
        objects = jnp.concatenate([pos, rot.reshape(NUM_OBJECTS, 9)], axis=1).reshape(-1)
        version = jnp.asarray(self._tables["version"])[info["version"]] / 10.0
        return jnp.concatenate([version[None], arm, objects]).astype(jnp.float32)

    def _reward_done(self, prev, data, action, info):
        pos, _ = self.object_poses(data.qpos)
        target = jnp.asarray(self._tables["target"])[info["version"]]
        dist = jnp.linalg.norm(pos[:, :2] - target, axis=1)
        reward = 1.0 - jnp.mean(jnp.minimum(dist, 1.0))
        lo, hi = jnp.asarray(WORKSPACE_LO), jnp.asarray(WORKSPACE_HI)
        outside = jnp.any((pos < lo) | (pos > hi))
        terminated = outside
        metrics = {"objects_outside": outside.astype(jnp.float32)}
        if self._franka:
            ee = data.site_xpos[self._ee_site]
            too_high = ee[2] > 0.2 + jnp.max(pos[:, 2])
            too_far = jnp.any(jnp.abs(ee[:2]) > 0.5)
            terminated = terminated | too_high | too_far
            metrics["ee_out"] = (too_high | too_far).astype(jnp.float32)
        return reward, terminated, metrics

    # -- rendering --------------------------------------------------------------------------------

    def _render_context(self, ctx, info):
        """This env's version in the render context: textures of the tray and objects, the sizes
        of primitive geoms (a slot's unused shapes are 1 mm), and the object meshes."""
        slot = info["version"]
        ctx = ctx.replace(geom_tex=jnp.asarray(self._tables["geom_tex"])[slot])
        if len(self._models) == 1:
            return ctx
        group_size = tuple(
            jnp.asarray(np.stack([m.geom_size[list(ids)] for m in self._models]), jnp.float32)[slot]
            for ids in ctx.group_geoms
        )
        ctx = ctx.replace(group_size=group_size)
        if ctx.mesh is not None and self.objects_kind == "ycb":
            tables = self._mesh_tables(ctx.mesh.geom)
            mesh = {f: jnp.asarray(t)[slot] for f, t in tables.items()}
            ctx = ctx.replace(mesh=ctx.mesh.replace(**mesh))
        return ctx

    def _mesh_tables(self, geoms: tuple) -> dict[str, np.ndarray]:
        """The renderer's triangles of `geoms` per version, padded to one count: [V, Gm, T, ...]
        (host arrays, built once per geom tuple, outside any trace)."""
        cache = self.__dict__.setdefault("_mesh_table_cache", {})
        if geoms not in cache:
            with jax.ensure_compile_time_eval():
                # make_context's default budget (300), which the env's meshes are already under.
                sets = [mesh_set(m, list(geoms), 300) for m in self._models]
                arrays = [{f: np.asarray(getattr(s, f)) for f in _MESH_FIELDS} for s in sets]
            n_tri = max(a["valid"].shape[1] for a in arrays)
            cache[geoms] = {
                f: np.stack([np.stack([_pad(g, n_tri) for g in a[f]]) for a in arrays])
                for f in _MESH_FIELDS
            }
        return cache[geoms]


_MESH_FIELDS = ("v0", "e1", "e2", "valid", "uv")


class RearrangeGeom(Rearrange):
    """Rearrange with the reference's Geom shapes."""

    objects_kind = "geom"


class RearrangeYCB(Rearrange):
    """Rearrange with textured stand-ins for the reference's YCB objects."""

    objects_kind = "ycb"


# Model fields that may differ between the versions' models and are stepped per env by MJX.
PHYSICS_FIELDS = (
    "body_mass",
    "body_inertia",
    "body_ipos",
    "body_iquat",
    "body_subtreemass",
    "body_invweight0",
    "dof_M0",
    "dof_invweight0",
    "geom_size",
    "geom_rbound",
    "geom_aabb",
    "geom_pos",
    "geom_quat",
    "geom_friction",
)


# -- building blocks ------------------------------------------------------------------------------


def _tray_name(version: int) -> str:
    return BLACK if version >= 6 else TRAY_TEXTURES[version][0]


def _tray_mean_rgb(name: str) -> np.ndarray:
    if name == BLACK:
        return np.zeros(3, np.float32)
    rgb = _texture(name).reshape(-1, 3).mean(0) / 255.0
    return (rgb * np.asarray(dict(TRAY_TEXTURES)[name])).astype(np.float32)


def _inertia(kind: ObjectKind) -> list[float]:
    """Principal moments (kg m^2) of the kind's collision shape, solid, about its centre."""
    a, b, c = kind.extent
    m = kind.mass
    if kind.shape == "box":
        return [m * (b * b + c * c) / 12, m * (a * a + c * c) / 12, m * (a * a + b * b) / 12]
    if kind.shape == "sphere":
        r = (a + b + c) / 6
        return [0.4 * m * r * r] * 3
    r = (a + b) / 4
    side = m * (3 * r * r + c * c) / 12
    return [side, side, 0.5 * m * r * r]


def _add_collision_geom(spec, body, k: int, shape: str, kind: ObjectKind, colour, visible: bool):
    """Slot k's collision geom of `shape`: the object's when it has that shape, else a 1 mm,
    massless stand-in at the body's centre (it never touches anything)."""
    on = kind.shape == shape
    ex = np.asarray(kind.extent, np.float64) / 2 if on else np.full(3, INACTIVE)
    common = dict(
        name=f"obj{k}_{shape}",
        contype=1,
        conaffinity=1 | 2 | 4,
        mass=kind.mass if on else 0.0,
        friction=[kind.friction, 0.005, 0.0001],
        rgba=[*colour, 1.0] if visible else [0.5, 0.5, 0.5, 0.0],
        group=0 if (visible and shape != "cylinder") else 3,
    )
    if shape == "box":
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=list(ex), **common)
    elif shape == "sphere":
        r = float(np.mean(ex))
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[r, 0.0, 0.0], **common)
    else:  # cylinder: a prism hull (MJX collides no cylinder with a box)
        radius, half = (ex[0] + ex[1]) / 2, ex[2]
        a = 2 * np.pi * np.arange(PRISM_SIDES) / PRISM_SIDES
        ring = np.stack([radius * np.cos(a), radius * np.sin(a)], 1)
        verts = np.concatenate(
            [np.c_[ring, np.full(PRISM_SIDES, -half)], np.c_[ring, np.full(PRISM_SIDES, half)]]
        )
        spec.add_mesh(name=f"obj{k}_hull", uservert=verts.ravel())
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname=f"obj{k}_hull", **common)


_MESH_CACHE: dict = {}


def _object_mesh(name: str, max_faces: int):
    key = (name, max_faces)
    if key not in _MESH_CACHE:
        _MESH_CACHE[key] = load_object(ASSETS / "meshes" / name, 1.0, max_faces=max_faces)
    return _MESH_CACHE[key]


def _fit_mesh(mesh, kind: ObjectKind):
    """(verts [V, 3], MuJoCo uv [3F, 2], faces [F, 3]) of `mesh` turned so its axes rank like the
    kind's extent (longest to longest) and scaled to that extent, centred."""
    verts = mesh.verts - (mesh.verts.min(0) + mesh.verts.max(0)) / 2
    src = np.ptp(verts, axis=0)
    want = np.asarray(kind.extent)
    perm = np.empty(3, int)
    perm[np.argsort(want)] = np.argsort(src)  # target axis i takes source axis perm[i]
    rot = np.zeros((3, 3))
    rot[np.arange(3), perm] = 1.0
    if np.linalg.det(rot) < 0:
        rot[0] *= -1.0  # a proper rotation: mirror one axis back
    verts = verts @ rot.T
    verts = verts * (want / np.maximum(np.ptp(verts, axis=0), 1e-9))
    uv = mesh.uv.reshape(-1, 2) * [1.0, -1.0] + [0.0, 1.0]  # MuJoCo: v = 0 at the top row
    return verts, uv, mesh.faces


def _quat_to_mat(q):
    """(w, x, y, z) unit quaternion -> 3 x 3 rotation matrix."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    return jnp.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _quat_to_mat_np(q) -> np.ndarray:
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.asarray(q, np.float64))
    return out.reshape(3, 3).astype(np.float32)
