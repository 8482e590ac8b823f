"""Rearrange with physics="c" (C MuJoCo substeps through `envs_mjx.c_physics`): the env's step
against a plain `mj_step` loop of the same action loop (test_rearrange.c_step), for both arms;
the batch axes the callback takes (none, one, two); bad input.

The C path compiles no MJX physics (its programs are the callback, kinematics, the Franka's bias
and the LD state), so a full reset with the settle and random-torque steps is cheap here.
Compiled at the suite's cheap setting (tests/conftest.py): its older fusion emitters keep the
Franka's MJX kinematics fast at level 0 (with XLA's default emitters they run pathologically
slowly there, envs_mjx/compile.py), and every program here compiles faster than at the full
level."""

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs_mjx
from envs_mjx.c_physics import CPhysics
from tests.envs_mjx.test_rearrange import c_step, resting_state

B, K = 4, 5
# Max |qpos| / |qvel| difference after K env steps (K x 8 substeps) against the plain loop. The
# engines are the same; what differs: the env holds qpos / qvel in float32 between Bullet steps,
# and each Bullet step's solve starts cold where the loop's mj_step carries its warm start.
# Measured (2-core CPU, 5 steps from rest): reacher 4.8e-7 / 2.1e-6, Franka 5.6e-7 / 8.2e-6;
# MJX's own float32 physics against C is allowed 1e-4 / 2e-2 over 3 steps (test_rearrange).
TOL = (1e-5, 1e-4)


@functools.cache
def env_and_programs(arm):
    env = envs_mjx.make("RearrangeGeom", arm=arm, physics="c", pixels="off")
    reset = jax.jit(lambda k: env.reset_batch(k, B))
    step = jax.jit(jax.vmap(env.step))
    return env, reset, step


@pytest.mark.parametrize("arm", ["reacher", pytest.param("franka", marks=pytest.mark.slow)])
def test_steps_as_a_plain_mj_step_loop(arm):
    env, reset, step = env_and_programs(arm)
    state0 = reset(jax.random.key(0))
    # The full reset ran its settle and random-torque Bullet steps in C: objects in the tray.
    pos = np.stack([np.asarray(env.object_poses(q)[0]) for q in state0.pipeline_state.qpos])
    assert np.isfinite(pos).all() and (np.abs(pos[..., :2]) < 0.45).all(), pos
    state0 = resting_state(env, state0)
    actions = np.random.default_rng(0).uniform(-1, 1, (K, B, env.action_size)).astype(np.float32)
    s, traj = state0, []
    for a in actions:
        s = step(s, jnp.asarray(a))
        traj.append(jax.tree.map(np.asarray, (s.pipeline_state, s.ld_state)))
    dt = env.mj_model.opt.timestep
    np.testing.assert_allclose(
        np.asarray(s.pipeline_state.time - state0.pipeline_state.time), K * env.n_frames * dt,
        rtol=1e-4,
    )
    errs = []
    for i in range(B):
        m = env.mj_model_for({"version": np.asarray(state0.info["version"][i])})
        d = mujoco.MjData(m)
        d.qpos[:] = np.asarray(state0.pipeline_state.qpos[i])
        d.qvel[:] = 0.0
        d.qfrc_bias[:] = np.asarray(state0.pipeline_state.qfrc_bias[i])  # the Franka's first torque
        for k in range(K):
            c_step(env, m, d, actions[k, i])
            mujoco.mj_kinematics(m, d)
            data, ld = traj[k]
            errs.append((np.abs(d.qpos - data.qpos[i]).max(), np.abs(d.qvel - data.qvel[i]).max()))
            # What the LD state, reward and pixels read is refreshed from the new qpos.
            np.testing.assert_allclose(data.site_xpos[i], d.site_xpos, atol=1e-4)
            np.testing.assert_allclose(data.geom_xpos[i], d.geom_xpos, atol=1e-4)
            q = d.qpos[: env.action_size]
            arm_ld = np.stack([np.sin(q), np.cos(q)], 1).ravel()
            np.testing.assert_allclose(ld[i, 1 : 1 + arm_ld.size], arm_ld, atol=1e-5)
    qerr, verr = np.max(errs, axis=0)
    print(f"{arm}: max |dqpos| {qerr:.2e}, max |dqvel| {verr:.2e} over {K} steps")
    assert qerr < TOL[0] and verr < TOL[1], (qerr, verr)
    # Random torques moved the arm.
    moved = traj[-1][0].qpos[:, :2] - np.asarray(state0.pipeline_state.qpos[:, :2])
    assert np.abs(moved).max() > 1e-2


