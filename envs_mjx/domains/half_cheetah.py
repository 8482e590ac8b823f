"""HalfCheetah (docs/reference/suite.md §2): a planar runner; LD state and reward in `locomotion`.

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

# LD entries the planar model holds constant (see HalfCheetah._ld_groups).
_CONSTANT = ("sin_to_target", "cos_to_target", "vy", "roll")


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

    def _ld_groups(self):
        # The planar runner has no sideways, roll or yaw freedom: vy, roll and the heading to the
        # target (1 km along +x: sin 0, cos 1) stay constant, unless the torso turns past
        # vertical and the Euler angles jump by π. They keep their place in the reference's LD
        # state but join no aggregate: an alignment error on a constant says nothing about a
        # latent, and 4 constants among 11 "position" entries would pull its mean towards 0.
        return tuple("other" if n in _CONSTANT else g
                     for n, g in zip(self.ld_state_names, super()._ld_groups(), strict=True))

    def _torso_linvel(self, data):
        # Planar root: qvel = (x slide, z slide, y hinge, ...).
        return jnp.stack([data.qvel[0], jnp.zeros(()), data.qvel[1]])

    def _alive(self, z, pitch):
        return jnp.where(jnp.abs(pitch) < 1.0, 1.0, -1.0)

    def _terminated(self, z, pitch):
        return jnp.zeros((), bool)
