"""The paper's simulation + rendering stack as a peer: PyBullet stepping the reference's scenes,
a 64x64 TinyRenderer frame after every step, one process per core.

The scenes are restated from pybullet_envs 3.2.7 and the bulb Aux wrappers as
suite_reference.md §2 describes them (not copied; pybullet_envs itself needs the old `gym`):

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

Every reset draws the reference's multicolour scheme (changeVisualShape), as jaml's default
`multicolor=True` does. After each step the LD-state reads the reference's env makes (joint
states; for the walkers link states, base velocity and foot contacts) run through PyBullet's
batched calls, which if anything is cheaper than pybullet_envs' per-part Python. The frame is
`getCameraImage(64, 64, renderer=ER_TINY_RENDERER, flags=ER_NO_SEGMENTATION_MASK)` kept as a
64x64x3 uint8 array, the form jaml's env.step returns. Both choices favour the peer: the
reference's call (ER_BULLET_HARDWARE_OPENGL, which a headless DIRECT client serves with
TinyRenderer) also computed the segmentation mask (about 20 % of a CartPole frame here;
`seg_mask=True` restores it), and its wrapper converted each frame to 3x64x64 float32 (about
3 %), which jaml leaves to the learner as well.

Not covered: the inclines and Rearrange are bulb's own scenes (URDFs and textures not in
pybullet_data), so they have no peer here.

Run alone: PYTHONPATH=. python -m benchmarks.peers.pybullet_envs [--envs CartPole Ant]
[--processes 2] [--episodes 128] [--steps 10] [--repeats 5] [--seg-mask]. Nothing is recorded; the
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

RES = 64
# The reference's Clr colour schemes (suite_reference.md §1): base, pole, pole2, pole3 RGBA.
SCHEMES = (
    ((1, 1, 0, 1), (0, 0, 1, 1), (1, 0, 0, 1), (0.8, 0.8, 0.8, 1)),
    ((0, 1, 1, 1), (0, 0, 0, 1), (0, 0, 1, 1), (0.7, 0, 0.7, 1)),
    ((1, 0, 1, 1), (0, 1, 0, 1), (1, 1, 0, 1), (0.7, 0, 0, 1)),
    ((0, 0, 1, 1), (1, 0, 0, 1), (0, 0, 0, 1), (0, 0.8, 0.8, 1)),
)
MJCF_FLAGS = ("URDF_USE_SELF_COLLISION", "URDF_USE_SELF_COLLISION_EXCLUDE_ALL_PARENTS",
              "URDF_GOOGLEY_UNDEFINED_COLORS")


class Scene:
    """One DIRECT PyBullet client holding one domain's scene; `reset`, `step`, `frame`."""

    action_size = 1
    cam_dist, cam_yaw, cam_pitch = 2.0, 0.0, -30.0

    def __init__(self, seed: int = 0, seg_mask: bool = False):
        import pybullet
        import pybullet_data
        from pybullet_utils import bullet_client

        self.pb = pybullet
        self.data = pybullet_data.getDataPath()
        self.p = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
        self.rng = np.random.default_rng(seed)
        self.flags = 0 if seg_mask else pybullet.ER_NO_SEGMENTATION_MASK
        self.proj = self.p.computeProjectionMatrixFOV(fov=60, aspect=1.0, nearVal=0.1,
                                                      farVal=100.0)
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
        view = self.p.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=self.camera_target(), distance=self.cam_dist,
            yaw=self.cam_yaw, pitch=self.cam_pitch, roll=0, upAxisIndex=2)
        rgba = self.p.getCameraImage(RES, RES, viewMatrix=view, projectionMatrix=self.proj,
                                     renderer=self.pb.ER_TINY_RENDERER, flags=self.flags)[2]
        return np.asarray(rgba, np.uint8).reshape(RES, RES, 4)[:, :, :3]

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


SCENES: dict[str, type[Scene]] = {
    "CartPole": CartPole,
    "InvertedPendulum": InvertedPendulum,
    "HalfCheetah": HalfCheetah,
    "Ant": Ant,
}
SCENE_NOTES = {
    "CartPole": "cartpole.urdf, dt 0.02",
    "InvertedPendulum": "mjcf/inverted_pendulum.xml, dt 0.0165",
    "HalfCheetah": "mjcf/half_cheetah.xml + plane_stadium.sdf, 4 substeps of 0.0165/4",
    "Ant": "mjcf/ant.xml + plane_stadium.sdf, 4 substeps of 0.0165/4",
}


def available() -> bool:
    try:
        import pybullet  # noqa: F401
    except ImportError:
        return False
    return True


def run_block(scene: Scene, actions: np.ndarray) -> int:
    """`actions` [episodes, steps, action_size]: reset, then step + frame per action."""
    for episode in actions:
        scene.reset()
        for a in episode:
            scene.step(a)
            scene.frame()
    return actions.shape[0] * actions.shape[1]