def test_callback_batch_axes_bias_and_poses():
    """One call per step whatever the batch axes: unbatched, vmapped, vmapped twice agree; the
    state, bias and poses against mj_step from each state (an independent loop)."""
    env = envs_mjx.make("RearrangeGeom", physics="c", pixels="off")
    c = CPhysics([env.mj_model_for({"version": v}) for v in range(len(env.versions))])
    rng = np.random.default_rng(1)
    state = env_and_programs("reacher")[1](jax.random.key(2)).pipeline_state
    qpos = np.asarray(state.qpos)  # [B, nq]
    qvel = rng.normal(0, 0.5, (B, env.mj_model.nv)).astype(np.float32)
    ctrl = rng.uniform(-3, 3, (B, 2)).astype(np.float32)
    slot = np.arange(B) % 4
    poses = ("geom_xpos", "cam_xmat", "site_xpos")

    def run(slot, qpos, qvel, ctrl):
        out = c.step(slot, qpos, qvel, ctrl, nstep=3, bias=True)
        return {**out, **c.poses(slot, out["qpos"], poses)}

    flat = jax.jit(jax.vmap(run))(slot, qpos, qvel, ctrl)
    one = [run(slot[i], qpos[i], qvel[i], ctrl[i]) for i in range(B)]
    two = jax.vmap(jax.vmap(run))(
        *(x.reshape(2, B // 2, *x.shape[1:]) for x in (slot, qpos, qvel, ctrl))
    )
    assert set(flat) == {"qpos", "qvel", "qfrc_bias", *poses}
    assert flat["cam_xmat"].shape == (B, env.mj_model.ncam, 3, 3)
    for k, v in flat.items():
        np.testing.assert_array_equal(np.stack([o[k] for o in one]), v)
        np.testing.assert_array_equal(np.asarray(two[k]).reshape(v.shape), v)
    for i in range(B):
        m = env.mj_model_for({"version": slot[i]})
        d = mujoco.MjData(m)
        d.qpos[:], d.qvel[:], d.ctrl[:] = qpos[i], qvel[i], ctrl[i]
        mujoco.mj_step(m, d, 3)
        np.testing.assert_allclose(flat["qpos"][i], d.qpos, atol=1e-6)
        np.testing.assert_allclose(flat["qvel"][i], d.qvel, atol=1e-5)
        np.testing.assert_allclose(flat["qfrc_bias"][i], d.qfrc_bias, rtol=1e-5, atol=1e-5)
        mujoco.mj_forward(m, d)
        for k in poses:
            np.testing.assert_allclose(flat[k][i].ravel(), getattr(d, k).ravel(), atol=1e-6)


def test_bad_input():
    with pytest.raises(ValueError, match=r"physics must be one of \('mjx', 'c'\)"):
        envs_mjx.make("RearrangeGeom", physics="warp")
    with pytest.raises(ValueError, match="at least one MjModel"):
        CPhysics([])
    m = envs_mjx.make("RearrangeGeom", physics="c", pixels="off").mj_model
    with pytest.raises(ValueError, match=r"qpos must have shape \(30,\)"):
        CPhysics([m]).step(0, jnp.zeros(3), jnp.zeros(m.nv), jnp.zeros(m.nu), 2)
    with pytest.raises(ValueError, match="nstep must be >= 2"):
        CPhysics([m]).step(0, jnp.zeros(m.nq), jnp.zeros(m.nv), jnp.zeros(m.nu), 1, bias=True)
    with pytest.raises(ValueError, match="'nefc' is not a pose field"):
        CPhysics([m]).poses(0, jnp.zeros(m.nq), ("nefc",))
