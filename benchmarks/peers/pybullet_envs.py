"""The paper's simulation + rendering stack as a peer: PyBullet stepping the reference's scenes,
a 64x64 TinyRenderer frame after every step, one process per core.

The scenes are restated from pybullet_envs 3.2.7 and the bulb Aux wrappers as
docs/reference/suite.md §2 describes them (not copied; pybullet_envs itself needs the old `gym`):

CartPole          pybullet_data `cartpole.urdf`, as `CartPoleBulletEnv`: no damping, velocity
                  motors off, gravity 9.8, dt 0.02, one stepSimulation per action; +-10 N on the
                  slider (the sign of a uniform action, jaml's `action_mode="sign"`). Camera
                  target (0,0,0), dist 2, yaw 0, pitch +0.3, fov 60, near/far 0.1/100.
InvertedPendulum  `mjcf/inverted_pendulum.xml` through loadMJCF with self-collision, as
                  `InvertedPendulumBulletEnv`: dt 0.0165, 1 substep, 5 solver iterations, contact
                  ERP 0.9; slider torque 100*clip(a); camera (x_cart,0,0), dist 1.8, pitch -30.
HalfCheetah, Ant  `mjcf/half_cheetah.xml` / `ant.xml` on `plane_stadium.sdf` (friction 0.8,
                  restitution 0.5), as the locomotion envs: dt 0.0165 in 4 substeps, 5 solver
                  iterations, ERP 0.9; torque power*100*clip(a) per joint (power 0.9 / 2.5);
                  camera tracking (mean part x, mean part y, torso z), dist 3, pitch -30.

RearrangeGeom     bulb's ReacherRearrangeEnv, Geom objects of version 0 (docs/reference/suite.md
                  §1-2, §6; envs_mjx/domains/rearrange.py): pybullet_data `plane.urdf` coloured
                  black; the reacher restated in the structure of bulb's reacher.xml and loaded
                  through loadMJCF (capsules, masses 2 / 2 / 1, inertia from the geometry, no
                  damping; only the hand's cross-bar and fingers collide, as there); the tray of
                  borders*.urdf at scale 0.8 (four wall boxes 0.04 x 0.84 x 0.08 colliding with
                  restitution 1 and friction 1, three visual floor panels 4 mm thick); a blue
                  cylinder (r 0.03, 0.13, 0.2 kg), magenta cube (0.05 x 0.10 x 0.15, 0.05 kg,
                  friction 1), red sphere (r 0.04, 0.1 kg) and yellow sphere1 (r 0.06, 0.3 kg)
                  with the reference's friction, rolling friction and restitution. Gravity 9.81,
                  dt 0.01 in 2 substeps, 5 solver iterations; an action is 4 repeats of (torque
                  3*clip(a) N m, one stepSimulation, the software joint limits that reverse
                  qdot), stopping early once an object leaves the workspace, as bulb's step.
                  Reset: q ~U(+-0.75 pi), objects dropped at random poses, 20 steps, 10 steps of
                  random torque. After each step the reference's LD-state and reward reads.
                  Camera target (0,0,0), dist 0.40, yaw 90, pitch -89, fov 90, near 0.01.
                  Differences from the reference: the tray's texture is jaml's stand-in for birch
                  (assets/textures/light-wood.png on PyBullet box primitives; the reference drew
                  textured unit-cube meshes, the same 12 triangles per box); the objects are
                  PyBullet primitives with the URDFs' sizes, masses and contact values (as the
                  URDFs declared them) rather than loaded from the URDF files; the action is
                  jaml's torque 3a (bulb's paper-era mapping clip((a - 0.5) 3) only shifts the
                  random torques). Differences from jaml's scene (docs/rearrange.md lists them):
                  jaml's walls collide as planes, its cylinder as a 16-sided prism, nothing
                  bounces, its shoulder and elbow capsules push objects too, and its batch holds
                  versions 0-3 (i mod 4; same shapes, other colours and tray textures).
RearrangeGeom:arm=franka
                  bulb's FrankaRearrangeEnv (docs/reference/suite.md §2 "Rearrange-Franka"; jaml's
                  RearrangeGeom with arm="franka"): the scene above (tray, version 0's objects,
                  timing, the 4-repeat step with its early stop, reset structure) with a Panda in
                  place of the reacher: pybullet_data's franka_panda/panda.urdf, fixed base at
                  (-0.7, 0, 0), URDF_USE_SELF_COLLISION (the flag bulb's BulletManipulator
                  passed; its code is known here from later copies, e.g. dedo's), every joint
                  motor off (forces 0). 7 actions: per Bullet step TORQUE_CONTROL of
                  clip(limit a + inverse dynamics, +-limit) on the 7 arm joints, limits
                  (87, 87, 87, 87, 12, 12, 12) N m, the inverse dynamics
                  (calculateInverseDynamics at the current q and qdot of all 9 joints, qdd = 0:
                  gravity and Coriolis compensation, as BulletManipulator.apply_joint_torque)
                  computed before the step; after it the joint limits by hard reset with qdot 0;
                  the fingers passive. Reset: from the rest pose (-0.0412, 0.5043, 0.0048,
                  -2.6232, -0.1651, 3.1273, 0.9135), IK for the hand link (bulb's ee_link_name
                  "panda_hand") at x, y ~U(-0.5, 0.5), z ~U(0.05, 0.35) with bulb's random
                  orientation (roll, pitch, yaw ~U(+-pi), |roll| raised to >= pi / 2, |pitch|,
                  |yaw| clipped to pi / 2: the gripper within 90 degrees of down) through
                  calculateInverseKinematics with BulletManipulator's arguments (joint limits,
                  rest pose, 500 iterations, residual 0.005), clipped to the limits, fingers
                  closed; then the objects, 20 bare Bullet steps (no torque, so no compensation:
                  bulb's apply_joint_torque returns early on a zero torque) and 10 steps of random
                  torque U(+-0.5 limit). Camera target (0.05, 0, 0), dist 0.44, yaw 90, pitch
                  -65, fov 90, near 0.01; the hand's position is read after each step (the
                  reference's extra done conditions). Differences from the reference: its
                  franka_small_fingers.urdf is not available, so the Panda is pybullet_data's,
                  with the standard fingers and that URDF's meshes, masses and inertias (the
                  reference's fingers were smaller; jaml's model follows the same
                  panda_description kinematics, docs/rearrange.md); panda.urdf's link7 and hand
                  collision meshes overlap (one standing self-contact, internal to a rigid pair,
                  0.05 ms per Bullet step here); the joint limits are jaml's (panda.urdf's
                  safety_controller soft limits) where bulb read its URDF's <limit> tags; the
                  ground is plane.urdf coloured as jaml's floor, not bulb's plane_blue.urdf. The
                  frame's cost is panda.urdf's visual meshes: ~100K triangles, which TinyRenderer
                  rasterises whether in view or not (a frame ~15 ms on the 2-core machine, ~2 ms
                  with the URDF's 3.4K-triangle collision meshes drawn instead, against the
                  reacher scene's ~2 ms); jaml draws ~1K triangles of decimated Panda meshes, so a
                  ratio against this scene holds the mesh detail as well as the stacks. The
                  reference's meshes are not known. From jaml as for the reacher, plus: jaml's
                  IK puts its `ee` site (0.1034 m below the hand) at the target with the gripper
                  straight down; its settle steps are compensated; its arm collides as capsules
                  and boxes from link4 on, without self-collision; its compensation uses the bias
                  of the previous 5 ms substep.

Every reset of the first four draws the reference's multicolour scheme (changeVisualShape), as
jaml's default `multicolor=True` does. After each step the LD-state reads the reference's env
makes (joint states; for the walkers link states, base velocity and foot contacts) run through
PyBullet's batched calls, which if anything is cheaper than pybullet_envs' per-part Python.

The frame is made as the reference made it: getCameraImage(64, 64) with the reference's renderer
(ER_BULLET_HARDWARE_OPENGL for the Aux envs, which a headless DIRECT client serves with
TinyRenderer; ER_TINY_RENDERER for Rearrange) and default flags, so the segmentation mask is
computed as it was there; then RGB to float 3x64x64 in [0, 1] (float64, as `astype(float)`),
clipped to the observation space for the Aux envs. Until 2026-11-23 the peer skipped the mask and
the float conversion (the `lean` option keeps that frame: 64x64x3 uint8, the form jaml's env.step
returns); the rows recorded before then measured that lighter frame. Shadows stay off (the
reference's default). What the peer still leaves out favours it: gym's wrappers and the Aux
env's per-step Python (reward, done and info bookkeeping).

Timing: run_block times the steps and frames, not the resets, because jaml's side-by-side block
steps envs reset beforehand; bulb's Rearrange reset alone runs 30 Bullet steps.

Not covered: the inclines (bulb's own URDFs and textures) and RearrangeYCB (the YCB scans).

Scenes are keyed by jaml env spec: `scene_key` maps "RearrangeGeom:arm=franka" to the Franka
scene and drops the options that change only how jaml computes a scene (physics=c,
max_contacts); any other option raises ValueError rather than run a scene that is not the one
asked for (envs_throughput then prints why and skips the side-by-side rows).

Run alone: PYTHONPATH=. python -m benchmarks.peers.pybullet_envs [--envs CartPole Ant
RearrangeGeom:arm=franka]
[--processes 2] [--episodes 128] [--steps 10] [--repeats 5] [--lean]. Nothing is recorded; the
side-by-side rows come from benchmarks/envs_throughput.py.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks.harness import parse_env

RES = 64
# The reference's Clr colour schemes (docs/reference/suite.md §1): base, pole, pole2, pole3 RGBA.
SCHEMES = (
    ((1, 1, 0, 1), (0, 0, 1, 1), (1, 0, 0, 1), (0.8, 0.8, 0.8, 1)),
    ((0, 1, 1, 1), (0, 0, 0, 1), (0, 0, 1, 1), (0.7, 0, 0.7, 1)),
    ((1, 0, 1, 1), (0, 1, 0, 1), (1, 1, 0, 1), (0.7, 0, 0, 1)),
    ((0, 0, 1, 1), (1, 0, 0, 1), (0, 0, 0, 1), (0, 0.8, 0.8, 1)),
)
# Rearrange-Reacher's reacher, restated from docs/reference/suite.md §2 ("Rearrange-Reacher") in the
# structure of bulb's reacher.xml, which the reference loaded through loadMJCF: links are capsules,
# only the hand's cross-bar and fingers collide (contype 1), pybullet takes the inertia from the
# geometry (the XML's diagonal inertia is ignored), no damping.
REACHER_MJCF = """<mujoco model="reacher">
 <compiler angle="radian" inertiafromgeom="true"/>
 <default><joint armature="0" damping="0" limited="true"/><geom contype="0"/></default>
 <worldbody>
  <geom name="base" type="cylinder" fromto="0 0 0 0 0 0.035" size="0.025" conaffinity="0"/>
  <body name="shoulder" pos="0 0 0.02">
   <inertial pos="0 0 0" mass="2" diaginertia="1 1 1"/>
   <geom name="shoulder_link" type="capsule" fromto="0 0 0 0.15 0 0" size="0.025"/>
   <joint name="q0" type="hinge" axis="0 0 1" limited="false"/>
   <body name="elbow" pos="0.15 0 0">
    <inertial pos="0 0 0" mass="2" diaginertia="1 1 1"/>
    <joint name="q1" type="hinge" axis="0 0 1" range="-3 3"/>
    <geom name="elbow_link" type="capsule" fromto="0 0 0 0.12 0 0" size="0.025"/>
    <body name="wrist" pos="0.135 0 0">
     <inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>
     <geom name="crossbar" type="capsule" fromto="0 -0.05 0 0 0.05 0" size="0.015" contype="1"
           conaffinity="1"/>
     <geom name="center" type="sphere" size="0.012"/>
     <body name="fingers" pos="0 0 0">
      <geom name="finger_l" type="capsule" fromto="0 -0.05 0 0.05 -0.05 0" size="0.015"
            contype="1" conaffinity="1"/>
      <geom name="finger_r" type="capsule" fromto="0 0.05 0 0.05 0.05 0" size="0.015"
            contype="1" conaffinity="1"/>
      <geom name="tip_l" type="sphere" pos="0.05 -0.05 0" size="0.012"/>
      <geom name="tip_r" type="sphere" pos="0.05 0.05 0" size="0.012"/>
     </body>
    </body>
   </body>
  </body>
 </worldbody>
</mujoco>
"""
# Rearrange-Franka (docs/reference/suite.md §2): torque limits (N m), the rest pose the reset's IK
# starts from, and the joint limits the arm is hard-reset to. The limits are jaml's
# (assets/rearrange_franka.xml: panda_description's soft limits, the `safety_controller` values
# of pybullet_data's panda.urdf, whose <limit> tags hold the wider hardware range).
FRANKA_TORQUE = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
FRANKA_REST = (-0.0412, 0.5043, 0.0048, -2.6232, -0.1651, 3.1273, 0.9135)
FRANKA_LIMITS = ((-2.8973, 2.8973), (-1.7628, 1.7628), (-2.8973, 2.8973), (-3.0718, -0.0698),
                 (-2.8973, 2.8973), (-0.0175, 3.7525), (-2.8973, 2.8973))
MJCF_FLAGS = ("URDF_USE_SELF_COLLISION", "URDF_USE_SELF_COLLISION_EXCLUDE_ALL_PARENTS",
              "URDF_GOOGLEY_UNDEFINED_COLORS")


class Scene:
    """One DIRECT PyBullet client holding one domain's scene; `reset`, `step`, `frame`."""

    action_size = 1
    cam_dist, cam_yaw, cam_pitch = 2.0, 0.0, -30.0
    fov, near = 60.0, 0.1
    # The reference's getCameraImage renderer: the Aux wrappers asked for the OpenGL renderer,
    # which a DIRECT client serves with TinyRenderer (the same frame, the same cost here).
    renderer = "ER_BULLET_HARDWARE_OPENGL"
    clip_frame = True  # the Aux wrappers clipped the float frame to the observation space

    def __init__(self, seed: int = 0, lean: bool = False):
        import pybullet
        import pybullet_data
        from pybullet_utils import bullet_client

        self.pb = pybullet
        self.data = pybullet_data.getDataPath()
        self.p = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
        self.rng = np.random.default_rng(seed)
        self.lean = lean
        self.flags = pybullet.ER_NO_SEGMENTATION_MASK if lean else 0
        self.proj = self.p.computeProjectionMatrixFOV(fov=self.fov, aspect=1.0,
                                                      nearVal=self.near, farVal=100.0)
        self.build()

    def build(self) -> None:
        raise NotImplementedError

    def reset(self) -> None:
        raise NotImplementedError

    def step(self, action: np.ndarray) -> None:
        raise NotImplementedError

    def camera_target(self):
        return (0.0, 0.0, 0.0)

    def frame(self) -> np.ndarray:
        """The reference's observation: getCameraImage with its default flags (the segmentation
        mask is computed), RGB as float 3x64x64 in [0, 1]. lean: no segmentation mask, the
        64x64x3 uint8 RGB jaml's env.step returns."""
        view = self.p.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=self.camera_target(), distance=self.cam_dist,
            yaw=self.cam_yaw, pitch=self.cam_pitch, roll=0, upAxisIndex=2)
        rgba = self.p.getCameraImage(RES, RES, viewMatrix=view, projectionMatrix=self.proj,
                                     renderer=getattr(self.pb, self.renderer),
                                     flags=self.flags)[2]
        rgb = np.asarray(rgba, np.uint8).reshape(RES, RES, 4)[:, :, :3]
        if self.lean:
            return rgb
        obs = (rgb.astype(float) / 255.0).transpose(2, 0, 1)
        return np.clip(obs, 0.0, 1.0) if self.clip_frame else obs

    def _world(self, timestep: float, substeps: int) -> None:
        """pybullet_envs' World: gravity, contact ERP, the action's dt in `substeps` substeps."""
        self.p.setGravity(0, 0, -9.8)
        self.p.setDefaultContactERP(0.9)
        self.p.setPhysicsEngineParameter(fixedTimeStep=timestep * substeps,
                                         numSolverIterations=5, numSubSteps=substeps)

    def _load_mjcf(self, name: str) -> list[int]:
        flags = 0
        for flag in MJCF_FLAGS:
            flags |= getattr(self.pb, flag)
        return list(self.p.loadMJCF(os.path.join(self.data, "mjcf", name), flags=flags))

    def _joints(self, body: int) -> dict[str, int]:
        """Motors off as pybullet_envs' addToScene leaves them; the actuated joints by name."""
        joints = {}
        for j in range(self.p.getNumJoints(body)):
            self.p.setJointMotorControl2(body, j, self.pb.POSITION_CONTROL, positionGain=0.1,
                                         velocityGain=0.1, force=0)
            name = self.p.getJointInfo(body, j)[1].decode()
            if not name.startswith(("ignore", "jointfix")):
                joints[name] = j
        return joints

    def _reset_joint(self, body: int, j: int, q: float) -> None:
        self.p.resetJointState(body, j, targetValue=q, targetVelocity=0)
        self.p.setJointMotorControl2(body, j, self.pb.POSITION_CONTROL, targetPosition=0,
                                     targetVelocity=0, positionGain=0.1, velocityGain=0.1,
                                     force=0)

    def _scheme(self):
        return SCHEMES[self.rng.integers(len(SCHEMES))]


class CartPole(Scene):
    cam_pitch = 0.3

    def build(self):
        p = self.p
        self.body = p.loadURDF(os.path.join(self.data, "cartpole.urdf"), [0, 0, 0])
        for link in (-1, 0, 1):
            p.changeDynamics(self.body, link, linearDamping=0, angularDamping=0)
        p.setJointMotorControl2(self.body, 1, self.pb.VELOCITY_CONTROL, force=0)
        p.setJointMotorControl2(self.body, 0, self.pb.VELOCITY_CONTROL, force=0)
        p.setGravity(0, 0, -9.8)
        p.setTimeStep(0.02)
        p.setRealTimeSimulation(0)

    def reset(self):
        s = self.rng.uniform(-0.05, 0.05, 4)
        self.p.resetJointState(self.body, 1, s[0], s[1])
        self.p.resetJointState(self.body, 0, s[2], s[3])
        base, pole = self._scheme()[:2]
        self.p.changeVisualShape(self.body, 0, rgbaColor=base)
        self.p.changeVisualShape(self.body, 1, rgbaColor=pole)

    def step(self, action):
        force = 10.0 if action[0] > 0 else -10.0
        self.p.setJointMotorControl2(self.body, 0, self.pb.TORQUE_CONTROL, force=force)
        self.p.stepSimulation()
        self.state = self.p.getJointState(self.body, 1)[:2] + self.p.getJointState(self.body, 0)[:2]


class InvertedPendulum(Scene):
    cam_dist = 1.8

    def build(self):
        self._world(0.0165, 1)
        self.body = self._load_mjcf("inverted_pendulum.xml")[-1]
        joints = self._joints(self.body)
        self.slider, self.hinge = joints["slider"], joints["hinge"]
        links = {self.p.getJointInfo(self.body, j)[12].decode(): j
                 for j in range(self.p.getNumJoints(self.body))}
        self.cart, self.pole = links["cart"], links["pole"]
        self.x = 0.0

    def reset(self):
        self._reset_joint(self.body, self.slider, 0.0)
        self._reset_joint(self.body, self.hinge, self.rng.uniform(-0.1, 0.1))
        base, pole = self._scheme()[:2]
        self.p.changeVisualShape(self.body, self.cart, rgbaColor=base)
        self.p.changeVisualShape(self.body, self.pole, rgbaColor=pole)
        self.x = 0.0

    def step(self, action):
        self.p.setJointMotorControl2(self.body, self.slider, self.pb.TORQUE_CONTROL,
                                     force=100.0 * float(np.clip(action[0], -1, 1)))
        self.p.stepSimulation()
        states = self.p.getJointStates(self.body, [self.slider, self.hinge])
        self.x = states[0][0]

    def camera_target(self):
        # bulb's get_base_pos for the pendula: the cart's x, read at render time.
        return (self.x, 0.0, 0.0)


class Walker(Scene):
    """pybullet_envs' WalkerBase on the stadium scene: HalfCheetah and Ant."""

    xml = ""
    power = 1.0
    feet: tuple[str, ...] = ()
    parts: tuple[str, ...] = ()  # recoloured per reset, bulb's order
    cam_dist = 3.0

    def build(self):
        self._world(0.0165 / 4, 4)
        for plane in self.p.loadSDF(os.path.join(self.data, "plane_stadium.sdf")):
            self.p.changeDynamics(plane, -1, lateralFriction=0.8, restitution=0.5)
            self.p.changeVisualShape(plane, -1, rgbaColor=[1, 1, 1, 0.8])
        self.body = self._load_mjcf(self.xml)[-1]
        self.joint_ids = list(self._joints(self.body).values())
        self.action_size = len(self.joint_ids)
        links = {self.p.getJointInfo(self.body, j)[12].decode(): j
                 for j in range(self.p.getNumJoints(self.body))}
        self.torso = links.get("torso", -1)  # Ant's torso is the base
        self.foot_links = [links[f] for f in self.feet]
        self.colour_links = [links.get(name, -1) for name in self.parts]
        self.link_ids = list(range(self.p.getNumJoints(self.body)))
        self.xyz = (0.0, 0.0, 0.0)

    def reset(self):
        for j in self.joint_ids:
            self._reset_joint(self.body, j, self.rng.uniform(-0.1, 0.1))
        base, pole, pole2, pole3 = self._scheme()
        colours = (pole, pole2, base, pole, base, pole2, pole3)
        for link, rgba in zip(self.colour_links, colours, strict=False):
            self.p.changeVisualShape(self.body, link, rgbaColor=rgba)
        self._read_state()

    def step(self, action):
        forces = self.power * 100.0 * np.clip(action, -1.0, 1.0)
        self.p.setJointMotorControlArray(self.body, self.joint_ids, self.pb.TORQUE_CONTROL,
                                         forces=forces.tolist())
        self.p.stepSimulation()
        self._read_state()

    def _read_state(self):
        p = self.p
        self.q = p.getJointStates(self.body, self.joint_ids)
        base_pos = p.getBasePositionAndOrientation(self.body)[0]
        links = p.getLinkStates(self.body, self.link_ids)
        xyz = np.array([base_pos] + [s[0] for s in links])
        torso_z = base_pos[2] if self.torso < 0 else links[self.torso][0][2]
        self.xyz = (float(xyz[:, 0].mean()), float(xyz[:, 1].mean()), torso_z)
        self.v = p.getBaseVelocity(self.body)
        self.contacts = [bool(p.getContactPoints(bodyA=self.body, linkIndexA=f))
                         for f in self.foot_links]

    def camera_target(self):
        return self.xyz


class HalfCheetah(Walker):
    xml, power = "half_cheetah.xml", 0.9
    feet = ("ffoot", "fshin", "fthigh", "bfoot", "bshin", "bthigh")
    parts = ("torso", "bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot")


class Ant(Walker):
    xml, power = "ant.xml", 2.5
    feet = ("front_left_foot", "front_right_foot", "left_back_foot", "right_back_foot")
    parts = ("torso", "front_left_foot", "front_right_foot", "left_back_foot", "right_back_foot")


class RearrangeGeom(Scene):
    """Rearrange-Reacher with the Geom objects of version 0, as bulb's ReacherRearrangeEnv
    (docs/reference/suite.md §1-2) and envs_mjx/domains/rearrange.py build it."""

    action_size = 2
    cam_dist, cam_yaw, cam_pitch = 0.40, 90.0, -89.0
    fov, near = 90.0, 0.01
    renderer = "ER_TINY_RENDERER"  # the reacher's render_debug asked for TinyRenderer itself
    clip_frame = False  # RearrangeEnv returned the float frame unclipped
    ground_rgb = (0, 0, 0)  # pybullet_data's plane.urdf coloured black
    torque = 3.0  # N m per joint
    limits = np.array([31 / 32, 26 / 32]) * np.pi  # software joint limits
    repeats = 4  # Bullet steps per action
    workspace = (np.array([-0.45, -0.45, -0.05]), np.array([0.45, 0.45, 0.20]))
    # Version 0's objects (shape, size, mass, lateral / rolling / spinning friction,
    # restitution, rgb): cylinder, cube, sphere, sphere1 in blue, magenta, red, yellow.
    objects = (
        ("cylinder", (0.03, 0.13), 0.2, (0.5, 0.001, 0.0), 1.0, (0, 0, 1)),
        ("box", (0.025, 0.05, 0.075), 0.05, (1.0, 0.0, 0.0), 0.1, (1, 0, 1)),
        ("sphere", (0.04,), 0.1, (0.5, 0.001, 0.001), 1.0, (1, 0, 0)),
        ("sphere", (0.06,), 0.3, (0.5, 0.001, 0.001), 1.0, (1, 1, 0)),
    )
    # The tray (borders*.urdf at globalScaling 0.8): walls (half extents, centre) and the
    # visual-only floor panels, 4 mm thick, at z 0.
    walls = (((0.02, 0.42, 0.04), (0.4, 0, 0.04)), ((0.02, 0.42, 0.04), (-0.4, 0, 0.04)),
             ((0.42, 0.02, 0.04), (0, 0.4, 0.04)), ((0.42, 0.02, 0.04), (0, -0.4, 0.04)))
    panels = (((0.2, 0.4, 0.002), (-0.2, 0, 0)), ((0.2, 0.2, 0.002), (0.2, -0.2, 0)),
              ((0.2, 0.2, 0.002), (0.2, 0.2, 0)))
    # v0's tray texture: birch in the reference, its stand-in in jaml (rearrange.TRAY_TEXTURES).
    tray_texture = Path(__file__).resolve().parents[2] / "assets" / "textures" / "light-wood.png"

    def build(self):
        p = self.p
        p.setGravity(0, 0, -9.81)
        p.setTimeStep(0.01)
        p.setRealTimeSimulation(0)
        p.setPhysicsEngineParameter(numSolverIterations=5, numSubSteps=2)
        plane = p.loadURDF(os.path.join(self.data, "plane.urdf"), [0, 0, 0])
        p.changeVisualShape(plane, -1, rgbaColor=(*self.ground_rgb, 1))
        self._build_arm()
        self.tray = self._tray()
        self.bodies = [self._object(*spec) for spec in self.objects]

    def _build_arm(self) -> None:
        """The reacher, loaded through loadMJCF as bulb did; its two joints' motors off."""
        import tempfile

        p, pb = self.p, self.pb
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "reacher.xml")
            with open(path, "w") as f:
                f.write(REACHER_MJCF)
            base, self.arm = p.loadMJCF(path)
        p.changeVisualShape(base, -1, rgbaColor=(1, 1, 1, 1))
        names = {p.getJointInfo(self.arm, j)[1].decode(): j
                 for j in range(p.getNumJoints(self.arm))}
        self.joints = [names["q0"], names["q1"]]
        for link in range(p.getNumJoints(self.arm)):  # the elbow's capsule orange, the rest white
            rgb = (1, 0.6, 0.15) if link == names["q1"] + 1 else (1, 1, 1)
            p.changeVisualShape(self.arm, link, rgbaColor=(*rgb, 1))
        p.setJointMotorControlArray(self.arm, self.joints, pb.VELOCITY_CONTROL, forces=[0, 0])

    def _tray(self) -> int:
        p, pb = self.p, self.pb
        boxes = self.walls + self.panels
        visual = p.createVisualShapeArray(
            shapeTypes=[pb.GEOM_BOX] * len(boxes), halfExtents=[b[0] for b in boxes],
            visualFramePositions=[b[1] for b in boxes])
        collision = p.createCollisionShapeArray(
            shapeTypes=[pb.GEOM_BOX] * len(self.walls),
            halfExtents=[w[0] for w in self.walls],
            collisionFramePositions=[w[1] for w in self.walls])
        tray = p.createMultiBody(baseMass=0, baseCollisionShapeIndex=collision,
                                 baseVisualShapeIndex=visual)
        p.changeDynamics(tray, -1, restitution=1.0, lateralFriction=1.0, rollingFriction=0.0)
        p.changeVisualShape(tray, -1, textureUniqueId=p.loadTexture(str(self.tray_texture)))
        return tray

    def _object(self, shape, size, mass, friction, restitution, rgb) -> int:
        p, pb = self.p, self.pb
        if shape == "cylinder":
            kind = dict(shapeType=pb.GEOM_CYLINDER, radius=size[0])
            vis, col = dict(length=size[1]), dict(height=size[1])
        elif shape == "box":
            kind, vis, col = dict(shapeType=pb.GEOM_BOX, halfExtents=size), {}, {}
        else:
            kind, vis, col = dict(shapeType=pb.GEOM_SPHERE, radius=size[0]), {}, {}
        body = p.createMultiBody(
            baseMass=mass, baseCollisionShapeIndex=p.createCollisionShape(**kind, **col),
            baseVisualShapeIndex=p.createVisualShape(**kind, **vis, rgbaColor=(*rgb, 1)))
        lateral, rolling, spinning = friction
        p.changeDynamics(body, -1, lateralFriction=lateral, rollingFriction=rolling,
                         spinningFriction=spinning, restitution=restitution)
        return body

    def reset(self):
        """The reference's random init: the arm's random pose (`_reset_arm`), objects dropped at
        random poses, 20 Bullet steps to settle, 10 steps of random torque U(+-0.5 max)."""
        self._reset_arm()
        lo, hi = np.array([-0.15, -0.15, 0.04]), np.array([0.15, 0.15, 0.075])
        for body in self.bodies:
            quat = self.rng.uniform(0, 1, 4)
            self.p.resetBasePositionAndOrientation(body, self.rng.uniform(lo, hi).tolist(),
                                                   (quat / np.linalg.norm(quat)).tolist())
        for _ in range(20):
            self.p.stepSimulation()
        for _ in range(10):
            self._bullet_step(self.rng.uniform(-0.5, 0.5, self.action_size) * self.torque)
        self._read_state()

    def _reset_arm(self) -> None:
        """The reacher's q ~U(+-0.75 pi)."""
        for j, q in zip(self.joints, self.rng.uniform(-0.75 * np.pi, 0.75 * np.pi, 2),
                        strict=True):
            self.p.resetJointState(self.arm, j, targetValue=q, targetVelocity=0)

    def _bullet_step(self, torque):
        """The reacher's apply_joint_torque: torque, one Bullet step, the software limits."""
        p = self.p
        p.setJointMotorControlArray(self.arm, self.joints, self.pb.TORQUE_CONTROL,
                                    forces=torque.tolist())
        p.stepSimulation()
        for (q, qd), j, lim in zip((s[:2] for s in p.getJointStates(self.arm, self.joints)),
                                   self.joints, self.limits, strict=True):
            if abs(q) > lim:
                p.resetJointState(self.arm, j, targetValue=np.sign(q) * lim, targetVelocity=-qd)

    def _in_workspace(self) -> bool:
        lo, hi = self.workspace
        for body in self.bodies:
            pos = np.array(self.p.getBasePositionAndOrientation(body)[0])
            if (pos < lo).any() or (pos > hi).any():
                return False
        return True

    def step(self, action):
        torque = self.torque * np.clip(action, -1.0, 1.0)
        for _ in range(self.repeats):  # the reference stops repeating once an object is out
            self._bullet_step(torque)
            if not self._in_workspace():
                break
        self._read_state()

    def _read_state(self):
        """The reads of the reference's LD state (object poses as rotation matrices, arm
        angles) and reward (object positions again)."""
        p = self.p
        poses = [p.getBasePositionAndOrientation(b) for b in self.bodies]
        self.rot = [p.getMatrixFromQuaternion(q) for _, q in poses]
        self.q = [s[0] for s in p.getJointStates(self.arm, self.joints)]
        self.xy = [p.getBasePositionAndOrientation(b)[0][:2] for b in self.bodies]


