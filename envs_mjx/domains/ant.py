"""Ant (docs/reference/suite.md §2): a four-legged walker; LD state and reward in `locomotion`.

Action a in [-1, 1]^8 in joint order (hip_1, ankle_1, ..., hip_4, ankle_4): 250 N m * clip(a).
LD state: 8 + 16 + 4 = 28 entries; contact flags for the four feet (front_left, front_right,
left_back, right_back). Terminates when the torso's z < 0.26 m; alive = +1 above that, else -1.
dt 0.0165 s = 4 substeps of 0.004125 s. Multicolor parts [torso, front_left_foot,
front_right_foot, left_back_foot, right_back_foot] take slots [pole, pole2, base, pole, base].
"""

from __future__ import annotations

import jax.numpy as jnp

from envs_mjx.base import BASE, POLE, POLE2
from envs_mjx.domains.locomotion import Locomotion, LocomotionConfig


def default_config() -> LocomotionConfig:
    return LocomotionConfig()


class Ant(Locomotion):
    xml = "ant.xml"
    joints = tuple(f"{j}_{i}" for i in range(1, 5) for j in ("hip", "ankle"))
    feet = ("front_left_foot", "front_right_foot", "left_back_foot", "right_back_foot")
    colour_parts = (
        ("body:torso", POLE),
        ("front_left_foot", POLE2),
        ("front_right_foot", BASE),
        ("left_back_foot", POLE),
        ("right_back_foot", BASE),
    )

    def __init__(self, config: LocomotionConfig | None = None, pixels_fn=None):
        super().__init__(config or default_config(), pixels_fn)

    def _torso_linvel(self, data):
        # Free joint: qvel[0:3] is the torso origin's linear velocity in the world frame.
        return data.qvel[0:3]

    def _alive(self, z, pitch):
        return jnp.where(z > 0.26, 1.0, -1.0)

    def _terminated(self, z, pitch):
        return z < 0.26
