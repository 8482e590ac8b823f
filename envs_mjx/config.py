"""The domains' configs and the domain registry (`ENVS`: names, config classes, env classes;
`ALL_ENVS`, `default_config`, `configured`): what `jaml envs show --env ENV --help` and
`jaml suite --env ENV --help` list. Importing this module imports neither JAX nor MuJoCo; the
domains that read these configs live in `envs_mjx.domains`, and `envs_mjx.registry` builds
them.
"""

from __future__ import annotations

import dataclasses
import math
import typing

# Where an env's pixels come from (`EnvConfig.pixels`).
Pixels = typing.Literal["auto", "required", "off"]
PIXELS = typing.get_args(Pixels)
# The domain families (`EnvConfig.family`): the domains of one family share the learning
# suite's per-domain settings.
FAMILIES = ("pendulum", "locomotion", "incline", "rearrange")


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """Settings every domain shares; domains subclass this with their own fields.

    episode_length: steps after which `done` is set with `info["truncation"] = 1`; None leaves
      time limits to a wrapper (e.g. Brax's EpisodeWrapper).
    reward_scale: multiplies the reward; None means 1 / episode_length (1 without a time limit).
      The paper-era Aux wrappers divided the benchmark envs' reward by the episode length, so
      those domains default to None and follow an overridden episode_length.
    n_frames: physics substeps per action.
    pixels: "auto" uses `envs_mjx.render` when importable and otherwise a zero placeholder with a
      warning; "required" raises if the renderer is missing; "off" is the placeholder, silently:
      give it to train on the LD state (Brax's PPO), which otherwise renders unread frames.
    image_size: side of the square image, in pixels.
    family (a class constant, one of FAMILIES): the domain's family.
    """

    family: typing.ClassVar[str]
    episode_length: int | None = 1000
    reward_scale: float | None = 1.0
    n_frames: int = 1
    pixels: Pixels = "auto"
    image_size: int = 64

    def __post_init__(self):
        problems = []
        if self.episode_length is not None and self.episode_length < 1:
            problems.append(f"episode_length must be ≥ 1 or None, got {self.episode_length}")
        if self.reward_scale is not None and not math.isfinite(self.reward_scale):
            problems.append(f"reward_scale must be finite or None, got {self.reward_scale}")
        if self.n_frames < 1:
            problems.append(f"n_frames must be ≥ 1, got {self.n_frames}")
        if self.pixels not in PIXELS:
            problems.append(f"pixels must be 'auto', 'required' or 'off', got {self.pixels!r}")
        if self.image_size < 1:
            problems.append(f"image_size must be ≥ 1, got {self.image_size}")
        if problems:
            raise ValueError(f"{type(self).__name__}: " + "; ".join(problems))

    @property
    def reward_multiplier(self) -> float:
        """The factor applied to the reward: reward_scale, or 1 / episode_length for None."""
        if self.reward_scale is not None:
            return float(self.reward_scale)
        return 1.0 if self.episode_length is None else 1.0 / self.episode_length


@dataclasses.dataclass(frozen=True)
class BenchmarkConfig(EnvConfig):
    """The benchmark domains' shared options (pendulums, locomotion).

    reward_scale: None, 1 / episode_length (the paper-era Aux wrappers' division).
    multicolor: the suite's (and the paper's Fig. 2) version: one of 4 colour schemes drawn per
      reset, so a learner cannot key on a fixed colour; False: the plain, fixed-colour version.
    reset_noise: scale of the random perturbation of the initial state.
    """

    reward_scale: float | None = None
    multicolor: bool = True
    reset_noise: float = 0.1


# CartPole's conventions (`CartPoleConfig.conventions`): the reference's, or Gymnasium's
# CartPole-v1 values for the fields still at the reference's (`GYMNASIUM_CARTPOLE`).
Conventions = typing.Literal["reference", "gymnasium"]
CONVENTIONS = typing.get_args(Conventions)
# Gymnasium's CartPole-v1: 500 steps, reward 1 a step, the episode ends at |x| > 2.4 m.
GYMNASIUM_CARTPOLE = {"episode_length": 500, "reward_scale": 1.0, "x_threshold": 2.4}


