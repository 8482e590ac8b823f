"""benchmarks/learner_determinism.py: a compiled step run again from the same state and keys
gives the same bits on XLA:CPU, so does the step compiled again in a new process of the script,
and the digests read the trained state."""

import pytest

from benchmarks import learner_determinism as ld

# The child compiles at XLA:CPU's default emitters (JAX_DISABLE_MOST_OPTIMIZATIONS reaches it,
# the older emitters do not): the module's own programs too, so that the two round alike.
pytestmark = [pytest.mark.xla_fusion_emitters]


def test_runs_in_this_process_and_in_a_new_one_give_the_same_bits_and_more_steps_others(
        monkeypatch):
    """The real child (this script with `--child`), compiled cheaply as this module's programs
    are (tests/conftest.py)."""
    monkeypatch.setenv("JAX_DISABLE_MOST_OPTIMIZATIONS", "true")
    found = ld.check("VAE_rpl", frames=2, dtype="float32", steps=2, processes=1)
    assert found["same"] and len(found["here"]) == 2 and len(found["processes"]) == 1
    further = ld.digests("VAE_rpl", frames=2, dtype="float32", steps=3, runs=1)
    assert further[0] != found["here"][0]  # the digest sees the trained parameters
