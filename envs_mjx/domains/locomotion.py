"""Shared machinery of the locomotion domains (HalfCheetah, Ant): the pybullet walker LD state,
reward and resets of docs/reference/suite.md §2.

LD state (8 + 2J + F entries, clipped to +-5):
  [z - z0, sin(angle_to_target), cos(angle_to_target), 0.3 vx, 0.3 vy, 0.3 vz, roll, pitch],
  then per actuated joint (position mapped to [-1, 1] by its limits, 0.1 * velocity),
  then per foot geom a floor-contact flag (1 when touching).
  Body position = mean x, y of the robot's bodies with the torso's z; the target is 1 km along +x;
  (vx, vy, vz) is the torso origin's world velocity rotated into the body-yaw frame.
Reward: alive + progress + electricity (-2 mean|a * 0.1 qdot| - 0.1 mean a^2)
  - 0.1 * (joints at their limits), times reward_scale (1 / episode_length by default: the paper-era
  wrappers divided by the episode length). progress = decrease of the distance to the target / dt.
Reset: actuated joints ~U(+-0.1) rad from the model's rest pose, zero velocity.
Kinematic quantities (body positions, contacts) are the ones MJX computed at the start of the last
substep, i.e. they lag qpos by one physics substep (4.1 ms), as in Brax / Playground envs.
Deviation: the reference's multicolor ("Clr") envs also ended an episode when every velocity entry
was below 0.1 ("stalled"); that rule is not implemented.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs_mjx.base import (
    Env,
    body_geom_ids,
    contact_flags,
    geom_ids,
    random_colour_scheme,
)
from envs_mjx.config import LocomotionConfig
from envs_mjx.domains._assets import asset


class Locomotion(Env):
    """A walker on the checker floor, with a tracking camera ("pixels", mode trackcom)."""

    reset_contacts = True
    xml: str
    joints: tuple[str, ...]  # actuated joints, in action order
    feet: tuple[str, ...]  # geoms whose floor contact enters the LD state
    # (geom names or "body:<name>" for all geoms of a body, colour slot) for multicolor mode
    colour_parts: tuple[tuple[str, int], ...]

    def __init__(self, config: LocomotionConfig, pixels_fn=None):
        mj_model = mujoco.MjModel.from_xml_path(asset(self.xml))
        jid = [mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in self.joints]
        if min(jid) < 0:
            raise KeyError(f"joints missing from {self.xml}: {self.joints}")
        self._qadr = np.asarray(mj_model.jnt_qposadr[jid])
        self._vadr = np.asarray(mj_model.jnt_dofadr[jid])
        lo, hi = np.asarray(mj_model.jnt_range[jid]).T
        self._jmid, self._jhalf = (lo + hi) / 2, (hi - lo) / 2
        self._feet = geom_ids(mj_model, list(self.feet))
        self._floor = int(geom_ids(mj_model, ["floor"])[0])
        self._torso = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_BODY, "torso")
        self._robot_bodies = np.arange(1, mj_model.nbody)
        self._slots = [
            body_geom_ids(mj_model, p[5:]) if p.startswith("body:") else geom_ids(mj_model, [p])
            for p, _ in self.colour_parts
        ]
        self._slot_index = np.asarray([s for _, s in self.colour_parts])
        names = ["z_rel", "sin_to_target", "cos_to_target", "vx", "vy", "vz", "roll", "pitch"]
        for j in self.joints:
            names += [f"{j}_pos", f"{j}_vel"]
        names += [f"{f}_contact" for f in self.feet]
        super().__init__(config, mj_model, tuple(names), pixels_fn)

    def _ld_groups(self):
        velocities = ("vx", "vy", "vz")
        return tuple(
            "contact" if n.endswith("_contact")
            else "velocity" if n in velocities or n.endswith("_vel")
            else "position"  # z, heading to target, roll, pitch, joint angles
            for n in self.ld_state_names
        )

    # -- subclass hooks ---------------------------------------------------------------------------

    def _torso_linvel(self, data) -> jax.Array:
        raise NotImplementedError

    def _alive(self, z, pitch) -> jax.Array:
        raise NotImplementedError

    def _terminated(self, z, pitch) -> jax.Array:
        raise NotImplementedError

    # -- Env hooks ------------------------------------------------------------------------------

    def _sample_reset(self, rng):
        k_q, k_colour = jax.random.split(rng)
        noise = self.config.reset_noise
        qpos = jnp.asarray(self.mj_model.qpos0, jnp.float32)
        dq = jax.random.uniform(k_q, (len(self.joints),), minval=-noise, maxval=noise)
        qpos = qpos.at[self._qadr].add(dq)
        scheme = random_colour_scheme(k_colour)
        rgba = self._rgba_with_scheme(self._slots, scheme[self._slot_index], self.config.multicolor)
        return qpos, jnp.zeros(self.mj_model.nv), {"geom_rgba": rgba}

    def _after_reset(self, data, info):
        return {**info, "z0": data.xpos[self._torso, 2]}

    def _ld_state(self, data, info):
        c = self.config
        xyz = self._body_xyz(data)
        roll, pitch, yaw = _rpy(data.xquat[self._torso])
        to_target = jnp.arctan2(c.target_y - xyz[1], c.target_x - xyz[0]) - yaw
        v = self._torso_linvel(data)
        cy, sy = jnp.cos(yaw), jnp.sin(yaw)
        v_body = jnp.stack([cy * v[0] + sy * v[1], -sy * v[0] + cy * v[1], v[2]])
        z_rel = xyz[2] - info["z0"]
        head = jnp.stack(
            [z_rel, jnp.sin(to_target), jnp.cos(to_target), *(0.3 * v_body), roll, pitch]
        )
        jpos, jvel = self._joints(data)
        joints = jnp.stack([jpos, jvel], axis=1).reshape(-1)
        feet = contact_flags(data, self._floor, self._feet)
        ld = jnp.concatenate([head, joints, feet])
        return jnp.clip(ld, -c.ld_clip, c.ld_clip).astype(jnp.float32)

    def _reward_done(self, prev, data, action, info):
        c = self.config
        a = jnp.clip(action, -1.0, 1.0)
        xyz = self._body_xyz(data)
        _, pitch, _ = _rpy(data.xquat[self._torso])
        progress = (self._distance(prev) - self._distance(data)) / self.dt
        jpos, jvel = self._joints(data)
        electricity = c.electricity_cost * jnp.mean(jnp.abs(a * jvel)) + (
            c.stall_torque_cost * jnp.mean(a**2)
        )
        at_limit = c.joints_at_limit_cost * jnp.sum(jnp.abs(jpos) > 0.99)
        alive = self._alive(xyz[2], pitch)
        reward = alive + progress + electricity + at_limit
        metrics = {
            "alive": alive,
            "progress": progress,
            "electricity": electricity,
            "joints_at_limit": at_limit,
        }
        return reward, self._terminated(xyz[2], pitch), metrics

    # -- helpers ----------------------------------------------------------------------------------

    def _body_xyz(self, data) -> jax.Array:
        xy = jnp.mean(data.xpos[self._robot_bodies, :2], axis=0)
        return jnp.concatenate([xy, data.xpos[self._torso, 2:3]])

    def _distance(self, data) -> jax.Array:
        xy = self._body_xyz(data)[:2]
        return jnp.hypot(self.config.target_x - xy[0], self.config.target_y - xy[1])

    def _joints(self, data) -> tuple[jax.Array, jax.Array]:
        """(positions mapped to [-1, 1] by the limits, 0.1 * velocities), [J] each."""
        pos = (data.qpos[self._qadr] - self._jmid) / self._jhalf
        return pos, 0.1 * data.qvel[self._vadr]


def _rpy(quat: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Roll, pitch, yaw (pybullet's getEulerFromQuaternion convention) of a (w, x, y, z) quat."""
    w, x, y, z = quat
    roll = jnp.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = jnp.arcsin(jnp.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = jnp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw
