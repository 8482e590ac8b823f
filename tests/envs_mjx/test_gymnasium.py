"""envs_mjx.to_gymnasium on CartPole: check_env, vector spaces, keys, determinism, autoreset,
and the packed state and one-buffer report both envs pass through their jitted calls."""

import types

import gymnasium
import jax
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode, VectorEnv

import envs_mjx
from envs_mjx.gym import _flags, _Packing, _Report

N = 4


@pytest.fixture(autouse=True, scope="module")
def _fast_compiling_prng():
    with jax.threefry_partitionable(False):  # see tests/learners/conftest.py
        yield


@pytest.fixture(scope="module")
def single():
    return envs_mjx.to_gymnasium("CartPole", None, seed=0)


@pytest.fixture(scope="module")
def vec():
    return envs_mjx.to_gymnasium("CartPole", N, seed=0)


@pytest.fixture(scope="module")
def direct(single):
    """The wrapped env's own reset / step, jitted here (not the wrapper's functions)."""
    env = single.unwrapped.env
    return jax.jit(env.reset), jax.jit(env.step)


def test_check_env(single):
    assert isinstance(single.unwrapped, gymnasium.Env)
    check_env(single.unwrapped, skip_render_check=True)


def test_single_spaces_and_step(single):
    assert single.observation_space == gymnasium.spaces.Box(0, 255, (64, 64, 3), np.uint8)
    assert single.action_space == gymnasium.spaces.Box(-1, 1, (1,), np.float32)
    obs, info = single.reset(seed=5)
    assert obs.dtype == np.uint8 and obs.shape == (64, 64, 3)
    assert info["ld_state"].dtype == np.float32 and info["ld_state"].shape == (4,)
    assert tuple(info["ld_state_names"]) == ("theta", "theta_dot", "x", "x_dot")
    obs, r, term, trunc, info = single.step(np.array([1.0], np.float32))
    assert type(r) is float and type(term) is bool and type(trunc) is bool
    assert obs in single.observation_space


def test_ld_state_matches_direct_env(single, direct):
    reset, step = direct
    key, sub = jax.random.split(jax.random.PRNGKey(11))
    state = reset(sub)
    _, info = single.reset(seed=11)
    np.testing.assert_array_equal(info["ld_state"], np.asarray(state.ld_state))
    a = np.array([-0.7], np.float32)
    state = step(state, a)
    obs, r, _, _, info = single.step(a)
    np.testing.assert_array_equal(info["ld_state"], np.asarray(state.ld_state))
    np.testing.assert_array_equal(obs, np.asarray(state.pixels))
    assert r == pytest.approx(float(state.reward))
    # An unseeded reset continues from the split key.
    _, sub = jax.random.split(key)
    _, info = single.reset()
    np.testing.assert_array_equal(info["ld_state"], np.asarray(reset(sub).ld_state))


def test_vector_spaces_and_shapes(vec):
    assert isinstance(vec, VectorEnv)
    assert vec.num_envs == N
    assert vec.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert vec.single_observation_space.shape == (64, 64, 3)
    assert vec.observation_space.shape == (N, 64, 64, 3)
    assert vec.observation_space.dtype == np.uint8
    assert vec.single_action_space == gymnasium.spaces.Box(-1, 1, (1,), np.float32)
    assert vec.action_space.shape == (N, 1) and vec.action_space.dtype == np.float32
    obs, info = vec.reset(seed=0)
    assert obs.shape == (N, 64, 64, 3) and obs.dtype == np.uint8
    assert obs in vec.observation_space
    assert info["ld_state"].shape == (N, 4) and info["ld_state"].dtype == np.float32
    obs, r, term, trunc, info = vec.step(vec.action_space.sample())
    assert obs.shape == (N, 64, 64, 3) and obs.dtype == np.uint8
    assert r.shape == (N,) and term.shape == (N,) and trunc.shape == (N,)
    assert term.dtype == np.bool_ and trunc.dtype == np.bool_
    assert info["ld_state"].shape == (N, 4)


def test_vector_ld_state_matches_direct_env(vec, direct):
    reset, _ = direct
    _, sub = jax.random.split(jax.random.PRNGKey(3))
    keys = jax.random.split(sub, N)  # CartPole's reset_batch: vmap(reset) over split keys
    _, info = vec.reset(seed=3)
    want = np.stack([np.asarray(reset(k).ld_state) for k in keys])
    np.testing.assert_allclose(info["ld_state"], want, rtol=1e-6, atol=1e-7)


def test_seed_determinism(single, vec):
    o1, _ = single.reset(seed=7)
    o2, _ = single.reset(seed=7)
    np.testing.assert_array_equal(o1, o2)
    v1, i1 = vec.reset(seed=7)
    s1 = vec.step(np.ones((N, 1), np.float32))[0]
    v2, i2 = vec.reset(seed=7)
    s2 = vec.step(np.ones((N, 1), np.float32))[0]
    np.testing.assert_array_equal(v1, v2)
    np.testing.assert_array_equal(s1, s2)
    np.testing.assert_array_equal(i1["ld_state"], i2["ld_state"])
    v3, i3 = vec.reset(seed=8)
    assert not np.array_equal(v1, v3)
    assert not np.array_equal(i1["ld_state"], i3["ld_state"])


def test_next_step_autoreset(vec):
    obs, info = vec.reset(seed=0)
    # Half the envs pushed at full force, half at half force: they end at different steps, so
    # both sides of the autoreset (ended envs and running ones) are checked below.
    push = np.where(np.arange(N)[:, None] < N // 2, 1.0, 0.5).astype(np.float32)
    for _ in range(200):
        obs, _, term, trunc, info = vec.step(push)
        if term.any():
            break
    else:
        pytest.fail("pushing one way never terminated CartPole")
    ended = term | trunc
    assert term[ended].all() and not trunc.any()  # pushed off the track: termination, not time
    assert np.all(np.abs(info["ld_state"][ended, 2]) > 0.3)  # cart far out
    last_ld = info["ld_state"]
    obs2, r2, term2, trunc2, info2 = vec.step(push)
    # Ended envs: reset observation, reward 0, flags False.
    assert np.all(r2[ended] == 0.0)
    assert not term2[ended].any() and not trunc2[ended].any()
    assert np.all(np.abs(info2["ld_state"][ended]) <= 0.05 + 1e-6)  # CartPole's reset noise
    assert not np.array_equal(obs2[ended], obs[ended])
    # The others stepped on: reward > 0, cart moved further right.
    live = ~ended
    assert live.any()
    assert np.all(r2[live] > 0)
    assert np.all(info2["ld_state"][live, 2] > last_ld[live, 2])
    # And the step after that steps the reset envs normally again.
    _, r3, _, _, info3 = vec.step(push)
    assert np.all(r3[ended] > 0)
    assert np.all(info3["ld_state"][ended, 2] > info2["ld_state"][ended, 2])


def test_vector_step_reports_what_the_vmapped_env_step_leaves(vec, direct):
    """Frames, LD states, rewards and flags through the packed state and the one-buffer report
    equal `vmap(env.step)` from the same reset states."""
    reset, step = direct
    _, sub = jax.random.split(jax.random.PRNGKey(21))
    states = jax.vmap(reset)(jax.random.split(sub, N))  # CartPole's reset_batch
    vec.reset(seed=21)
    actions = np.linspace(-1, 1, N, dtype=np.float32)[:, None]
    want = jax.jit(jax.vmap(step))(states, actions)
    obs, reward, term, trunc, info = vec.step(actions)
    np.testing.assert_array_equal(obs, np.asarray(want.pixels))
    np.testing.assert_allclose(info["ld_state"], np.asarray(want.ld_state), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(reward, np.asarray(want.reward), rtol=1e-6)
    np.testing.assert_array_equal(term | trunc, np.asarray(want.done) > 0)


@pytest.mark.parametrize("batch", [(), (3,)])
def test_report_round_trips_the_step_fields_exactly(batch):
    """The one-buffer report carries frames, LD state, reward, done and truncation exactly, for
    one env and for a batch."""
    rng = np.random.default_rng(0)
    state = types.SimpleNamespace(
        pixels=rng.integers(0, 256, (*batch, 4, 4, 3), dtype=np.uint8),
        ld_state=rng.normal(size=(*batch, 5)).astype(np.float32),
        reward=rng.normal(size=batch).astype(np.float32),
        done=np.ones(batch, np.float32),
        info={"truncation": np.zeros(batch, np.float32)},
    )
    frames, floats = _Report(state).decode(_Report.encode(state))
    np.testing.assert_array_equal(frames, state.pixels)
    np.testing.assert_array_equal(floats[..., :-3], state.ld_state)
    np.testing.assert_array_equal(floats[..., -3], state.reward)
    np.testing.assert_array_equal(floats[..., -2], state.done)
    np.testing.assert_array_equal(floats[..., -1], state.info["truncation"])


def test_flags_split_done_by_truncation():
    floats = np.zeros((3, 5), np.float32)
    floats[:, -2] = [0.0, 1.0, 1.0]  # done
    floats[:, -1] = [0.0, 0.0, 1.0]  # truncation
    term, trunc = _flags(floats)
    np.testing.assert_array_equal(term, [False, True, False])
    np.testing.assert_array_equal(trunc, [False, False, True])


def test_packed_state_round_trips_exactly_in_one_buffer_per_dtype(direct):
    reset, step = direct
    state = step(reset(jax.random.PRNGKey(3)), np.array([0.4], np.float32))
    packing = _Packing(state)
    packed = jax.jit(packing.pack)(state)
    assert [p.dtype for p in packed] == [np.dtype(d) for d in ("bool", "float32", "int32",
                                                                "uint8")]
    back = jax.jit(packing.unpack)(packed)
    assert jax.tree.structure(back) == jax.tree.structure(state)
    jax.tree.map(np.testing.assert_array_equal, back, state)


def test_registered_ids_build_the_named_domain_single_and_vector():
    """`gym.make("jaml/NAME-v0")` and `gym.make_vec` build what `to_gymnasium` builds: the same
    first LD state from the same seed as the env's own reset."""
    from envs_mjx.gym import GYM_IDS

    assert set(GYM_IDS) == set(envs_mjx.ALL_ENVS)
    assert all(gymnasium.spec(i).vector_entry_point is not None for i in GYM_IDS.values())
    env = gymnasium.make("envs_mjx.gym:jaml/InvertedPendulum-v0", pixels="off")
    assert env.unwrapped.env.config.pixels == "off"
    _, info = env.reset(seed=5)
    direct = envs_mjx.make("InvertedPendulum", pixels="off")
    _, sub = jax.random.split(jax.random.PRNGKey(5))
    # jitted: op by op, MJX's reset dispatches hundreds of small programs (seconds on a CPU)
    np.testing.assert_allclose(info["ld_state"], jax.jit(direct.reset)(sub).ld_state, rtol=1e-6)
    vec = gymnasium.make_vec("jaml/InvertedPendulum-v0", 3, vectorization_mode="vector_entry_point",
                             pixels="off")
    obs, info = vec.reset(seed=5)
    assert obs.shape == (3, 64, 64, 3) and info["ld_state"].shape == (3, len(direct.ld_state_names))
    with pytest.raises(gymnasium.error.Error):
        gymnasium.make("jaml/InvertedPendulum-v1")


def test_load_is_playground_style_default_config_plus_overrides():
    config = envs_mjx.default_config("CartPole")
    env = envs_mjx.load("CartPole", config.__class__(**{**vars(config), "episode_length": 7}),
                        config_overrides={"pixels": "off"})
    assert env.config.episode_length == 7 and env.config.pixels == "off"
    assert env.config.n_frames == config.n_frames
    with pytest.raises(ValueError, match="needs a"):
        envs_mjx.load("CartPole", envs_mjx.default_config("HalfCheetah"))


def test_metadata_gives_the_render_rate_of_the_envs_steps(single, vec):
    """CartPole steps 0.02 s of simulated time: 50 frames a second."""
    assert single.unwrapped.env.dt == pytest.approx(0.02)
    assert single.metadata["render_fps"] == 50 and vec.metadata["render_fps"] == 50
    assert single.metadata["render_modes"] == ["rgb_array"]
    assert vec.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP


def test_a_dict_observation_holds_the_ld_state_beside_the_pixels():
    """observation="dict": Dict(pixels, ld_state), passing Gymnasium's checker; its LD state is
    info's, single and vector; a bad choice is named."""
    env = gymnasium.make("jaml/CartPole-v0", observation="dict", pixels="off")
    space = env.observation_space
    assert isinstance(space, gymnasium.spaces.Dict) and set(space) == {"pixels", "ld_state"}
    assert space["ld_state"].shape == (4,) and space["ld_state"].dtype == np.float32
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=3)
    np.testing.assert_array_equal(obs["ld_state"], info["ld_state"])
    obs, *_, info = env.step(np.array([0.5], np.float32))
    assert obs in space and obs["pixels"].shape == (64, 64, 3)
    np.testing.assert_array_equal(obs["ld_state"], info["ld_state"])
    vec = envs_mjx.to_gymnasium("CartPole", 2, observation="dict", pixels="off")
    obs, info = vec.reset(seed=3)
    assert obs["ld_state"].shape == (2, 4) and obs in vec.observation_space
    np.testing.assert_array_equal(obs["ld_state"], info["ld_state"])
    with pytest.raises(ValueError, match=r"observation must be one of \('pixels', 'dict'\)"):
        envs_mjx.to_gymnasium("CartPole", None, observation="state", pixels="off")


def test_cartpole_keeps_the_references_reward_and_limits_or_takes_gymnasiums():
    """By default 200 steps at 1/200 a step, |x| ≤ 0.4 m; conventions="gymnasium" gives
    CartPole-v1's 500 steps, reward 1, |x| ≤ 2.4 m, except where a field is given."""
    reference = envs_mjx.default_config("CartPole")
    assert (reference.episode_length, reference.reward_multiplier, reference.x_threshold) == (
        200, 1 / 200, 0.4)
    assert reference.theta_threshold == pytest.approx(np.deg2rad(12))
    gym_like = envs_mjx.make("CartPole", conventions="gymnasium", pixels="off").config
    assert (gym_like.episode_length, gym_like.reward_multiplier, gym_like.x_threshold) == (
        500, 1.0, 2.4)
    assert gym_like.theta_threshold == reference.theta_threshold
    mine = envs_mjx.make("CartPole", conventions="gymnasium", episode_length=300, pixels="off")
    assert mine.config.episode_length == 300 and mine.config.reward_multiplier == 1.0
    with pytest.raises(ValueError, match=r"conventions must be one of \('reference', "
                                         r"'gymnasium'\), got 'gym'"):
        envs_mjx.make("CartPole", conventions="gym")


def test_cartpole_under_gymnasiums_conventions_pays_1_a_step_and_allows_a_wider_track():
    """The step's reward and termination, stepped (not just the config): x = 0.5 m ends the
    reference's episode and not Gymnasium's."""
    rewards, dones = {}, {}
    for conventions in ("reference", "gymnasium"):
        env = envs_mjx.make("CartPole", conventions=conventions, pixels="off")
        state = jax.jit(env.reset)(jax.random.PRNGKey(0))  # one program, not op by op
        data = state.pipeline_state
        state = state.replace(pipeline_state=data.replace(qpos=data.qpos.at[0].set(0.5)))
        state = jax.jit(env.step)(state, np.zeros(1, np.float32))
        rewards[conventions], dones[conventions] = float(state.reward), float(state.done)
    assert rewards == {"reference": pytest.approx(1 / 200), "gymnasium": 1.0}
    assert dones == {"reference": 1.0, "gymnasium": 0.0}


def test_brax_registry_builds_the_named_domain_with_its_overrides():
    import brax.envs

    from envs_mjx.brax_envs import BRAX_NAMES

    assert set(BRAX_NAMES) == set(envs_mjx.ALL_ENVS)
    env = brax.envs.get_environment("jaml/CartPole", pixels="off", conventions="gymnasium")
    assert type(env) is type(envs_mjx.make("CartPole", pixels="off"))
    assert env.config.pixels == "off" and env.config.episode_length == 500
