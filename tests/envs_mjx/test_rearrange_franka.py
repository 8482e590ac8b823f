"""Rearrange with the Franka arm, both scenes: the contract under jit + vmap and MJX against C
MuJoCo stepping the same actions (the checks of test_rearrange.py).

This module compiles at XLA's full optimisation (`xla_optimized`, tests/conftest.py): at the
LLVM level 0 the other modules use, the Franka scenes' MJX programs run pathologically slowly
(the RearrangeGeom contract's 10-step rollout of 4 envs had not finished after 18 min of one
core; optimised, compile and run take ~100 s). One compiled harness per scene serves both
checks (the module's tests run in one worker).
"""

import pytest

from tests.envs_mjx import test_rearrange as rearrange

pytestmark = [pytest.mark.xla_optimized, pytest.mark.first]

FRANKA = [(n, "franka") for n in ("RearrangeGeom", "RearrangeYCB")]


@pytest.mark.parametrize("name,arm", FRANKA)
def test_contract_jit_vmap(name, arm):
    rearrange.check_contract(name, arm)


@pytest.mark.parametrize("name,arm", FRANKA)
def test_mjx_step_matches_c_mujoco(name, arm):
    rearrange.check_mjx_matches_c(name, arm)