@dataclasses.dataclass(frozen=True)
class CartPoleConfig(BenchmarkConfig):
    """CartPole's options. By default the reference's episode (200 steps, the episode's reward
    scaled to ≤ 1: 1/200 a step) and limits (|x| ≤ 0.4 m, |θ| ≤ 12°).

    conventions: "reference", or "gymnasium" for Gymnasium's CartPole-v1 where a field is
      still at the reference's value: 500 steps, reward 1 a step, |x| ≤ 2.4 m (the cart leaves
      the 64×64 frame beyond about ±1.15 m). The physics stay the reference's (its slowly
      falling pole) and so do the actions (continuous; `action_mode`).
    action_mode: "sign" (the reference's ±10 N) or "linear" (10 N · a).
    x_threshold, theta_threshold: the episode ends when |x| (m) or |θ| (rad) exceeds them.
    """

    family: typing.ClassVar[str] = "pendulum"
    episode_length: int | None = 200
    n_frames: int = 1
    action_mode: str = "sign"
    reset_noise: float = 0.05
    x_threshold: float = 0.4
    theta_threshold: float = 12.0 * 3.141592653589793 / 180.0
    conventions: Conventions = "reference"

    def __post_init__(self):
        if self.conventions not in CONVENTIONS:
            raise ValueError(f"CartPoleConfig: conventions must be one of {CONVENTIONS}, got "
                             f"{self.conventions!r}")
        if self.conventions == "gymnasium":
            reference = {"episode_length": 200, "reward_scale": None, "x_threshold": 0.4}
            for name, value in GYMNASIUM_CARTPOLE.items():
                if getattr(self, name) == reference[name]:
                    object.__setattr__(self, name, value)
        super().__post_init__()


@dataclasses.dataclass(frozen=True)
class InvertedPendulumConfig(BenchmarkConfig):
    family: typing.ClassVar[str] = "pendulum"
    episode_length: int | None = 1000
    n_frames: int = 1
    theta_threshold: float = 0.2


@dataclasses.dataclass(frozen=True)
class LocomotionConfig(BenchmarkConfig):
    family: typing.ClassVar[str] = "locomotion"
    episode_length: int | None = 1000
    n_frames: int = 4
    target_x: float = 1000.0
    target_y: float = 0.0
    ld_clip: float = 5.0
    electricity_cost: float = -2.0
    stall_torque_cost: float = -0.1
    joints_at_limit_cost: float = -0.1


@dataclasses.dataclass(frozen=True)
class InclineConfig(EnvConfig):
    family: typing.ClassVar[str] = "incline"
    episode_length: int | None = 50
    reward_scale: float = 1.0
    n_frames: int = 8
    object_id: int = 0
    theta_range: tuple[float, float] = (0.25, 0.50)
    mass_range: tuple[float, float] = (0.05, 0.5)
    friction_range: tuple[float, float] = (0.10, 0.50)
    start_range: tuple[float, float] = (0.05, 0.15)
    force_scale: float = 2.0
    ground: str = "paired"
    ld_friction: bool = False
    normalize_ld: bool = True


# The mesh incline's objects (`envs_mjx.domains.mesh_incline`).
MESH_OBJECTS = ("duck", "domino", "cereal", "can", "bread", "lemon")


@dataclasses.dataclass(frozen=True)
class MeshInclineConfig(InclineConfig):
    """objects: names in MESH_OBJECTS; env slot i of a batch holds objects[i mod N].
    object: one name in MESH_OBJECTS for every env instead (the single-object option).
    object_dir: a YCB-layout folder, one object for every env (overrides both).
    object_size: longest side (m); None: OBJECT_SIZES per object, FOLDER_SIZE for a folder.
    (The inherited object_id is unused: the LD object id is the object's index in
    MESH_OBJECTS.)"""

    objects: tuple[str, ...] = MESH_OBJECTS
    object: str | None = None
    object_dir: str | None = None
    object_size: float | None = None
    object_mass: float = 0.05
    max_faces: int = 300
    max_hull_vertices: int = 32


# The Rearrange domains' arms and physics (`envs_mjx.domains.rearrange`).
Arm = typing.Literal["reacher", "franka"]
ARMS = typing.get_args(Arm)
Physics = typing.Literal["mjx", "c"]
PHYSICS = typing.get_args(Physics)


