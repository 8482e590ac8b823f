"""benchmarks/learner_determinism.py: the digests read the trained state, a compiled step run
again from the same state and keys gives the same bits (XLA:CPU), and a new process of the
script gives its run's digest back."""

import pytest

from benchmarks import learner_determinism as ld

# The child compiles at XLA:CPU's default emitters (JAX_DISABLE_MOST_OPTIMIZATIONS reaches it,
# the older emitters do not): the module's own programs too, so that the two round alike.
pytestmark = [pytest.mark.xla_fusion_emitters]


def test_the_same_steps_give_the_same_digest_and_more_steps_another(capsys):
    same = ld.digests("VAE_rpl", frames=2, dtype="float32", steps=2)
    assert len(same) == 2 and same[0] == same[1]
    further = ld.digests("VAE_rpl", frames=2, dtype="float32", steps=3, runs=1)
    assert further[0] != same[0]  # the digest sees the trained parameters
    ld.main(["--child", "--learners", "VAE_rpl", "--frames", "2", "--dtype", "float32",
             "--steps", "2"])
    assert capsys.readouterr().out.strip() == f'{{"VAE_rpl": ["{same[0]}"]}}'


def test_a_new_process_compiles_the_step_again_and_gives_the_same_bits_on_the_cpu(monkeypatch):
    """The real child (this script with `--child`), compiled cheaply as this module's programs
    are (tests/conftest.py): XLA:CPU's step has no run-to-run variation to find."""
    monkeypatch.setenv("JAX_DISABLE_MOST_OPTIMIZATIONS", "true")
    found = ld.check("VAE_rpl", frames=2, dtype="float32", steps=2, processes=1)
    assert found["same"] and len(found["here"]) == 2 and len(found["processes"]) == 1
