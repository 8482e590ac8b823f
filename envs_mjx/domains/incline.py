"""Geom-on-incline (docs/reference/suite.md §1 "Geom-/YCB-on-incline", §2 "BlockOnIncline", §6).

One object (a block, or a cylinder variant) slides on a 4 m plank tilted about +y by theta, so the
surface through (0, 0, 0.55) runs downhill along +x. Every reset draws, per env:
  theta ~U(theta_range) rad, mass ~U(mass_range) kg (inertia rescaled to match),
  f ~U(friction_range) with contact friction f^2 (pybullet multiplied object x plank friction;
  f = 0 is a frictionless plank),
  texture_id ~U{0..5}: plank colour INCLINE_COLOURS[id], ground colour GROUND_COLOURS[id].
These live in `info` ("theta", "mass", "friction", "texture_id", "geom_rgba") and become batched
mjx.Model fields each step: plank body_quat; object body_mass / body_inertia and the compiler's
mass-derived constants (dof_M0, body_subtreemass, body_invweight0, dof_invweight0); pair_friction
and pair_margin (which of the frictional / frictionless contact pairs is on).

Action a in [-1, 1]: a force force_scale * clip(a) N (2 N by default) along the incline's downhill
direction, applied at the object's centre of mass (xfrc_applied), held over 8 substeps of 5 ms.
Reward: 1 - |x - 0.5| (x: world x of the object). Terminates when x >= 1, x <= 0 or |y| >= 0.1.
Episodes last 50 steps.

LD state: [texture_id, object_id, (friction f if ld_friction), theta, position, velocity] where
position is the object's displacement along the plank from the plank origin and velocity its
signed velocity along the plank. With normalize_ld (default) these are mapped like the reference's
min-max normalization: id/6; f and theta min-max over the config's friction_range / theta_range
(the defaults give the reference's (f - 0.1)/0.4 and (theta - 0.25)/0.25; a zero-width range maps
to 0), clipped to [0, 1]; position/POSITION_SCALE clipped to [0, 1] and velocity/VELOCITY_SCALE
clipped to [-1, 1] (the reference's 1.27 m and 3.1 m/s); otherwise they are raw (rad, m, m/s).

Deviations from the reference (recorded here on purpose):
- The force acts along the incline, not along the object's local z axis (which the reference
  aligned with the slope at reset, so the two agree until the object rotates).
- Reset places the object at rest on the plank at position ~U(start_range) m instead of dropping
  it from (-0.05, 0, 0.7) and stepping until it passes x ~U(0.05, 0.15), and without the
  reference's small random yaw.
- The reference's position was the distance from the drop point and its velocity the unsigned
  speed; here both are measured along the plank and the velocity is signed.
- The camera keeps the reference's yaw 35, pitch -45 and fov 90 but looks at (0.6, 0, 0.4) from
  1.15 m instead of at (0.5, 0.2, 0.1) from 0.8 m, which cut the 2.5x-scale object at the frame's
  top-left (near x = 0) and right edge (near x = 1). The object now stays inside the 64 x 64 frame
  over every angle and position an episode reaches (tests/envs_mjx/test_domains.py), at the cost
  of size: the block covers ~80 pixels at 64 x 64 (150-1000 before, mostly cut off).
- Ground colours are flat stand-ins for the YCB variant's paired ground textures (the reference's
  Geom variant kept a black ground: `ground="black"`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs_mjx.base import Env, geom_ids
from envs_mjx.config import InclineConfig
from envs_mjx.domains._assets import asset

# Plank colours per texture id (reference INCLINE_COLORS).
INCLINE_COLOURS = np.array(
    [[1, 0.5, 0], [0.8, 0.8, 0.8], [0.9, 0.4, 0.4], [0, 1, 0], [0.5, 0.15, 0.15], [1, 0.6, 0]],
    np.float32,
)
# Flat stand-ins for the paired ground textures red_marble, blue_bright, purple_squares,
# wood_stripes, dark_pattern, orange_pattern.
GROUND_COLOURS = np.array(
    [
        [0.6, 0.25, 0.25],
        [0.2, 0.45, 0.95],
        [0.5, 0.3, 0.65],
        [0.6, 0.45, 0.3],
        [0.15, 0.15, 0.15],
        [0.9, 0.55, 0.2],
    ],
    np.float32,
)
# Geom objects v0-5 at the incline's 2.5x scale: (type, size, nominal mass kg, rgb).
_BOX, _CYL = mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CYLINDER
OBJECTS = (
    (_BOX, (0.0625, 0.125, 0.1875), 0.05, (1, 1, 0.5)),
    (_BOX, (0.0625, 0.125, 0.1875), 0.05, (0.2, 0.2, 0.2)),
    (_BOX, (0.0625, 0.125, 0.1875), 0.05, (1, 0, 0)),
    (_CYL, (0.075, 0.1625, 0), 0.2, (1, 0, 1)),
    (_CYL, (0.15, 0.1625, 0), 0.2, (0, 0.5, 1)),
    (_CYL, (0.075, 0.04375, 0), 0.2, (0, 0, 1)),
)
# Reset places the object this far into the plank (m), inside the soft contact's rest depth
# (~0.1-0.3 mm here): at exactly zero distance float32 MJX and float64 C MuJoCo disagree on whether
# the contact is active, and C lets the object fall freely for one substep.
RESET_SINK = 2e-4
# Contact friction below this is treated as exactly zero (the frictionless contact pair): MJX's
# pyramidal cone returns NaN below about 1e-3 (measured with MJX 3.17, float32).
FRICTIONLESS_BELOW = 1e-3
PLANK_ORIGIN = np.array([0.0, 0.0, 0.55], np.float32)
# LD-state scales of position (m) and velocity (m/s): the reference's min-max normalization
# constants, kept so normalised states compare with its data. They are not config ranges: an
# episode ends at world x = 1 (position ~1.03-1.14 m over the default angles) and velocity is
# whatever the slide and pushes reach (up to ~3 m/s under uniform actions before x = 1).
POSITION_SCALE = 1.27
VELOCITY_SCALE = 3.1


def default_config() -> InclineConfig:
    return InclineConfig()


class GeomOnIncline(Env):
    """A block or cylinder sliding on a randomly tilted plank, pushed along the slope."""

    def __init__(self, config: InclineConfig | None = None, pixels_fn=None):
        config = config or default_config()
        if config.ground not in ("paired", "black"):
            raise ValueError(f"ground must be 'paired' or 'black', got {config.ground!r}")
        spec = mujoco.MjSpec.from_file(asset("geom_on_incline.xml"))
        self._half_height = self._add_object(spec, config)
        mj_model = spec.compile()
        self._object = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_BODY, "object")
        adr, num = mj_model.body_dofadr[self._object], mj_model.body_dofnum[self._object]
        self._object_dofs = np.arange(adr, adr + num)
        self._plank = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_BODY, "plank")
        self._plank_geom = geom_ids(mj_model, ["plank"])
        self._ground_geom = geom_ids(mj_model, ["ground"])
        self._inertia0 = np.asarray(mj_model.body_inertia[self._object], np.float32)
        self._mass0 = float(mj_model.body_mass[self._object])
        self._pair_friction0 = np.asarray(mj_model.pair_friction, np.float32)
        names = ["texture_id", "object_id"]
        names += ["friction"] if config.ld_friction else []
        names += ["theta", "position", "velocity"]
        super().__init__(config, mj_model, tuple(names), pixels_fn)

    def _ld_groups(self):
        # The angle, texture, object and friction are drawn per episode and stay constant.
        kinds = {"position": "position", "velocity": "velocity"}
        return tuple(kinds.get(n, "other") for n in self.ld_state_names)

    def _add_object(self, spec: mujoco.MjSpec, config: InclineConfig) -> float:
        """Shapes the spec's "object" geom (the collision geom the contact pairs name) and
        returns the object's extent along its local +x, which reset points into the plank."""
        if not 0 <= config.object_id < len(OBJECTS):
            raise ValueError(f"object_id must be in 0..{len(OBJECTS) - 1}, got {config.object_id}")
        self._object_index = config.object_id
        gtype, size, mass, rgb = OBJECTS[config.object_id]
        obj = spec.geom("object")
        obj.type, obj.size, obj.mass, obj.rgba = gtype, list(size), mass, [*rgb, 1.0]
        return float(size[0])  # box local x half-size / cylinder radius

    @property
    def action_size(self) -> int:
        return 1

    def _sample_reset(self, rng):
        c = self.config
        keys = jax.random.split(rng, 5)
        theta = jax.random.uniform(keys[0], (), minval=c.theta_range[0], maxval=c.theta_range[1])
        mass = jax.random.uniform(keys[1], (), minval=c.mass_range[0], maxval=c.mass_range[1])
        friction = jax.random.uniform(
            keys[2], (), minval=c.friction_range[0], maxval=c.friction_range[1]
        )
        texture_id = jax.random.randint(keys[3], (), 0, len(INCLINE_COLOURS))
        s0 = jax.random.uniform(keys[4], (), minval=c.start_range[0], maxval=c.start_range[1])
        u, n = _downhill(theta), _normal(theta)
        pos = jnp.asarray(PLANK_ORIGIN) + s0 * u + (self._half_height - RESET_SINK) * n
        # Object frame: local z downhill, local x into the plank = plank rotation, then +90 deg
        # about y. Both are rotations about y, so the angles add.
        quat = _quat_y(theta + jnp.pi / 2)
        qpos = jnp.concatenate([pos, quat])
        rgba = jnp.asarray(self._base_rgba)
        rgba = rgba.at[self._plank_geom, :3].set(jnp.asarray(INCLINE_COLOURS)[texture_id])
        if c.ground == "paired":
            rgba = rgba.at[self._ground_geom, :3].set(jnp.asarray(GROUND_COLOURS)[texture_id])
        info = {
            "geom_rgba": rgba,
            "theta": theta,
            "mass": mass,
            "friction": friction,
            "texture_id": texture_id,
            "object_id": jnp.asarray(self._object_index, jnp.int32),
        }
        return qpos, jnp.zeros(6), info

    def _model_fields(self, info):
        mass = jnp.asarray(info["mass"], jnp.float32)
        body_quat = jnp.asarray(self.mj_model.body_quat, jnp.float32)
        body_quat = body_quat.at[self._plank].set(_quat_y(info["theta"]))
        body_mass = jnp.asarray(self.mj_model.body_mass, jnp.float32).at[self._object].set(mass)
        scale = mass / self._mass0
        body_inertia = jnp.asarray(self.mj_model.body_inertia, jnp.float32)
        body_inertia = body_inertia.at[self._object].set(self._inertia0 * scale)
        # The compiler's mass-derived constants must follow the mass: C MuJoCo builds the free
        # body's mass matrix from dof_M0 (a stale dof_M0 made C accelerate the object as if it
        # weighed the nominal 0.05 kg: the bulk of the MJX-vs-C gap), and both engines scale
        # contact softness by body_invweight0. The object is one free body with inertia
        # proportional to its mass, so each constant scales by mass / mass0 (or its inverse).
        m = self.mj_model
        dofs = self._object_dofs
        body_subtreemass = jnp.asarray(m.body_subtreemass, jnp.float32)
        body_subtreemass = body_subtreemass.at[self._object].set(mass)
        body_subtreemass = body_subtreemass.at[0].add(mass - self._mass0)
        body_invweight0 = jnp.asarray(m.body_invweight0, jnp.float32)
        body_invweight0 = body_invweight0.at[self._object].divide(scale)
        dof_invweight0 = jnp.asarray(m.dof_invweight0, jnp.float32).at[dofs].divide(scale)
        dof_m0 = jnp.asarray(m.dof_M0, jnp.float32).at[dofs].multiply(scale)
        # Contact friction mu = f^2. Below FRICTIONLESS_BELOW the frictionless pair (condim 1)
        # carries the contact and the frictional one is switched off by a -1 m margin (its mu is
        # then left at 1: a pyramidal row with mu = 0 has D = inf even when inactive).
        mu = jnp.asarray(info["friction"], jnp.float32) ** 2
        frictionless = mu < FRICTIONLESS_BELOW
        pair_friction = jnp.asarray(self._pair_friction0)
        pair_friction = pair_friction.at[0, :2].set(jnp.where(frictionless, 1.0, mu))
        off = jnp.asarray(-1.0, jnp.float32)
        pair_margin = jnp.stack(
            [jnp.where(frictionless, off, 0.0), jnp.where(frictionless, 0.0, off)]
        )
        return {
            "body_quat": body_quat,
            "body_mass": body_mass,
            "body_inertia": body_inertia,
            "body_subtreemass": body_subtreemass,
            "body_invweight0": body_invweight0,
            "dof_invweight0": dof_invweight0,
            "dof_M0": dof_m0,
            "pair_friction": pair_friction,
            "pair_margin": pair_margin,
        }

    def _apply_action(self, data, action, info):
        force = self.config.force_scale * jnp.clip(action[0], -1.0, 1.0) * _downhill(info["theta"])
        xfrc = data.xfrc_applied.at[self._object].set(jnp.concatenate([force, jnp.zeros(3)]))
        return data.replace(xfrc_applied=xfrc)

    def along_plank(self, qpos, qvel, theta) -> tuple[jax.Array, jax.Array]:
        """(position from the plank origin, signed velocity), both along the downhill axis."""
        u = _downhill(theta)
        return jnp.dot(qpos[:3] - PLANK_ORIGIN, u), jnp.dot(qvel[:3], u)

    def _ld_state(self, data, info):
        c = self.config
        s, v = self.along_plank(data.qpos, data.qvel, info["theta"])
        tid = info["texture_id"].astype(jnp.float32)
        oid = jnp.asarray(info["object_id"], jnp.float32)
        f, theta = info["friction"], info["theta"]
        if c.normalize_ld:
            tid, oid = tid / 6.0, oid / 6.0
            f = min_max(f, c.friction_range)
            theta = min_max(theta, c.theta_range)
            s = jnp.clip(s / POSITION_SCALE, 0.0, 1.0)
            v = jnp.clip(v / VELOCITY_SCALE, -1.0, 1.0)
        parts = [tid, oid] + ([f] if c.ld_friction else []) + [theta, s, v]
        return jnp.stack(parts).astype(jnp.float32)

    def _reward_done(self, prev, data, action, info):
        x, y = data.qpos[0], data.qpos[1]
        terminated = (x >= 1.0) | (x <= 0.0) | (jnp.abs(y) >= 0.1)
        return 1.0 - jnp.abs(x - 0.5), terminated, {}


def min_max(value, value_range: tuple[float, float]):
    """(value - lo) / (hi - lo) clipped to [0, 1]; 0 for a zero-width range (a constant)."""
    lo, hi = value_range
    span = hi - lo if hi > lo else 1.0
    return jnp.clip((value - lo) / span, 0.0, 1.0)


def _downhill(theta):
    return jnp.stack([jnp.cos(theta), jnp.zeros_like(theta), -jnp.sin(theta)])


def _normal(theta):
    return jnp.stack([jnp.sin(theta), jnp.zeros_like(theta), jnp.cos(theta)])


def _quat_y(angle):
    """(w, x, y, z) quaternion of a rotation by `angle` about +y."""
    z = jnp.zeros_like(angle)
    return jnp.stack([jnp.cos(angle / 2), z, jnp.sin(angle / 2), z])
