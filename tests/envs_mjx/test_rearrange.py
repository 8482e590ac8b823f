"""Rearrange (RearrangeGeom / RearrangeYCB x reacher / franka): the contract under jit + vmap and
MJX against C MuJoCo stepping the same action loop for the reacher pairs (the Franka pairs run the
same checks in test_rearrange_franka.py), the LD state against hand-computed values, per-version
models, resets, the Panda's IK, bad input, and the renderer against mujoco.Renderer on Franka
scenes.

Compile budget (2 CPU cores): one batched rollout per pair, with resets that skip the settle
physics (settle_steps = random_torque_steps = 0) so that reset compiles no MJX step; the full
reset (settle + random torques) is compiled once, for RearrangeGeom with the reacher."""

import functools
import os

# MuJoCo picks its GL backend at import; EGL is the headless one that works on this machine.
os.environ.setdefault("MUJOCO_GL", "egl")

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco.mjx._src import mesh as mjx_mesh

import envs_mjx
from envs_mjx import render
from envs_mjx.domains import rearrange
from tests.envs_mjx.rollout_harness import FAST_COMPILE, RECORD, Harness

# One of the default suite's longest modules: scheduled early (tests/conftest.py).
pytestmark = pytest.mark.first

B, T = 4, 10
COMPILE_OPTIONS = {"reacher": FAST_COMPILE, "franka": FAST_COMPILE}
PAIRS = [(n, a) for n in ("RearrangeGeom", "RearrangeYCB") for a in rearrange.ARMS]
NO_SETTLE = {"settle_steps": 0, "random_torque_steps": 0}


@functools.cache
def harness(name, arm) -> Harness:
    """One (domain, arm) env without reset physics, a jitted batch reset (one key) and a jitted
    batched T-step rollout of random actions."""
    env = envs_mjx.make(name, arm=arm, pixels="off", **NO_SETTLE)
    return Harness(env, B, T, reset_batch=True, compiler_options=COMPILE_OPTIONS[arm],
                   record=(*RECORD, "contact_dist"))


def _row(tree, i):
    return jax.tree.map(lambda x: x[i], tree)


# -- contract -------------------------------------------------------------------------------------


# The reacher pairs here (RearrangeYCB's is RearrangeGeom's scene with other meshes, ~40 s of
# compile on two cores); the Franka pairs in test_rearrange_franka.py, slow-marked. RearrangeGeom's
# reacher contract is slow-marked too: the default suite steps the Geom scene's versions
# (test_every_version_steps_as_its_compiled_model) and runs the tray's contract with
# RearrangeYCB here.
REACHER = [pytest.param("RearrangeGeom", "reacher", marks=pytest.mark.slow),
           ("RearrangeYCB", "reacher")]


@pytest.mark.parametrize("name,arm", REACHER)
def test_contract_jit_vmap(name, arm):
    check_contract(name, arm)


def check_contract(name, arm):
    """Shapes, dtypes, versions per slot, finiteness, bounds and reward of a random rollout."""
    h = harness(name, arm)
    env = h.env
    state0, _, final, traj = h.random_run
    n_arm = 2 if arm == "reacher" else 7
    d = 1 + 2 * n_arm + 4 * 12
    assert env.action_size == n_arm and len(env.ld_state_names) == d == env.observation_size
    assert d == (53 if arm == "reacher" else 63)
    assert len(env.ld_state_groups) == d
    for s in (state0, final):
        assert s.ld_state.shape == (B, d) and s.ld_state.dtype == jnp.float32
        assert s.pixels.shape == (B, 64, 64, 3) and s.pixels.dtype == jnp.uint8
        assert s.reward.shape == (B,) and s.done.shape == (B,)
        # Env slot i uses version i mod 4; the LD state's first entry is version / 10.
        np.testing.assert_array_equal(np.asarray(s.info["version"]), np.arange(B) % 4)
        np.testing.assert_allclose(np.asarray(s.ld_state[:, 0]), (np.arange(B) % 4) / 10)
    for key in ("ld_state", "reward", "qpos", "qvel"):
        assert np.isfinite(traj[key]).all(), key
    assert np.isin(traj["done"], [0.0, 1.0]).all() and not traj["nonfinite"].any()
    assert (np.abs(traj["ld_state"][:, :, 1:]) <= 1.0 + 1e-5).all()
    # Random torques move the arm: its sin / cos entries change.
    arm_ld = slice(1, 1 + 2 * n_arm)
    assert (
        np.abs(traj["ld_state"][-1, :, arm_ld] - np.asarray(state0.ld_state[:, arm_ld])).max()
        > 1e-2
    )
    # Reward: per step (1 - mean min(distance, 1)) / 50.
    assert (traj["reward"] > 0).all() and (traj["reward"] <= 1 / 50).all()
    check_contact_cap(env, traj["contact_dist"], "random rollout from reset")


