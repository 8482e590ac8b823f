"""Sources from the MJX incline domains: contract, determinism, episode ends, frictionless physics.

Three rollout programs compile here (geom and mesh `sample`, a frictionless geom `rollout`),
each once per module through fixtures, at XLA's lowest optimisation level (compile time
dominates)."""

import jax
import numpy as np
import pytest

from envs_mjx.domains import incline
from jaml import cli, sources
from jaml.sources import incline_env
from tests.envs_mjx.rollout_harness import FAST_COMPILE

# One of the default suite's longest modules: scheduled early (tests/conftest.py).
pytestmark = pytest.mark.first

N = 512
NAMES = ("theta", "s0", "v0", "a0", "s1", "v1")


# The mesh preset draws through the same sampler as the geom one with another scene (its own
# ~21 s compile): slow; tests/envs_mjx/test_mesh_incline.py and test_domains.py cover the scene.
@pytest.fixture(scope="module", params=["geom-on-incline",
                                        pytest.param("mesh-on-incline", marks=pytest.mark.slow)])
def drawn(request):
    """(source, [rows(key 0), rows(key 0), rows(key 1)])."""
    src = sources.make(request.param)
    sample = jax.jit(src.sample, static_argnums=1, compiler_options=FAST_COMPILE)
    return src, [np.asarray(sample(jax.random.key(k), N)) for k in (0, 0, 1)]


@pytest.fixture(scope="module")
def frictionless():
    """A rollout [T, E] on a frictionless plank (μ = 0) under zero actions, and its source."""
    src = sources.make("geom-on-incline", friction_range=(0.0, 0.0), action_range=(0.0, 0.0))
    rollout = jax.jit(src.rollout, static_argnums=1, compiler_options=FAST_COMPILE)
    rows, valid = rollout(jax.random.key(0), 32)
    return src, np.asarray(rows), np.asarray(valid)


def _metres(src, rows):
    """θ (rad), s0, v0, a0, s1, v1 (m, m/s) from normalised rows [..., 6]."""
    lo, hi = src.env.config.theta_range
    th, s0, v0, a0, s1, v1 = np.moveaxis(rows.astype(np.float64), -1, 0)
    p, v = incline.POSITION_SCALE, incline.VELOCITY_SCALE
    return lo + th * (hi - lo), s0 * p, v0 * v, a0, s1 * p, v1 * v


def test_contract(drawn):
    src, (rows, _, _) = drawn
    assert src.dim_names == NAMES and src.name in sources.PRESETS
    assert src.pool_size is not None and src.pool_size >= 100_000
    assert rows.shape == (N, 6) and rows.dtype == np.float32
    assert np.isfinite(rows).all()
    th, s0, v0, a0, s1, v1 = rows.T
    assert th.min() >= 0 and th.max() <= 1 and np.ptp(th) > 0.5
    # drop_clipped (the default): no position or velocity at its clip bound.
    for s in (s0, s1):
        assert s.min() > 0 and s.max() < 1
    for v in (v0, v1):
        assert np.abs(v).max() < 1
    assert a0.min() < -0.9 and a0.max() > 0.9 and np.abs(a0).max() <= 1
    assert len(np.unique(rows, axis=0)) == N  # no shortfall: every row drawn once


def test_same_key_same_rows(drawn):
    _, (rows, again, other) = drawn
    np.testing.assert_array_equal(rows, again)
    assert np.abs(rows - other).max() > 0.1


def test_rows_are_steps_within_one_episode(drawn):
    """Every row is one env step of one episode: position changes as the mean velocity times
    dt (a row spanning a reset would jump by tens of cm; tolerance 2 cm, the trapezoid rule's
    error under friction and pushes, measured ≤ 1.2 cm over 16K rows), and, for the block, whose
    extent is known (mesh objects differ per reset), no step that ended the episode: the object
    never ends past the termination boundary world x = 1 or x = 0."""
    src, (rows, _, _) = drawn
    theta, s0, v0, _, s1, v1 = _metres(src, rows)
    np.testing.assert_allclose(s1 - s0, (v0 + v1) / 2 * src.dt, atol=0.02)
    if src.env_name == "GeomOnIncline":
        height = src.env._half_height - incline.RESET_SINK
        x1 = s1 * np.cos(theta) + height * np.sin(theta)  # world x of the object after the step
        assert x1.max() < 1.0 and x1.min() > 0.0


def test_dropped_rows_are_the_episode_ends(frictionless):
    """A kept row's next state starts the next row of the same env; a dropped row is either
    followed by a fresh reset (at rest, position in start_range) or at a clip bound."""
    src, rows, valid = frictionless
    assert 0.8 < valid.mean() < 1.0  # some episodes ended; most steps give rows
    now, nxt = rows[:-1], rows[1:]
    kept = valid[:-1]
    np.testing.assert_array_equal(nxt[kept][:, [0, 1, 2]], now[kept][:, [0, 4, 5]])
    dropped_now, dropped_next = now[~kept], nxt[~kept]
    lo, hi = src.env.config.start_range
    start = dropped_next[:, 1] * incline.POSITION_SCALE
    reset = (dropped_next[:, 2] == 0) & (start >= lo - 1e-6) & (start <= hi + 1e-6)
    clipped = (np.abs(dropped_now[:, [2, 5]]) >= 1).any(1) | (dropped_now[:, [1, 4]] >= 1).any(1)
    assert (reset | clipped).all()
    assert reset.sum() > 10


