"""GeomOnIncline's normalised LD state follows the config's theta / friction ranges."""

import jax
import numpy as np

import envs_mjx
from envs_mjx.domains import incline
from tests.envs_mjx.rollout_harness import FAST_COMPILE


def test_ld_normalisation_follows_overridden_ranges():
    theta_range, friction_range = (0.1, 0.3), (0.2, 0.6)
    env = envs_mjx.make(
        "GeomOnIncline",
        pixels="off",
        theta_range=theta_range,
        friction_range=friction_range,
        ld_friction=True,
    )
    reset = jax.jit(jax.vmap(env.reset), compiler_options=FAST_COMPILE)
    state = reset(jax.random.split(jax.random.key(0), 512))
    ld, info = np.asarray(state.ld_state), state.info
    names = env.ld_state_names
    theta, f = np.asarray(info["theta"]), np.asarray(info["friction"])
    # Min-max over the overridden ranges (the old hard-coded (theta - 0.25) / 0.25 clipped all
    # angles below 0.25 rad to 0).
    np.testing.assert_allclose(ld[:, names.index("theta")], (theta - 0.1) / 0.2, atol=1e-6)
    np.testing.assert_allclose(ld[:, names.index("friction")], (f - 0.2) / 0.4, atol=1e-6)
    for name in ("theta", "friction"):
        column = ld[:, names.index(name)]
        assert column.min() < 0.01 and column.max() > 0.99, name
    s, _ = jax.vmap(env.along_plank)(state.pipeline_state.qpos, state.pipeline_state.qvel, theta)
    np.testing.assert_allclose(
        ld[:, names.index("position")], np.asarray(s) / incline.POSITION_SCALE, atol=1e-6
    )
    np.testing.assert_allclose(ld[:, names.index("velocity")], 0.0, atol=1e-6)


def test_min_max_defaults_and_zero_width_range():
    # The default ranges reproduce the reference's constants; a zero-width range is 0, not NaN.
    np.testing.assert_allclose(incline.min_max(0.4, (0.25, 0.5)), (0.4 - 0.25) / 0.25, atol=1e-7)
    np.testing.assert_allclose(incline.min_max(0.3, (0.1, 0.5)), (0.3 - 0.1) / 0.4, atol=1e-7)
    np.testing.assert_allclose(incline.min_max(0.7, (0.1, 0.5)), 1.0)
    assert float(incline.min_max(0.0, (0.0, 0.0))) == 0.0
