"""Stacked analysis: R runs analysed by one `evaluate_runs` call must each get what `evaluate`
gives that run alone (the same keys: the same replay rows, rollouts and regressor fit).

The regressor check runs by default (≈ 45 s on 2 shared cores, mostly compilation). The whole
analysis compiles the env and renderer three times (the epoch that fills the replays, one run's
rollouts, the vmapped rollouts): ≈ 10 min on 2 cores shared with other jobs, so it is slow.
"""

import jax
import numpy as np
import pytest

from jaml import stream
from jaml.evaluation import alignment
from jaml.stream import analysis
from tests.stream.test_loop import tiny

SEEDS = (0, 1)


@pytest.fixture(autouse=True, scope="module")
def _fast_compiling_prng():
    with jax.threefry_partitionable(False):  # see tests/learners/conftest.py
        yield


def small():
    """VAE_v0 (no kept slots) with narrow convolutions; 8 replay slots fill in one epoch."""
    narrow = {"conv_filters": (8, 8, 8, 8), "conv_features": 16, "deconv_filters": (8, 8, 8, 8)}
    return tiny(learner="VAE_v0", replay_slots=8, learner_steps=1, learner_overrides=narrow)


@pytest.mark.parametrize("normalize", [True, False])
def test_stacked_regressor_fits_match_each_fit_alone(normalize):
    rng = np.random.default_rng(0)
    R, N, Z, D = 3, 40, 5, 2
    x, y = rng.normal(size=(R, N, Z)), rng.normal(size=(R, N, D)) * [1.0, 3.0]
    tests = {"a": (rng.normal(size=(R, 16, Z)), rng.normal(size=(R, 16, D)))}
    seeds = [3, 11, 2**31 - 2]
    # batch 8 < 28 fit rows: random minibatches (the paper-size path), dropout on.
    options = dict(num_iterations=50, batch_size=8, normalize=normalize)
    together = alignment.alignment_errors_runs(x, y, tests, seeds, **options)
    for r, seed in enumerate(seeds):
        alone = alignment.alignment_errors(x[r], y[r], {"a": (tests["a"][0][r], tests["a"][1][r])},
                                           seed, **options)
        assert list(together) == list(alone)  # the same order: run records follow it
        for k in alone:
            # The same keys and rows; only rounding differs (normalisation stats on the device
            # rather than the host, batched rather than single matmuls): ~1e-7 relative per step,
            # grown by 50 Adam steps to well under 1e-5 of errors of order 1.
            np.testing.assert_allclose(together[k][r], alone[k], rtol=1e-5, atol=1e-6, err_msg=k)


@pytest.mark.slow
def test_stacked_runs_analysed_at_once_match_each_run_alone():
    s = stream.build(small())
    states = stream.stack_runs([s.init(jax.random.PRNGKey(seed)) for seed in SEEDS])
    states, _ = stream.run_stacked_epochs(s, states, 1)  # fills the replays, one PPO update
    keys = [jax.random.PRNGKey(10 + seed) for seed in SEEDS]
    pi_rand_keys = [jax.random.PRNGKey(20 + seed) for seed in SEEDS]
    together = analysis.evaluate_runs(s, states, jax.numpy.stack(keys),
                                      jax.numpy.stack(pi_rand_keys))
    assert len(together) == len(SEEDS)
    for r, state in enumerate(stream.unstack_runs(states)):
        alone = analysis.evaluate(s, state, keys[r], pi_rand_keys[r])
        assert list(together[r]["errors"]) == list(alone["errors"]) == [
            "pi_rand", "pi_curr", "validation"]
        # The same keys give the same replay rows and rollouts (vmapping the physics, renderer
        # and policy does not change them beyond rounding), each run's encoder is applied alone
        # (the same convolutions), and the regressor fits agree to ~1e-6 (the test above):
        # errors and distortion agree to 1e-4 relative, far below the seeds' differences.
        for k, v in alone["errors"].items():
            np.testing.assert_allclose(together[r]["errors"][k], v, rtol=1e-4, atol=1e-6,
                                       err_msg=k)
        np.testing.assert_allclose(together[r]["distortion"], alone["distortion"], rtol=1e-4)
    assert together[0]["errors"]["pi_rand"] != together[1]["errors"]["pi_rand"]
