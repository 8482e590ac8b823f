"""Learner-test setup: cheaper-to-compile random bits for the tests in this folder only."""

import jax
import pytest


@pytest.fixture(autouse=True, scope="package")
def _fast_compiling_prng():
    # On CPU, XLA takes seconds to compile each partitionable-threefry draw (every initializer
    # and reparameterised sample); the classic threefry compiles ~8× faster. Scoped to this
    # package so other tests keep the default bit streams.
    with jax.threefry_partitionable(False):
        yield