class RearrangeGeomFranka(RearrangeGeom):
    """Rearrange-Franka with the Geom objects of version 0 (docs/reference/suite.md §2
    "Rearrange-Franka"; envs_mjx/domains/rearrange.py with arm="franka"): the reacher scene's
    tray, objects, timing and reset structure with pybullet_data's Panda in place of the reacher.
    """

    action_size = 7
    cam_dist, cam_yaw, cam_pitch = 0.44, 90.0, -65.0
    ground_rgb = (0.25, 0.35, 0.75)  # jaml's floor colour for bulb's plane_blue.urdf
    urdf = os.path.join("franka_panda", "panda.urdf")
    base = (-0.7, 0.0, 0.0)
    torque = np.array(FRANKA_TORQUE)
    lower, upper = np.array(FRANKA_LIMITS).T  # hard reset to these with qdot 0
    # The reference's random init (bulb's FrankaRearrangeEnv): the hand's position in this box,
    # its roll, pitch, yaw ~U(+-pi) with |roll| raised to at least pi / 2 and |pitch|, |yaw|
    # clipped to pi / 2 (the gripper points down within 90 degrees); IK as its manipulator ran it.
    ee_range = (np.array([-0.5, -0.5, 0.05]), np.array([0.5, 0.5, 0.35]))
    ik_iterations, ik_residual = 500, 0.005

    def camera_target(self):
        return (0.05, 0.0, 0.0)

    def _build_arm(self):
        """panda.urdf, fixed base at (-0.7, 0, 0), URDF_USE_SELF_COLLISION (the reference's
        flag); every motor off (forces 0): the 7 arm joints are torque-driven, the 2 fingers
        passive."""
        p, pb = self.p, self.pb
        self.arm = p.loadURDF(os.path.join(self.data, self.urdf), self.base, useFixedBase=True,
                              flags=pb.URDF_USE_SELF_COLLISION)
        info = [p.getJointInfo(self.arm, j) for j in range(p.getNumJoints(self.arm))]
        links = {i[12].decode(): i[0] for i in info}
        # Every moving joint in order: the 7 arm joints, then the fingers (the inverse dynamics'
        # and the IK's coordinates).
        self.dofs = [i[0] for i in info if i[2] != pb.JOINT_FIXED]
        self.joints = [i[0] for i in info if i[2] == pb.JOINT_REVOLUTE]
        assert len(self.joints) == 7 and len(self.dofs) == 9, (self.joints, self.dofs)
        self.ee = links["panda_hand"]  # the reference's ee_link_name
        p.setJointMotorControlArray(self.arm, self.dofs, pb.VELOCITY_CONTROL,
                                    forces=[0.0] * len(self.dofs))
        self._zeros = [0.0] * len(self.dofs)
        n_fingers = len(self.dofs) - len(self.joints)
        lower = [*self.lower, *[0.0] * n_fingers]
        upper = [*self.upper, *[0.04] * n_fingers]
        self.rest = [*FRANKA_REST, *[0.02] * n_fingers]  # fingers mid-range, as the reference
        self.ik_args = dict(lowerLimits=lower, upperLimits=upper,
                            jointRanges=list(np.subtract(upper, lower)), restPoses=self.rest,
                            maxNumIterations=self.ik_iterations,
                            residualThreshold=self.ik_residual)

    def _reset_arm(self):
        """The reference's random init: from the rest pose, IK for the hand at a random pose
        (`ee_range`, orientation as the reference drew it; an unreachable one ends nearby),
        clipped to the joint limits; fingers closed, everything at rest."""
        p = self.p
        for j, q in zip(self.dofs, self.rest, strict=True):
            p.resetJointState(self.arm, j, targetValue=q, targetVelocity=0)
        pos = self.rng.uniform(*self.ee_range)
        rpy = self.rng.uniform(-np.pi, np.pi, 3)
        if abs(rpy[0]) < np.pi / 2:
            rpy[0] = np.pi / 2 * np.sign(rpy[0])
        rpy = np.clip(rpy, [-np.pi, -np.pi / 2, -np.pi / 2], [np.pi, np.pi / 2, np.pi / 2])
        quat = p.getQuaternionFromEuler(rpy.tolist())
        q = p.calculateInverseKinematics(self.arm, self.ee, pos.tolist(), quat, **self.ik_args)
        q = np.clip(q[:len(self.joints)], self.lower, self.upper)
        for j, qj in zip(self.dofs, [*q, *[0.0] * (len(self.dofs) - len(q))], strict=True):
            p.resetJointState(self.arm, j, targetValue=qj, targetVelocity=0)

    def _bullet_step(self, torque):
        """One Bullet step of the Franka's torque control: limit * a plus the gravity and
        Coriolis compensation (inverse dynamics at the current q, qdot with qdd = 0), clipped to
        +-limit; then the joint limits by hard reset with qdot 0."""
        p, pb = self.p, self.pb
        states = p.getJointStates(self.arm, self.dofs)
        bias = p.calculateInverseDynamics(self.arm, [s[0] for s in states],
                                          [s[1] for s in states], self._zeros)
        tau = np.clip(torque + np.asarray(bias[:len(self.joints)]), -self.torque, self.torque)
        p.setJointMotorControlArray(self.arm, self.joints, pb.TORQUE_CONTROL,
                                    forces=tau.tolist())
        p.stepSimulation()
        for (q, _), j, lo, hi in zip((s[:2] for s in p.getJointStates(self.arm, self.joints)),
                                     self.joints, self.lower, self.upper, strict=True):
            if q < lo or q > hi:
                p.resetJointState(self.arm, j, targetValue=min(max(q, lo), hi), targetVelocity=0)

    def _read_state(self):
        """The reacher's reads (here 7 joint angles) and the end effector's position, which
        the reference's extra done conditions read."""
        super()._read_state()
        self.ee_pos = self.p.getLinkState(self.arm, self.ee)[0]