def test_frictionless_rows_follow_the_closed_form(frictionless):
    """μ = 0 and zero actions: s1 − s0 = v0 dt + ½ g sinθ dt², v1 − v0 = g sinθ dt.

    Tolerance: MuJoCo's semi-implicit Euler over N = 8 substeps travels ½ g sinθ dt² / N
    farther than the exact flow (≤ 0.47 mm at θ = 0.5); beyond that 10 µm (float32; measured
    0.2 µm). Velocity is exact for constant acceleration: 10 µm/s (measured 1.2 µm/s)."""
    src, rows, valid = frictionless
    theta, s0, v0, a0, s1, v1 = _metres(src, rows[valid])
    assert len(theta) > 500 and (a0 == 0).all()
    g = -float(src.env.mj_model.opt.gravity[2])
    dt, substeps = src.dt, src.env.n_frames
    accel = g * np.sin(theta)
    euler = 0.5 * accel * dt**2 / substeps
    ds_error = s1 - s0 - (v0 * dt + 0.5 * accel * dt**2)
    assert (np.abs(ds_error) <= euler + 1e-5).all(), np.abs(ds_error).max()
    np.testing.assert_allclose(ds_error, euler, atol=1e-5)
    np.testing.assert_allclose(v1 - v0, accel * dt, atol=1e-5)


def test_pick_valid_takes_only_valid_rows_and_covers_a_shortfall():
    rows = np.arange(20, dtype=np.float32)[:, None] * np.ones((1, 3), np.float32)
    valid = np.arange(20) % 4 != 0  # 15 valid rows
    key = jax.random.key(0)
    picked = np.asarray(incline_env.pick_valid(key, rows, valid, 10))
    assert set(picked[:, 0]) <= set(rows[valid, 0]) and len(set(picked[:, 0])) == 10
    np.testing.assert_array_equal(picked, np.asarray(incline_env.pick_valid(key, rows, valid, 10)))
    # 20 asked, 15 valid: every valid row once, 5 repeated, none invalid.
    picked = np.asarray(incline_env.pick_valid(key, rows, valid, 20))[:, 0]
    assert set(picked) == set(rows[valid, 0]) and len(picked) == 20
    assert np.isnan(np.asarray(incline_env.pick_valid(key, rows, valid & False, 4))).all()


def test_overrides_and_pool():
    src = sources.make("mesh-on-incline", theta_range=(0.3, 0.4), pool_size=N, rollout_steps=16)
    assert src.env.config.theta_range == (0.3, 0.4)
    assert src.pool_size == N and src.rollout_steps == 16
    assert src.env.config.pixels == "off"
    with pytest.raises(ValueError, match="unknown config overrides"):
        sources.make("geom-on-incline", gravity=1.0)
    with pytest.raises(ValueError, match="action_range"):
        sources.make("geom-on-incline", action_range=(-2.0, 2.0))
    args = cli.parse(
        ["relations", "--source", "geom-on-incline", "--source-opt", "pool_size=4096", "--out", "x"]
    )
    assert args.command.source == "geom-on-incline"
    assert cli.key_values(args.command.source_opt) == {"pool_size": 4096}


def test_reference_units_are_the_released_codes_rows_of_the_same_steps(drawn):
    """units="reference" (docs/reference/fig9.md §4) on the same key: the same steps (same picks),
    θ as is, unsigned speed, the force in N, and the distance from the episode's start, which
    lies in the reset range U(0.05, 0.15) m: s_env − s_ref is that start (or s_env + s_ref for
    an object pushed uphill past it)."""
    src, (rows, *_) = drawn
    if src.name != "geom-on-incline":
        pytest.skip("one scene is enough")
    ref = sources.make("geom-on-incline", units="reference")
    sample = jax.jit(ref.sample, static_argnums=1, compiler_options=FAST_COMPILE)
    got = np.asarray(sample(jax.random.key(0), N)).astype(np.float64)
    rows = rows.astype(np.float64)
    np.testing.assert_array_equal(got[:, 0], rows[:, 0])
    # Two compiled programs of the same physics: equal to float32 rounding (1.4e-6 was seen).
    np.testing.assert_allclose(got[:, [2, 5]], np.abs(rows[:, [2, 5]]), atol=1e-5)
    np.testing.assert_allclose(got[:, 3], 2.0 * rows[:, 3], rtol=1e-6)
    lo, hi = (x / incline.POSITION_SCALE for x in src.env.config.start_range)
    for s_env, s_ref in ((rows[:, 1], got[:, 1]), (rows[:, 4], got[:, 4])):
        start = np.where(s_env - s_ref >= lo - 1e-5, s_env - s_ref, s_env + s_ref)
        assert np.all((start >= lo - 1e-5) & (start <= hi + 1e-5))
    assert (got[:, [1, 2, 4, 5]] >= 0).all() and np.abs(got[:, 3]).max() > 1.0
    with pytest.raises(ValueError, match="units"):
        sources.make("geom-on-incline", units="si")
