"""The relation penalty a stream's learner trains under (paper eq. 4, docs/transfer.md): the
relations its config's `penalty` names, on the latent slots the learner declares."""

from __future__ import annotations

from envs_mjx.base import Env
from jaml import learners
from jaml.configs.stream import PenaltyConfig


def latent_penalty(penalty: PenaltyConfig, learner: learners.Learner, env: Env):
    """`relations.latent_penalty` of `penalty`: its relations, loaded and selected, placed on
    the slots the `learner` declares (`LearnerConfig.penalty_slots`), the env's action between
    two steps."""
    from jaml import relations  # here: a stream without a penalty needs none of it

    if not penalty.relations:
        raise ValueError("penalty.relations names no relation set: give the checkpoint "
                         "directory jaml.relations.save wrote")
    if not hasattr(learner.config, "penalty_slots"):
        raise ValueError(f"penalty: the learner {type(learner).__name__} declares no latent "
                         "slots for relations (LearnerConfig.penalty_slots); give no penalty")
    rs = relations.load(penalty.relations)
    rs = rs.select(list(penalty.used)) if penalty.used else rs
    layout = relations.LatentLayout.place(learner.config.penalty_slots, static=penalty.static,
                                          dynamic=penalty.dynamic)
    return relations.latent_penalty(
        rs, layout, latent_size=learner.config.penalty_dim, action_size=env.action_size,
        weight=penalty.weight, form=penalty.form, ok_weight=penalty.ok_weight,
        ok_rows=penalty.ok_rows, ok_fraction=penalty.ok_fraction)