SCENES: dict[str, type[Scene]] = {
    "CartPole": CartPole,
    "InvertedPendulum": InvertedPendulum,
    "HalfCheetah": HalfCheetah,
    "Ant": Ant,
    "RearrangeGeom": RearrangeGeom,
    "RearrangeGeom:arm=franka": RearrangeGeomFranka,
}
SCENE_NOTES = {
    "CartPole": "cartpole.urdf, dt 0.02",
    "InvertedPendulum": "mjcf/inverted_pendulum.xml, dt 0.0165",
    "HalfCheetah": "mjcf/half_cheetah.xml + plane_stadium.sdf, 4 substeps of 0.0165/4",
    "Ant": "mjcf/ant.xml + plane_stadium.sdf, 4 substeps of 0.0165/4",
    "RearrangeGeom": "reacher (loadMJCF) + tray + v0 Geom objects (primitives) on plane.urdf, "
                     "4 Bullet steps of 0.01 (2 substeps) per action",
    "RearrangeGeom:arm=franka": "franka_panda/panda.urdf (standard fingers; the reference's "
                                "franka_small_fingers.urdf is not available) at (-0.7, 0, 0), "
                                "torque + inverse-dynamics gravity compensation, + tray + v0 "
                                "Geom objects (primitives) on plane.urdf, 4 Bullet steps of 0.01 "
                                "(2 substeps) per action; the frame draws the URDF's ~100K-"
                                "triangle visual meshes",
}
# jaml env options that change how jaml computes a scene, not the scene: the peer runs the same
# PyBullet scene for them (physics="c": C MuJoCo's substeps; max_contacts: MJX's contact budget).
ENGINE_OPTIONS = ("physics", "max_contacts")
SCENE_ALIASES = {"RearrangeGeom:arm=reacher": "RearrangeGeom"}  # jaml's default arm, spelt out


def scene_key(spec: str) -> str:
    """The SCENES key of a jaml env spec ("RearrangeGeom:arm=franka,physics=c" ->
    "RearrangeGeom:arm=franka"): the domain, plus `arm` where it picks another scene; the
    ENGINE_OPTIONS are dropped. ValueError when the peer has no such scene or cannot honour an
    option (it never stands in another scene for the one asked for)."""
    name, overrides = parse_env(spec)
    arm = overrides.pop("arm", None)
    unhonoured = sorted(set(overrides) - set(ENGINE_OPTIONS))
    if unhonoured:
        raise ValueError(f"the PyBullet peer cannot honour {spec!r}: it builds one scene per "
                         f"domain (and arm), not the options {unhonoured}")
    key = name if arm is None else f"{name}:arm={arm}"
    key = SCENE_ALIASES.get(key, key)
    if key not in SCENES:
        raise ValueError(f"no PyBullet scene for {spec!r}; have {sorted(SCENES)}")
    return key


def available() -> bool:
    try:
        import pybullet  # noqa: F401
    except ImportError:
        return False
    return True


def run_block(scene: Scene, actions: np.ndarray) -> tuple[int, float, float]:
    """`actions` [episodes, steps, action_size]: reset, then step + frame per action.

    Returns (frames, wall seconds, CPU seconds of this process), both timed over the steps and
    frames only: jaml's side-by-side block steps envs reset beforehand, so the resets (bulb's
    Rearrange reset runs 30 Bullet steps) stay out of both."""
    wall = cpu = 0.0
    for episode in actions:
        scene.reset()
        start, start_cpu = time.perf_counter(), time.process_time()
        for a in episode:
            scene.step(a)
            scene.frame()
        wall += time.perf_counter() - start
        cpu += time.process_time() - start_cpu
    return actions.shape[0] * actions.shape[1], wall, cpu