def _serve(name: str, episodes: int, steps: int, seed: int, seg_mask: bool) -> None:
    """A worker's loop: build the scene, then one block per "run" line on stdin.

    Replies go to the original stdout; PyBullet's own C prints are sent to stderr so that
    they cannot interleave with them."""
    reply = os.fdopen(os.dup(1), "w", buffering=1)
    os.dup2(2, 1)
    start = time.perf_counter()
    scene = SCENES[name](seed, seg_mask)
    actions = np.random.default_rng(seed).uniform(-1, 1, (episodes, steps, scene.action_size))
    print(f"ready {time.perf_counter() - start}", file=reply)
    for line in sys.stdin:
        if line.strip() != "run":
            break
        start = time.perf_counter()
        frames = run_block(scene, actions)
        print(f"{frames} {time.perf_counter() - start}", file=reply)


class PeerPool:
    """`processes` PyBullet workers, one scene each; `block()` runs one block on all at once.

    Each worker is a fresh interpreter (`python -m benchmarks.peers.pybullet_envs --serve`):
    not a fork of the caller, which may hold JAX's threads, and not multiprocessing's spawn,
    which re-imports the caller's main module. Workers build their scene before the first
    block, so start-up and loading are reported apart (`setup_s`), as compile time is."""

    def __init__(self, name: str, processes: int = 2, episodes: int = 64, steps: int = 10,
                 seed: int = 0, seg_mask: bool = False):
        if name not in SCENES:
            raise ValueError(f"no PyBullet scene for {name!r}; have {sorted(SCENES)}")
        root = str(Path(__file__).resolve().parents[2])
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            filter(None, [root, os.environ.get("PYTHONPATH")]))}
        start = time.perf_counter()
        self.procs = []
        for i in range(processes):
            cmd = [sys.executable, "-m", "benchmarks.peers.pybullet_envs", "--serve", name,
                   str(episodes), str(steps), str(seed + i), str(int(seg_mask))]
            self.procs.append(subprocess.Popen(
                cmd, cwd=root, env=env, text=True, bufsize=1, stdin=subprocess.PIPE,
                stdout=subprocess.PIPE, stderr=subprocess.PIPE))
        for proc in self.procs:
            tag = self._reply(proc).split()[0]
            assert tag == "ready", tag
        self.setup_s = time.perf_counter() - start
        self.frames_per_block = processes * episodes * steps

    def _reply(self, proc) -> str:
        line = proc.stdout.readline()
        if not line:
            self.close()
            raise RuntimeError(f"PyBullet worker exited ({proc.poll()}): {proc.stderr.read()}")
        return line

    def block(self) -> float:
        """Wall seconds for one block on every worker (all started together, all finished)."""
        start = time.perf_counter()
        for proc in self.procs:
            proc.stdin.write("run\n")
        frames = sum(int(self._reply(proc).split()[0]) for proc in self.procs)
        wall = time.perf_counter() - start
        assert frames == self.frames_per_block, frames
        return wall

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
            repeats: int = 5, warmup: int = 1, seg_mask: bool = False) -> dict:
    """Frames/s of `processes` PyBullet workers together: median over `repeats` blocks."""
    with PeerPool(name, processes, episodes, steps, seg_mask=seg_mask) as pool:
        for _ in range(warmup):
            pool.block()
        times = [pool.block() for _ in range(repeats)]
    frames = pool.frames_per_block
    return {
        "frames_per_s": frames / statistics.median(times),
        "min_frames_per_s": frames / max(times),
        "max_frames_per_s": frames / min(times),
        "setup_s": pool.setup_s,
        "frames_per_block": frames,
        "repeats": repeats,
    }


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--serve"]:  # a PeerPool worker
        name, episodes, steps, seed, seg_mask = argv[1:]
        return _serve(name, int(episodes), int(steps), int(seed), bool(int(seg_mask)))
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--envs", nargs="+", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--processes", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--episodes", type=int, default=64, help="per process and block")
    parser.add_argument("--steps", type=int, default=10, help="per episode")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seg-mask", action="store_true",
                        help="also compute the segmentation mask, as the reference's call did")
    args = parser.parse_args(argv)
    import pybullet

    print(f"pybullet {pybullet.getAPIVersion()}, {args.processes} processes")
    for name in args.envs:
        r = measure(name, args.processes, args.episodes, args.steps, args.repeats,
                    seg_mask=args.seg_mask)
        print(f"{name} ({SCENE_NOTES[name]}): {r['frames_per_s']:,.0f} frames/s "
              f"(blocks {r['min_frames_per_s']:,.0f}-{r['max_frames_per_s']:,.0f}, "
              f"setup {r['setup_s']:.1f} s)", flush=True)


if __name__ == "__main__":
    main()