def check_contact_cap(env, dist, what):
    """MJX keeps the `max_contacts` deepest contacts (RearrangeConfig): when fewer of the kept
    ones touch (distance < 0, MJX's activation at margin 0), every contact it dropped was
    further apart than one it kept, so none touched and the cap changed nothing."""
    cap = env.config.max_contacts
    assert dist.shape[-1] == cap, (dist.shape, cap)
    touching = (dist < 0).sum(-1)
    assert touching.max() < cap, f"{what}: {touching.max()} touching contacts fill the cap {cap}"


# -- LD state and reward against hand-computed values --------------------------------------------


def _state_at(env, qpos, slot):
    """(data, info) of env at qpos (no physics) for version slot `slot`, as one jitted program
    (run eagerly, each of its hundreds of ops compiled apart: ~30 s of the test)."""

    def at(qpos):
        _, _, info = env._sample_reset(jax.random.key(0), slot)
        info = {k: v for k, v in info.items() if k != "reset_action"}
        return env._initial_data(env.physics_model(info), qpos, jnp.zeros(env.mj_model.nv)), info

    return jax.jit(at)(jnp.asarray(qpos, jnp.float32))


def _reward_done(env, data, info):
    """(reward, done) of a step that ends at `data`, jitted like `_state_at`."""
    return jax.jit(lambda d, i: env._reward_done(d, d, jnp.zeros(2), i)[:2])(data, info)


def test_ld_state_and_reward_hand_computed():
    env = envs_mjx.make("RearrangeYCB", arm="reacher", pixels="off", versions=(0, 1, 2, 3))
    c, s = np.cos, np.sin
    h = np.sqrt(0.5)
    qpos = np.zeros(env.mj_model.nq)
    qpos[:2] = [0.3, -1.2]
    # obj0 at (0.09, -0.18, 0.075), turned 90 deg about z; obj1 at the identity; obj2 beyond the
    # workspace in x (clipped to 1); obj3 turned 180 deg about x.
    objects = [
        ((0.09, -0.18, 0.075), (h, 0, 0, h)),
        ((0.2, -0.2, 0.05), (1, 0, 0, 0)),
        ((0.6, 0.2, 0.0), (1, 0, 0, 0)),
        ((-0.45, 0.45, 0.2), (0, 1, 0, 0)),
    ]
    for k, (p, q) in enumerate(objects):
        a = env._obj_qpos[k]
        qpos[a : a + 7] = [*p, *q]
    data, info = _state_at(env, qpos, 2)  # slot 2: version 2 (chef can, sugar box, pear, lemon)
    ld = np.asarray(jax.jit(env._ld_state)(data, info))
    want = [0.2, s(0.3), c(0.3), s(-1.2), c(-1.2)]
    want += [0.2, -0.4, 0.0, 0, -1, 0, 1, 0, 0, 0, 0, 1]  # turned 90 deg about z
    want += [2 * 0.65 / 0.9 - 1, 2 * 0.25 / 0.9 - 1, 2 * 0.1 / 0.25 - 1, *np.eye(3).ravel()]
    want += [1.0, 2 * 0.65 / 0.9 - 1, -0.6, *np.eye(3).ravel()]
    want += [-1.0, 1.0, 1.0, 1, 0, 0, 0, -1, 0, 0, 0, -1]
    np.testing.assert_allclose(ld, want, atol=1e-6)
    assert env.ld_state_names[:5] == ("version", "sin_q0", "cos_q0", "sin_q1", "cos_q1")
    assert env.ld_state_names[5:8] == ("obj0_x", "obj0_y", "obj0_z")
    assert env.ld_state_names[8] == "obj0_r00" and env.ld_state_groups[8] == "orientation"
    # Reward: the can and the box aim at (0.2, -0.2), the pear and the lemon at (0.2, 0.2).
    reward, done = _reward_done(env, data, info)
    dist = [np.hypot(0.11, 0.02), 0.0, min(np.hypot(0.4, 0.0), 1.0), np.hypot(0.65, 0.25)]
    np.testing.assert_allclose(float(reward), 1 - np.mean(dist), rtol=1e-6)
    assert bool(done)  # obj2 left the workspace (x > 0.45)
    # Geom: every shape aims at (0.2, 0.2); nothing outside: not done.
    geom = envs_mjx.make("RearrangeGeom", pixels="off")
    qpos[env._obj_qpos[2]] = 0.3
    data, info = _state_at(geom, qpos, 0)
    reward, done = _reward_done(geom, data, info)
    pos = [o[0] for o in objects]
    pos[2] = (0.3, 0.2, 0.0)
    dist = [min(np.hypot(p[0] - 0.2, p[1] - 0.2), 1.0) for p in pos]
    np.testing.assert_allclose(float(reward), 1 - np.mean(dist), rtol=1e-6)
    assert not bool(done)