def _serve(name: str, episodes: int, steps: int, seed: int, lean: bool) -> None:
    """A worker's loop: build the scene, then one block per "run" line on stdin, answered with
    "frames wall_s cpu_s" (run_block's).

    Replies go to the original stdout; PyBullet's own C prints are sent to stderr so that
    they cannot interleave with them."""
    reply = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    start = time.perf_counter()
    scene = SCENES[name](seed, lean)
    actions = np.random.default_rng(seed).uniform(-1, 1, (episodes, steps, scene.action_size))
    print(f"ready {time.perf_counter() - start}", file=reply)
    for line in sys.stdin:
        if line.strip() != "run":
            break
        frames, wall, cpu = run_block(scene, actions)
        print(f"{frames} {wall} {cpu}", file=reply)


class PeerPool:
    """`processes` PyBullet workers, one scene each; `block()` runs one block on all at once.
    `name` is a jaml env spec ("CartPole", "RearrangeGeom:arm=franka,physics=c"), resolved by
    `scene_key` (ValueError for a spec the peer has no scene for).

    Each worker is a fresh interpreter (`python -m benchmarks.peers.pybullet_envs --serve`):
    not a fork of the caller, which may hold JAX's threads, and not multiprocessing's spawn,
    which re-imports the caller's main module. Workers build their scene before the first
    block, so start-up and loading are reported apart (`setup_s`), as compile time is."""

    def __init__(self, name: str, processes: int = 2, episodes: int = 64, steps: int = 10,
                 seed: int = 0, lean: bool = False):
        key = scene_key(name)
        root = str(Path(__file__).resolve().parents[2])
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            filter(None, [root, os.environ.get("PYTHONPATH")]))}
        start = time.perf_counter()
        self.procs = []
        for i in range(processes):
            cmd = [sys.executable, "-m", "benchmarks.peers.pybullet_envs", "--serve", key,
                   str(episodes), str(steps), str(seed + i), str(int(lean))]
            self.procs.append(subprocess.Popen(
                cmd, cwd=root, env=env, text=True, bufsize=1, stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, stderr=subprocess.PIPE))
        for proc in self.procs:
            tag = self._reply(proc).split()[0]
            assert tag == "ready", tag
        self.setup_s = time.perf_counter() - start
        self.frames_per_block = processes * episodes * steps
        self.last_cpu_s = 0.0

    def _reply(self, proc) -> str:
        line = proc.stdout.readline()
        if not line:
            self.close()
            raise RuntimeError(f"PyBullet worker exited ({proc.poll()}): {proc.stderr.read()}")
        return line

    def block(self) -> float:
        """Seconds for one block on every worker, all started together: the slowest worker's
        stepping and rendering time (its resets left out, see run_block). `last_cpu_s` is the
        workers' CPU seconds over the same span, summed."""
        for proc in self.procs:
            proc.stdin.write("run\n")
        replies = [self._reply(proc).split() for proc in self.procs]
        frames = sum(int(r[0]) for r in replies)
        assert frames == self.frames_per_block, frames
        self.last_cpu_s = sum(float(r[2]) for r in replies)
        return max(float(r[1]) for r in replies)

    def close(self) -> None:
        for proc in self.procs:
            with contextlib.suppress(OSError):
                proc.stdin.close()  # end of input ends the worker's loop
        for proc in self.procs:
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            proc.stdout.close()
            proc.stderr.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def measure(name: str, processes: int = 2, episodes: int = 64, steps: int = 10,
            repeats: int = 5, warmup: int = 1, lean: bool = False) -> dict:
    """Frames/s of `processes` PyBullet workers together: median over `repeats` blocks;
    frames_per_cpu_s: frames per CPU second of the workers (a per-core rate that load from
    other processes does not lower, as long as it leaves the caches alone)."""
    with PeerPool(name, processes, episodes, steps, lean=lean) as pool:
        for _ in range(warmup):
            pool.block()
        times, cpus = [], []
        for _ in range(repeats):
            times.append(pool.block())
            cpus.append(pool.last_cpu_s)
    frames = pool.frames_per_block
    return {
        "frames_per_s": frames / statistics.median(times),
        "frames_per_cpu_s": frames / statistics.median(cpus),
        "min_frames_per_s": frames / max(times),
        "max_frames_per_s": frames / min(times),
        "setup_s": pool.setup_s,
        "frames_per_block": frames,
        "repeats": repeats,
    }


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--serve"]:  # a PeerPool worker
        name, episodes, steps, seed, lean = argv[1:]
        return _serve(name, int(episodes), int(steps), int(seed), bool(int(lean)))
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--envs", nargs="+", default=list(SCENES),
                        help=f"jaml env specs with a scene here: {', '.join(SCENES)}")
    parser.add_argument("--processes", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--episodes", type=int, default=64, help="per process and block")
    parser.add_argument("--steps", type=int, default=10, help="per episode")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--lean", action="store_true",
                        help="no segmentation mask and no float frame (less than the reference "
                             "did per frame; the peer's earlier default)")
    args = parser.parse_args(argv)
    for spec in args.envs:
        try:
            scene_key(spec)
        except ValueError as e:
            parser.error(str(e))
    import pybullet

    print(f"pybullet {pybullet.getAPIVersion()}, {args.processes} processes")
    for name in args.envs:
        r = measure(name, args.processes, args.episodes, args.steps, args.repeats,
                    lean=args.lean)
        print(f"{name} ({SCENE_NOTES[scene_key(name)]}): {r['frames_per_s']:,.0f} frames/s "
              f"(blocks {r['min_frames_per_s']:,.0f}-{r['max_frames_per_s']:,.0f}, "
              f"{r['frames_per_cpu_s']:,.0f} per CPU second, setup {r['setup_s']:.1f} s)",
              flush=True)


if __name__ == "__main__":
    main()
