"""Every domain declares a group (position, velocity, contact, other) for each LD dimension."""

import pytest

import envs_mjx
from envs_mjx.base import LD_GROUPS


@pytest.mark.parametrize("name", envs_mjx.ALL_ENVS)
def test_every_ld_dimension_has_a_group(name):
    env = envs_mjx.make(name, pixels="off")
    groups = env.ld_state_groups
    assert len(groups) == len(env.ld_state_names)
    assert set(groups) <= set(LD_GROUPS)
    assert "position" in groups
    # Rearrange's LD state (the reference's) holds poses only: no velocities.
    assert "velocity" in groups or name.startswith("Rearrange")
    for n, g in zip(env.ld_state_names, groups, strict=True):
        if n.endswith(("_dot", "_vel")):
            assert g == "velocity", n
        if n.endswith("_contact"):
            assert g == "contact", n