def test_franka_ld_names_and_fk_match_mujoco():
    env = envs_mjx.make("RearrangeGeom", arm="franka", pixels="off")
    names = env.ld_state_names
    assert (
        len(names) == 63
        and names[1:3] == ("sin_q0", "cos_q0")
        and names[13:15]
        == (
            "sin_q6",
            "cos_q6",
        )
    )
    fk = jax.jit(env._franka_fk())
    m = env.mj_model
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    for _ in range(3):
        q = rng.uniform(env._qlo, env._qhi)
        d.qpos[:7] = q
        mujoco.mj_kinematics(m, d)
        pos, z_axis = fk(jnp.asarray(q, jnp.float32))
        np.testing.assert_allclose(pos, d.site_xpos[env._ee_site], atol=1e-5)
        hand = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "hand")
        np.testing.assert_allclose(z_axis, d.xmat[hand].reshape(3, 3)[:, 2], atol=1e-5)


def test_franka_ik_reaches_gripper_down_poses():
    """The reset's IK: for targets the arm can reach (x <= 0, within 0.75 m of the shoulder) the
    end effector lands within 1 cm, pointing down within 0.1 rad."""
    env = envs_mjx.make("RearrangeGeom", arm="franka", pixels="off")
    ik = jax.jit(jax.vmap(env._franka_ik))
    fk = jax.vmap(env._franka_fk())
    keys = jax.random.split(jax.random.key(3), 16)
    q = ik(keys)
    pos, z_axis = fk(q)
    targets = []
    for k in keys:  # the targets _franka_ik draws from each key
        k_xy, k_z = jax.random.split(k)
        xy = jax.random.uniform(k_xy, (2,), minval=-0.5, maxval=0.5)
        z = jax.random.uniform(k_z, (1,), minval=0.05, maxval=0.35)
        targets.append(np.concatenate([xy, z]))
    targets = np.array(targets)
    reach = np.linalg.norm(targets - np.array([-0.7, 0.0, 0.333]), axis=1)
    ok = (targets[:, 0] <= 0.0) & (reach < 0.75)
    assert ok.sum() >= 4
    err = np.linalg.norm(np.asarray(pos) - targets, axis=1)
    assert (err[ok] < 0.01).all(), err[ok]
    tilt = np.arccos(np.clip(-np.asarray(z_axis)[:, 2], -1, 1))
    assert (tilt[ok] < 0.1).all(), tilt[ok]
    assert (np.asarray(q) >= env._qlo - 1e-6).all() and (np.asarray(q) <= env._qhi + 1e-6).all()


# -- MJX against C MuJoCo -------------------------------------------------------------------------


def c_step(env, m, d, action):
    """The env's action loop in C MuJoCo: repeats x (torque [+ qfrc_bias], 2 mj_steps, software
    joint limits)."""
    lim = env._torque
    n = len(lim)
    for _ in range(env.config.repeats):
        torque = lim * np.clip(action, -1, 1)
        if env._franka:
            torque = torque + d.qfrc_bias[:n]
        d.ctrl[:] = np.clip(torque, -lim, lim)
        mujoco.mj_step(m, d, rearrange.BULLET_SUBSTEPS)
        q = d.qpos[:n].copy()
        over = (q < env._qlo) | (q > env._qhi)
        d.qpos[:n] = np.clip(q, env._qlo, env._qhi)
        d.qvel[:n] = np.where(over, 0.0 if env._franka else -d.qvel[:n], d.qvel[:n])