@dataclasses.dataclass(frozen=True)
class RearrangeConfig(EnvConfig):
    """The Rearrange domains' options (docs/reference/suite.md §1-2).

    arm: "reacher" (the reference's 2-link arm, 2 torques) or "franka" (a Franka Panda, 7
      torques with gravity compensation).
    version: one version (0-11) for every env; None: env slot i of a batch uses
      versions[i mod len(versions)].
    versions: the versions a batch cycles through (the reference trained on 0-3).
    n_frames: derived, repeats x BULLET_SUBSTEPS MJX substeps per action (a value given here is
      replaced).
    repeats: physics steps of the reference's Bullet (10 ms) per action (4).
    settle_steps: zero-torque physics steps after placing the objects at reset.
    random_torque_steps: random-torque physics steps after settling, so an episode does not
      start from rest.
    reacher_init_range: the reacher's joint angles at reset are uniform in ± this (radians).
    ik_iterations: damped least-squares iterations that place the Franka's gripper at its random
      reset target.
    max_faces: the object meshes' face budget after decimation (the renderer's cost per mesh).
    max_joint_velocity: the arm's joint speeds are clipped to this (rad/s) after every Bullet
      step, as Bullet's multibodies cap their joint velocities (`btMultiBody`'s
      maxCoordinateVelocity, 100 by default, which the reference's loadMJCF arm kept). Without
      it nothing bounds the undamped reacher's speed under random torques and its physics turns
      NaN (docs/notes/rearrange.md). None: no cap.
    max_contacts: MJX keeps this many contacts per step, the deepest (its `max_contact_points`
      numeric; C MuJoCo ignores it), instead of a slot for every contact the scene's geom pairs
      could make (97 with the reacher, 127 with the Franka), touching or not; 32 leaves room
      above the most contacts seen at once, and cuts the constraint solve's cost
      (docs/notes/rearrange.md). None: every slot.
    physics: "mjx" (MJX's JAX physics: any device, differentiable) or "c" (C MuJoCo's substeps
      through `envs_mjx.c_physics`, a callback into `mujoco.rollout`'s thread pool: the fast
      path on a CPU; each 2-substep Bullet step starts the solver cold; `max_contacts` does not
      apply, C MuJoCo keeps every contact). Either way the env's step is one jittable function;
      with "c" the pipeline state holds qpos, qvel and the geom, site and camera poses (of the
      final state), not the contacts, constraint forces or body poses.
    """

    family: typing.ClassVar[str] = "rearrange"
    episode_length: int | None = 50
    reward_scale: float | None = None  # 1 / episode_length
    n_frames: int = 8
    arm: Arm = "reacher"
    version: int | None = None
    versions: tuple[int, ...] = (0, 1, 2, 3)
    repeats: int = 4
    settle_steps: int = 20
    random_torque_steps: int = 10
    reacher_init_range: float = 0.75 * math.pi
    ik_iterations: int = 40
    max_faces: int = 200
    max_joint_velocity: float | None = 100.0
    max_contacts: int | None = 32
    physics: Physics = "mjx"


# The domain registry: name → (config class, the "module:class" of its env, which
# `envs_mjx.registry` builds). The env classes are named, not imported: they import JAX and
# MuJoCo, and this module must not.
ENVS: dict[str, tuple[type[EnvConfig], str]] = {
    "CartPole": (CartPoleConfig, "envs_mjx.domains.cartpole:CartPole"),
    "InvertedPendulum": (InvertedPendulumConfig,
                         "envs_mjx.domains.inverted_pendulum:InvertedPendulum"),
    "HalfCheetah": (LocomotionConfig, "envs_mjx.domains.half_cheetah:HalfCheetah"),
    "Ant": (LocomotionConfig, "envs_mjx.domains.ant:Ant"),
    "GeomOnIncline": (InclineConfig, "envs_mjx.domains.incline:GeomOnIncline"),
    "MeshOnIncline": (MeshInclineConfig, "envs_mjx.domains.mesh_incline:MeshOnIncline"),
    # arm="reacher" (default) | "franka"; version=0..11 or a batch of versions (i mod 4).
    "RearrangeGeom": (RearrangeConfig, "envs_mjx.domains.rearrange:RearrangeGeom"),
    "RearrangeYCB": (RearrangeConfig, "envs_mjx.domains.rearrange:RearrangeYCB"),
}
ALL_ENVS: tuple[str, ...] = tuple(ENVS)


def registered(name: str) -> tuple[type[EnvConfig], str]:
    """The named domain's registry entry (config class, env class's "module:class"); an unknown
    name raises ValueError listing the valid ones."""
    if name not in ENVS:
        raise ValueError(f"unknown env {name!r}; valid names: {list(ALL_ENVS)}")
    return ENVS[name]


def default_config(name: str) -> EnvConfig:
    """The named domain's default config (reproduces the reference settings)."""
    return registered(name)[0]()


def configured(name: str, config: EnvConfig | None = None, **overrides) -> EnvConfig:
    """`config` (default: the named domain's default config; else checked to be its class) with
    `overrides` (its fields) replaced. Unknown keys raise ValueError; a list value becomes a
    tuple (overrides read back from a run's JSON config arrive as lists; configs stay hashable
    and compare equal to the ones they were written from)."""
    cls = registered(name)[0]
    if config is None:
        config = cls()
    elif type(config) is not cls:
        raise ValueError(f"{name} needs a {cls.__name__}, got {type(config).__name__}: give "
                         f"a {cls.__name__} or None (its defaults)")
    valid = {f.name for f in dataclasses.fields(config)}
    unknown = sorted(set(overrides) - valid)
    if unknown:
        raise ValueError(f"{name}: unknown config overrides {unknown}; valid: {sorted(valid)}")
    overrides = {k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()}
    return dataclasses.replace(config, **overrides)


def family(name: str) -> str:
    """The named domain's family (one of FAMILIES)."""
    return registered(name)[0].family
