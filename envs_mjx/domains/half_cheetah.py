"""HalfCheetah (suite_reference.md §2): a planar runner; LD state and reward in `locomotion`.

Action a in [-1, 1]^6 (bthigh, bshin, bfoot, fthigh, fshin, ffoot): torques
0.9 x (120, 90, 60, 140, 60, 30) N m * clip(a). LD state: 8 + 12 + 6 = 26 entries; contact flags
for ffoot, fshin, fthigh, bfoot, bshin, bthigh. Never terminates; alive = +1 while |pitch| < 1.
dt 0.0165 s = 4 substeps of 0.004125 s. Multicolor parts [torso, bthigh, bshin, bfoot, fthigh,
fshin, ffoot] take scheme slots [pole, pole2, base, pole, base, pole2, pole3] (torso includes the
head).
"""

from __future__ import annotations

import jax.numpy as jnp

from envs_mjx.base import BASE, POLE, POLE2, POLE3
from envs_mjx.domains.locomotion import Locomotion, LocomotionConfig


def default_config() -> LocomotionConfig:
    return LocomotionConfig()


class HalfCheetah(Locomotion):
    xml = "half_cheetah.xml"
    joints = ("bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot")
    feet = ("ffoot", "fshin", "fthigh", "bfoot", "bshin", "bthigh")
    colour_parts = (
        ("body:torso", POLE),
        ("bthigh", POLE2),
        ("bshin", BASE),
        ("bfoot", POLE),
        ("fthigh", BASE),
        ("fshin", POLE2),
        ("ffoot", POLE3),
    )

    def __init__(self, config: LocomotionConfig | None = None, pixels_fn=None):
        super().__init__(config or default_config(), pixels_fn)

    def _torso_linvel(self, data):
        # Planar root: qvel = (x slide, z slide, y hinge, ...).
        return jnp.stack([data.qvel[0], jnp.zeros(()), data.qvel[1]])

    def _alive(self, z, pitch):
        return jnp.where(jnp.abs(pitch) < 1.0, 1.0, -1.0)

    def _terminated(self, z, pitch):
        return jnp.zeros((), bool)