def resting_state(env, state):
    """`state` with the objects at rest on the floor (upright, at their half-height, 0.2 mm into
    it) at radius 0.25 around the tray's centre, 45 degrees off the axes, and the arm clear of
    them (reacher along +x, the Panda's gripper at (-0.25, 0, 0.25)), where its random torques
    reach them within a few steps."""
    qpos = np.array(state.pipeline_state.qpos)
    if env._franka:
        qpos[:, :7] = np.asarray(env.franka_ik(jnp.array([-0.25, 0.0, 0.25])))
    else:
        qpos[:, :2] = 0.0
    for i, slot in enumerate(np.asarray(state.info["version"])):
        names = env._sets[env.versions[slot] % 6]
        for k, name in enumerate(names):
            kind = env._kinds[name]
            half = np.mean(kind.extent) / 2 if kind.shape == "sphere" else kind.extent[2] / 2
            angle = np.pi / 2 * k + np.pi / 4
            a = env._obj_qpos[k]
            qpos[i, a : a + 7] = [
                0.25 * np.cos(angle),
                0.25 * np.sin(angle),
                half - 2e-4,
                1,
                0,
                0,
                0,
            ]
    data = state.pipeline_state.replace(
        qpos=jnp.asarray(qpos), qvel=jnp.zeros_like(state.pipeline_state.qvel)
    )
    return state.replace(pipeline_state=data)


# Max |qpos| / |qvel| difference after K env steps (K x 8 substeps of random torques), MJX (float32)
# against C MuJoCo (float64) running the same loop, from objects at rest. The 16-sided prism (the
# cylinder's collision shape) resting on the floor sits 5e-5 m apart in the two engines (their
# plane-mesh contact points differ), and once the arm strikes it they part within a step or two
# (1-3 cm, as MeshOnIncline's rounded meshes do), so K is short. From the reset's random drop
# (random heights and orientations, overlapping objects) the two engines part on the first impacts
# (measured up to 5 cm within 3 steps): landings on an edge or corner are chaotic, so the check
# starts from rest.
K = 3
C_TOL = (1e-4, 2e-2)


@pytest.mark.parametrize("name,arm", REACHER)
def test_mjx_step_matches_c_mujoco(name, arm):
    check_mjx_matches_c(name, arm)


def check_mjx_matches_c(name, arm):
    """K steps of the batched MJX rollout against C MuJoCo stepping each slot's own model."""
    h = harness(name, arm)
    env = h.env
    state0, actions, _, _ = h.random_run
    state0 = resting_state(env, state0)
    _, traj = jax.tree.map(np.asarray, h.rollout(state0, actions))
    check_contact_cap(env, traj["contact_dist"][:K], "rollout from rest")
    actions = np.asarray(actions)
    errs = []
    for i in range(B):
        info = jax.tree.map(np.asarray, _row(state0.info, i))
        m = env.mj_model_for(info)
        d = mujoco.MjData(m)
        d.qpos[:] = np.asarray(state0.pipeline_state.qpos[i])
        d.qvel[:] = 0.0
        for k in range(K):
            c_step(env, m, d, actions[k, i])
            errs.append(
                (
                    np.abs(d.qpos - traj["qpos"][k, i]).max(),
                    np.abs(d.qvel - traj["qvel"][k, i]).max(),
                )
            )
    qerr, verr = np.max(errs, axis=0)
    print(f"{name}/{arm}: max |dqpos| {qerr:.2e}, max |dqvel| {verr:.2e} over {K} steps")
    assert qerr < C_TOL[0] and verr < C_TOL[1], (qerr, verr)


# -- per-version models ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["RearrangeGeom", "RearrangeYCB"])
def test_every_version_steps_as_its_compiled_model(name):
    """Over all 12 versions (v5 / v11 put other shapes in slots 0, 1 and 3): the per-env MJX model
    carries exactly the version's compiled physics fields and hull data, which C MuJoCo steps."""
    env = envs_mjx.make(name, pixels="off", versions=rearrange.VERSIONS)
    for slot, v in enumerate(env.versions):
        _, _, info = env._sample_reset(jax.random.key(v), slot)
        m = env.mj_model_for(jax.tree.map(np.asarray, info))
        model = env.physics_model(info)
        for field in rearrange.PHYSICS_FIELDS:
            np.testing.assert_allclose(getattr(model, field), getattr(m, field), atol=1e-6)
        for mid, hull in enumerate(model._impl.mesh_convex):
            if hull is not None and mid in env._tables["convex"]:
                np.testing.assert_allclose(hull.vert, mjx_mesh.convex(m, mid).vert, atol=1e-6)
        kinds = [env._kinds[n] for n in env._sets[v % 6]]
        body = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"obj{k}") for k in range(4)]
        np.testing.assert_allclose(m.body_mass[body], [k.mass for k in kinds], rtol=1e-6)
        panel = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "panel_left")
        mat = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_MATERIAL, m.geom_matid[panel])
        assert mat == f"tray_{rearrange._tray_name(v)}"
        assert (v >= 6) == (mat == "tray_black")


