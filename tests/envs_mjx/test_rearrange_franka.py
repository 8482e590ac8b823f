"""Rearrange with the Franka arm, both scenes: the contract under jit + vmap and MJX against C
MuJoCo stepping the same actions (the checks of test_rearrange.py).

The Franka scenes' MJX programs once ran pathologically slowly on the CPU (the RearrangeGeom
contract's 10-step rollout of 4 envs had not finished after 18 min of one core at LLVM level 0,
~100 s at XLA's full level). The cause was XLA:CPU's newer fusion emitters on MJX's kinematics of
the arm's deep chain (envs_mjx/compile.py); with jaml's env options (`FAST_COMPILE` includes
them) the module compiles at level 0 like the others and took 44 s in all, against 121 s at the
full level without them (2-core CPU, 2026-11-25). One compiled harness per scene serves both
checks (the module's tests run in one worker).
"""

import pytest

from tests.envs_mjx import test_rearrange as rearrange

# Out of the default suite (55 s of its CPU, the longest module; `make test-slow` runs it): the
# Franka is the optional arm (the reacher is the default and Fig. 3's), and the default suite
# keeps its compile options (test_compile.py), its IK (test_rearrange.py) and its renders
# against MuJoCo's renderer (test_render.py); both scenes' contracts run with the reacher.
pytestmark = [pytest.mark.slow]

FRANKA = [("RearrangeGeom", "franka"), ("RearrangeYCB", "franka")]


@pytest.mark.parametrize("name,arm", FRANKA)
def test_contract_jit_vmap(name, arm):
    rearrange.check_contract(name, arm)


@pytest.mark.parametrize("name,arm", FRANKA)
def test_mjx_step_matches_c_mujoco(name, arm):
    rearrange.check_mjx_matches_c(name, arm)
