"""jaml.suite: the runs' test sets and analysis for an encoder of one's own."""

import json
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml import stream, suite
from jaml.cli import main
from jaml.stream import analysis

# The API's numbers and the analysis' own come from two programs: they agree to float rounding
# (3e-5 after the regressor's fit with the suite's faster-compiling emitters, tests/conftest.py;
# a different test set, key or target would part them by far more than RTOL).
# One of the default suite's longest modules: scheduled early (tests/conftest.py).
pytestmark = [pytest.mark.first]
RTOL = 1e-4


@pytest.fixture(scope="module")
def run():
    """A smoke-scale CartPole run at the end of its replay fill: (config, stream, state)."""
    config = suite.scaled(stream.for_env("CartPole", "VAE_rpl"), "smoke")
    s = stream.build(config)
    k_init = jax.random.split(jax.random.PRNGKey(config.seed), 3)[0]
    state, _ = stream.run_epochs(s, s.init(k_init), config.fill_epochs)
    return config, s, state


def test_the_apis_numbers_equal_the_streams_own_analysis(run):
    """The run's learner scored through `suite.evaluate` gets the report its analysis writes."""
    config, s, state = run
    _, k_eval, pi_rand_key = jax.random.split(jax.random.PRNGKey(config.seed), 3)
    own = analysis.evaluate(s, state, jax.random.fold_in(k_eval, int(state.epoch)), pi_rand_key)

    def encode(frames, actions):
        return s.learner.encode(state.learner.variables, frames, actions)

    api = suite.evaluate(encode, config, state, actions_seen=s.learner.config.actions_seen)
    assert set(api["errors"]) == set(own["errors"]) == {"pi_rand", "pi_curr", "validation"}
    for name in own["errors"]:
        np.testing.assert_allclose(api["errors"][name], own["errors"][name], rtol=RTOL,
                                   atol=1e-6)
    assert api["baseline"] == own["baseline"]
    np.testing.assert_allclose(api["distortion"], own["distortion"], rtol=RTOL)
    assert api["irregularity"] == pytest.approx(own["irregularity"], rel=RTOL)
    assert api["error_names"] == list(s.env.ld_state_names)


# ~130 s on two cores even with the fixture's programs (the whole run path: checkpoints,
# figures, the resumed loop): out of the default suite, which is over its time bound.
@pytest.mark.slow
def test_a_deadline_stops_between_analyses_with_a_checkpoint_and_the_run_resumes(
        run, tmp_path, monkeypatch):
    """`run_many(deadline=)` on the fixture's config (its programs compiled once): one-epoch
    blocks and a clock that passes the deadline after the first block's check."""
    from jaml.stream import run as run_lib

    config = run[0]
    monkeypatch.setattr(run_lib, "DEADLINE_BLOCK", 1)
    readings = iter([0.0])
    monkeypatch.setattr(run_lib, "_clock", lambda: next(readings, 100.0))
    stopped = run_lib.run(config, tmp_path, progress=False, deadline=10.0)
    assert stopped["status"] == "interrupted" and stopped["epoch"] == 1
    assert stopped["checkpoint_epoch"] == 1  # saved where it stopped, with no analysis there
    # A far deadline changes nothing: the run resumes from epoch 1 and finishes.
    monkeypatch.setattr(run_lib, "_clock", time.monotonic)
    resumed = run_lib.run(config, tmp_path, progress=False, deadline=time.monotonic() + 3600)
    assert resumed["status"] == "finished" and resumed["resumed_from"] == 1
    lines = (tmp_path / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(x)["epoch"] for x in lines] == list(range(1, config.epochs + 1))
    steps = [json.loads(x)["step"] for x in (tmp_path / "history.jsonl").read_text().splitlines()]
    assert sorted(set(steps)) == [2, 4]


def test_test_sets_are_the_sequences_and_targets_a_run_builds(run):
    config, s, state = run
    sets = suite.test_sets(config, state)
    assert set(sets) == {"train", "pi_rand", "pi_curr"}
    rand = sets["pi_rand"]
    assert rand.frames.shape == (config.eval.rand, s.seq_len, 64, 64, 3)
    assert rand.frames.dtype == np.uint8 and rand.frames.std() > 0
    np.testing.assert_array_equal(rand.states, rand.ld[:, s.hist - 1])
    assert rand.names == tuple(s.env.ld_state_names)
    # π_rand is a function of the run's key alone: the same sequences again.
    again = suite.test_sets(config, state)["pi_rand"]
    np.testing.assert_array_equal(again.frames, rand.frames)


def test_linear_probe_recovers_an_affine_encoding_exactly():
    rng = np.random.default_rng(0)
    states = rng.normal(size=(200, 3))
    mix = rng.normal(size=(3, 5))
    latents = states @ mix + 2.0
    out = suite.linear_probe(latents[:150], states[:150], {"test": (latents[150:], states[150:])})
    np.testing.assert_allclose(out["r2"]["test"], 1.0, atol=1e-9)
    np.testing.assert_allclose(out["errors"]["test"], 0.0, atol=1e-8)
    noise = suite.linear_probe(rng.normal(size=(150, 5)), states[:150],
                               {"test": (rng.normal(size=(50, 5)), states[150:])})
    assert max(noise["r2"]["test"]) < 0.3


def test_readme_encoder_snippet_runs_as_written(run):
    """README's 'your encoder' snippet, as written (its own smoke run, filled inside `suite`):
    in this module, whose `run` has the snippet's config, so its programs are compiled once."""
    from tests.test_readme import snippet

    namespace = {}
    exec(compile(snippet("encoder"), "README:encoder", "exec"), namespace)
    report, sets = namespace["report"], namespace["sets"]
    assert namespace["config"] == run[0]  # the fixture's config: the programs it compiled
    assert set(sets) == {"train", "pi_rand", "pi_curr"}
    assert len(report["errors"]["pi_rand"]) == len(report["error_names"]) == 4
    assert np.all(np.isfinite(report["errors"]["pi_rand"]))
    assert np.isfinite(report["distortion"])
    assert set(report["linear"]["r2"]) == {"pi_rand", "pi_curr"}


def test_own_learner_trains_on_the_stream_with_every_analysis(tmp_path, capsys):
    """`jaml suite --learner MODULE:FACTORY` (tests/stream/test_own_learner.py's TinyAE), every
    analysis. Here, after the fixture's run: the env's acting and test-set programs are the same
    ones, read from the run's XLA cache instead of compiled again."""
    out = tmp_path / "own"
    spec = "tests.stream.test_own_learner:make_tiny"
    assert main(["suite", "--env", "CartPole", "--learner", spec, "--scale", "smoke",
                 "--no-progress", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "finished" and summary["epoch"] == 4
    history = [json.loads(line) for line in (out / "history.jsonl").read_text().splitlines()]
    assert sorted({r["step"] for r in history}) == [2, 4]  # replay full, then the end
    assert {r["test_set"] for r in history} == {"pi_rand", "pi_curr"}
    metrics = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    trained = [m for m in metrics if m["learner/training"] == 1.0]
    assert trained and all(jnp.isfinite(m["learner/loss"]) for m in trained)
    assert (out / "alignment.png").is_file() and (out / "recon" / "epoch_000004.png").is_file()
    assert f"CartPole {spec} (ppo): finished at epoch 4" in capsys.readouterr().out