def test_v5_slot_shapes_rest_in_c_mujoco():
    """v5's objects (cube, sphere, sphere, cube) dropped into the tray come to rest on the floor
    at their own half-height: the unused slot shapes (1 mm, massless) do not hold them up."""
    env = envs_mjx.make("RearrangeGeom", pixels="off", version=5)
    _, _, info = env._sample_reset(jax.random.key(0), 0)
    m = env.mj_model_for(jax.tree.map(np.asarray, info))
    d = mujoco.MjData(m)
    d.qpos[:2] = [2.5, 0.0]  # the arm points away from the objects
    xy = [(-0.2, -0.2), (-0.2, 0.2), (0.2, -0.2), (0.2, 0.2)]
    for k, p in enumerate(xy):
        a = env._obj_qpos[k]
        d.qpos[a : a + 7] = [*p, 0.12, 1, 0, 0, 0]
    mujoco.mj_step(m, d, 400)
    z = [d.qpos[env._obj_qpos[k] + 2] for k in range(4)]
    want = [0.075, 0.04, 0.04, 0.075]  # the cube stands on its 0.05 x 0.10 end
    np.testing.assert_allclose(z, want, atol=3e-3)


# -- reset ----------------------------------------------------------------------------------------


@pytest.mark.slow  # the full reset's 30 physics steps compile for ~40 s on two cores
def test_reset_settles_objects_inside_the_tray():
    """The full reset (20 settle + 10 random-torque Bullet steps): every object is inside the
    walls, low in the tray (it may rest on another object: spawns overlap, as in the reference),
    most at rest."""
    env = envs_mjx.make("RearrangeGeom", pixels="off")
    reset = jax.jit(lambda k: env.reset_batch(k, B), compiler_options=FAST_COMPILE)
    s = reset(jax.random.key(5))
    assert "reset_action" not in s.info
    qpos = np.asarray(s.pipeline_state.qpos)
    qvel = np.asarray(s.pipeline_state.qvel)
    for k in range(4):
        a = env._obj_qpos[k]
        assert (np.abs(qpos[:, a : a + 2]) < 0.38).all()
        assert ((qpos[:, a + 2] > 0.01) & (qpos[:, a + 2] < 0.15)).all(), qpos[:, a + 2]
    obj_dofs = np.concatenate([np.arange(2 + 6 * k, 5 + 6 * k) for k in range(4)])
    # Most objects are at rest; one the arm's last random torques struck may still roll
    # (measured up to 1.4 m/s).
    speed = np.abs(qvel[:, obj_dofs]).reshape(B, 4, 3).max(-1)
    assert (speed < 3.0).all() and (speed < 0.5).mean() >= 0.75, speed
    assert not np.asarray(s.done).any()
    # The arm starts where U(+-0.75 pi) put it, moved only by the settle and random torques.
    assert (np.abs(qpos[:, :2]) < np.pi).all() and np.ptp(qpos[:, 0]) > 0.3


# -- bad input ------------------------------------------------------------------------------------


def test_bad_input_lists_valid_values():
    with pytest.raises(ValueError, match=r"arm must be one of \('reacher', 'franka'\)"):
        envs_mjx.make("RearrangeGeom", arm="ur5", pixels="off")
    with pytest.raises(ValueError, match=r"version must be in \[0, 1, .*11\], got \[12\]"):
        envs_mjx.make("RearrangeYCB", version=12, pixels="off")
    with pytest.raises(ValueError, match=r"version must be in .*got \[-1\]"):
        envs_mjx.make("RearrangeGeom", versions=(0, -1), pixels="off")
    with pytest.raises(ValueError, match=r"max_contacts must be a positive int or None, got 0"):
        envs_mjx.make("RearrangeGeom", max_contacts=0, pixels="off")
    # A state of the reacher env the default contract already rolled out (RearrangeGeom's reacher
    # rollout is slow-marked; compiling it for this check alone took ~40 s on two cores).
    env = harness("RearrangeYCB", "reacher").env
    state0, *_ = harness("RearrangeYCB", "reacher").random_run
    with pytest.raises(ValueError, match=r"action must have shape \(2,\), got \(7,\)"):
        env.step(_row(state0, 0), jnp.zeros(7))


# -- rendering ------------------------------------------------------------------------------------


def _franka_scene(env, slot, rng):
    """(C model, data) of a Franka scene: the arm at a random gripper-down IK pose, objects
    scattered in the tray at random orientations."""
    _, _, info = env._sample_reset(jax.random.key(int(rng.integers(1 << 30))), slot)
    info = jax.tree.map(np.asarray, info)
    m = env.mj_model_for(info)
    d = mujoco.MjData(m)
    d.qpos[:7] = np.asarray(env._franka_ik(jax.random.key(int(rng.integers(1 << 30)))))
    for k in range(4):
        a = env._obj_qpos[k]
        q = rng.normal(size=4)
        d.qpos[a : a + 7] = [*rng.uniform(-0.3, 0.3, 2), 0.05, *(q / np.linalg.norm(q))]
    mujoco.mj_forward(m, d)
    return m, d, info


@pytest.mark.parametrize("name", ["RearrangeGeom", "RearrangeYCB"])
def test_renderer_matches_mujoco_on_franka_scenes(name):
    """Segmentation agrees with mujoco.Renderer on >= 97% of pixels with the Panda's meshes in
    view, across versions (tray textures, a black tray, YCB meshes switched per version); the
    tray's textured panels match MuJoCo's colours."""
    env = envs_mjx.make(name, arm="franka", pixels="off", versions=(0, 2, 5, 7))
    ctx = render.make_context(env.mj_model, "pixels", 64, 64)
    draw = jax.jit(lambda c, d: render.render(env._render_context(c, d[1]), d[0]))
    rng = np.random.default_rng(1)
    m0 = env.mj_model
    links = [
        g
        for g in range(m0.ngeom)
        if m0.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH
        and m0.geom_bodyid[g] != 0
        and "obj" not in (mujoco.mj_id2name(m0, mujoco.mjtObj.mjOBJ_BODY, m0.geom_bodyid[g]) or "")
    ]
    panels = [mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_GEOM, p) for p in rearrange.TRAY_PANELS]
    scores, colour = [], []
    for slot in range(len(env.versions)):
        m, d, info = _franka_scene(env, slot, rng)
        with mujoco.Renderer(m, 64, 64) as r:
            r.update_scene(d, "pixels")
            ref_rgb = r.render().astype(np.float32)
            r.enable_segmentation_rendering()
            r.update_scene(d, "pixels")
            s = r.render()
        ref = np.where(s[..., 1] == mujoco.mjtObj.mjOBJ_GEOM, s[..., 0], -1)
        poses = {
            f: np.asarray(getattr(d, f), np.float32)
            for f in ("geom_xpos", "geom_xmat", "cam_xpos", "cam_xmat")
        }
        c = ctx.replace(geom_rgb=jnp.asarray(info["geom_rgba"][:, :3]))
        out = draw(c, (_Poses(**poses), info))
        seg = np.asarray(out.segmentation)
        scores.append((seg == ref).mean())
        assert np.isin(ref, links).sum() >= 30, "the arm should be in view"
        assert np.isin(seg, links).sum() >= 30
        on_panel = np.isin(seg, panels) & (seg == ref)
        colour.append(np.abs(np.asarray(out.rgb, np.float32) - ref_rgb)[on_panel].mean())
    print(name, "segmentation agreement", np.round(scores, 4), "panel |rgb|", np.round(colour, 1))
    assert min(scores) >= 0.97, scores
    assert max(colour) < 12, colour


class _Poses:
    """What the renderer reads from data, as a pytree."""

    def __init__(self, **fields):
        self.__dict__.update(fields)


jax.tree_util.register_pytree_node(
    _Poses,
    lambda p: (tuple(p.__dict__.values()), tuple(p.__dict__)),
    lambda keys, vals: _Poses(**dict(zip(keys, vals, strict=True))),
)
