"""jaml.suite: the runs' test sets and analysis for an encoder of one's own."""

import contextlib
import hashlib
import io
import json
import re
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaml import evaluation, stream, suite
from jaml.cli import main
from jaml.evaluation import alignment
from jaml.stream import analysis
from jaml.stream import replay as replay_lib
from tests.conftest import xla_optimized

# The API's numbers and the analysis' own come from two programs: they agree to float rounding
# (3e-5 after the regressor's fit with the suite's faster-compiling emitters, tests/conftest.py;
# a different test set, key or target would part them by far more than RTOL).
# One of the default suite's longest modules: scheduled early (tests/conftest.py).
pytestmark = [pytest.mark.first]
RTOL = 1e-4


@pytest.fixture(autouse=True, scope="module")
def _fast_compiling_prng():
    with jax.threefry_partitionable(False):  # see tests/learners/conftest.py
        yield


@pytest.fixture(scope="module")
def run():
    """A smoke-scale CartPole run at the end of its replay fill: (config, stream, state)."""
    config = suite.scaled(stream.for_env("CartPole", "VAE_rpl"), "smoke")
    s = stream.build(config)
    k_init = jax.random.split(jax.random.PRNGKey(config.seed), 3)[0]
    state, _ = stream.run_epochs(s, s.init(k_init), s.config.fill_epochs)
    return config, s, state


@pytest.fixture(scope="module")
def reports(run):
    """(the run's analysis with its reference rows, the run's learner scored through
    `suite.evaluate`): the two tests below read their own parts of one pair."""
    config, s, state = run
    _, k_eval, pi_rand_key = jax.random.split(jax.random.PRNGKey(config.seed), 3)
    own = analysis.evaluate(s, state, jax.random.fold_in(k_eval, int(state.epoch)), pi_rand_key,
                            references=True)

    def encode(frames, actions):
        return s.learner.encode(state.learner.variables, frames, actions)

    said = io.StringIO()
    with contextlib.redirect_stderr(said):
        api = suite.evaluate(encode, config, state, actions_seen=s.learner.config.actions_seen,
                             stream=s)
    return own, api | {"stderr": said.getvalue()}


def test_the_apis_numbers_equal_the_streams_own_analysis(run, reports):
    """The run's learner scored through `suite.evaluate` gets the report its analysis writes."""
    _, s, _ = run
    own, api = reports
    keys = ["pi_rand", "pi_curr", "validation"]  # every row of the report: these, in order
    assert list(api["errors"]) == list(own["errors"]) == list(api["baseline"]) == keys
    assert list(api["linear"]["errors"]) == list(api["linear"]["r2"]) == keys
    for name in own["errors"]:
        np.testing.assert_allclose(api["errors"][name], own["errors"][name], rtol=RTOL,
                                   atol=1e-6)
    assert api["baseline"] == own["baseline"]
    np.testing.assert_allclose(api["distortion"], own["distortion"], rtol=RTOL)
    assert api["distortion_trimmed"]["left_out"] == own["distortion_trimmed"]["left_out"]
    assert api["irregularity"] == pytest.approx(own["irregularity"], rel=RTOL)
    assert api["error_names"] == list(s.env.ld_state_names)
    assert api["validation_split"] == own["validation_split"] == "slots"
    assert api["scale"] == "smoke" and api["note"] == suite.SMOKE_NOTE
    # Its phases, one line each on stderr (the state given: no replay to fill).
    phases = [re.sub(r"\d+ chunks", "N chunks", line.split("] ", 1)[1])
              for line in api["stderr"].splitlines()]
    assert phases == ["building the stream", "drawing the test sets (train, pi_rand, pi_curr)",
                      "encoding N chunks", "fitting the alignment regressor",
                      "the reference rows (true state, pixels' PCA, a random projection)",
                      "done"], api["stderr"]


def test_the_reference_rows_are_the_runs_own_and_the_floor_is_below_the_ceiling(reports):
    """`suite.evaluate`'s reference rows equal those the stream's analysis computes on its own
    sets (`analysis.evaluate(references=True)`), share the report's keys, and the true state
    (the floor) scores below the constant predictor (the ceiling) on every set (the rows do not
    read `actions_seen`, which only the distortion does)."""
    own, api = (report["references"] for report in reports)
    assert list(api) == ["constant", "true_state", "pca", "random_projection"] == list(own)
    for row, by_set in own.items():
        assert list(api[row]) == ["pi_rand", "pi_curr", "validation"]
        for name, values in by_set.items():
            np.testing.assert_allclose(api[row][name], values, rtol=RTOL, atol=1e-6,
                                       err_msg=f"{row} {name}")
    for name in ("pi_rand", "pi_curr", "validation"):
        assert np.mean(api["true_state"][name]) < np.mean(api["constant"][name]), name


def _frame_hash(frames) -> np.ndarray:
    """float32 [N, 8]: eight bytes of SHA-256 of each frame, over 255: no state information a
    regressor can use beyond telling equal frames apart."""
    return np.asarray([np.frombuffer(hashlib.sha256(f.tobytes()).digest()[:8], np.uint8)
                       for f in np.asarray(frames)], np.float32) / 255.0


def test_held_out_rows_share_no_column_and_a_frame_hash_no_longer_beats_the_constant(run):
    """The suite's training set: its leading 30 % (the regressor's held-out rows) and the rest
    come from different replay columns. A frame-hash encoder on 256 rows of the smoke replay
    (64 distinct frames), fit 2,000 steps: drawn by slot its validation error is the constant's
    level; drawn as the reference draws them (leading rows of one draw, which repeat the fit
    rows' frames) it is far below, the leak this split removes."""
    config, s, state = run
    train = suite.test_sets(config, state, stream=s)["train"]
    held = alignment.RegressorConfig().split(len(train.states))
    columns = [{tuple(np.round(row.ravel(), 6)) for row in part}
               for part in (train.ld[:held], train.ld[held:])]
    assert held > 0 and not columns[0] & columns[1]
    rows = 256
    n_val = alignment.RegressorConfig().split(rows)
    key = jax.random.PRNGKey(1)
    ratios = {}
    for split in ("slots", "leading"):
        if split == "slots":
            seqs = replay_lib.sample_split(state.replay, key, jnp.arange(rows) < n_val,
                                           s.seq_len, 0.3)
        else:
            seqs = replay_lib.sample(state.replay, key, rows, s.seq_len)
        latents = _frame_hash(seqs.frames[:, s.hist - 1])
        states = np.asarray(seqs.ld[:, s.hist - 1])
        with xla_optimized():  # the module's cheap codegen runs 2,000 steps several times slower
            errors = evaluation.alignment_errors(latents, states,
                                                 {"t": (latents[:8], states[:8])},
                                                 num_iterations=2000)
        constant = evaluation.constant_errors(states, {"v": states[:n_val]})["v"]
        ratios[split] = float(np.mean(np.asarray(errors["validation"]) / constant))
    assert ratios["slots"] > 0.9 and ratios["leading"] < 0.7, ratios


def test_evaluate_checks_its_config_and_the_encoders_output_before_filling_the_replay(
        run, monkeypatch):
    """Wrong input is refused by one-line errors naming the output's shape and the fix, before
    the replay is filled (`_prepare` is not reached)."""
    config, s, _ = run

    def never(*args):
        raise AssertionError("reached the expensive part")

    monkeypatch.setattr(suite, "_prepare", never)
    with pytest.raises(TypeError, match=r"config must be a jaml\.stream\.StreamConfig, got a dict"):
        suite.evaluate(lambda f, a: f, config.to_dict())
    e = config.num_envs
    cases = [
        (lambda f, a: jnp.zeros((len(f), f.shape[1], 3)),
         rf"encode returned shape \({e}, 1, 3\).*\[E, Z\] = \[{e}, Z\] \(e.g. reshape"),
        (lambda f, a: jnp.zeros((3, 4)), rf"shape \(3, 4\).*of {e} sequences"),
        (lambda f, a: jnp.full((len(f), 4), jnp.nan), r"2?\d+ NaN or inf .*shape \(\d+, 4\)"),
        (lambda f, a: jnp.zeros((len(f), 4), bool), r"dtype bool .*return numbers"),
        (lambda f, a: {"z": f}, r"encode returned a dict"),
    ]
    for encode, message in cases:
        with pytest.raises(ValueError, match=message) as caught:
            suite.evaluate(encode, config, stream=s)
        assert "\n" not in str(caught.value)


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
    sets = suite.test_sets(config, state, stream=s)
    assert set(sets) == {"train", "pi_rand", "pi_curr"}
    rand = sets["pi_rand"]
    assert rand.frames.shape == (config.eval.rand, s.seq_len, 64, 64, 3)
    assert rand.frames.dtype == np.uint8 and rand.frames.std() > 0
    np.testing.assert_array_equal(rand.states, rand.ld[:, s.hist - 1])
    assert rand.names == tuple(s.env.ld_state_names)
    # π_rand is a function of the run's key alone: the same sequences again.
    again = suite.test_sets(config, state, stream=s)["pi_rand"]
    np.testing.assert_array_equal(again.frames, rand.frames)
    # The Stream passed must be the config's (the seed aside).
    with pytest.raises(ValueError, match="stream was not built from this config"):
        suite.test_sets(config.with_overrides({"learner_steps": 3}), state, stream=s)


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


def _run_encoder_snippet(scale: str | None = None) -> dict:
    """README's 'your encoder' snippet executed (its own run, filled inside `suite`), at
    `scale` in place of the one it names; its namespace."""
    from tests.test_readme import snippet

    code = snippet("encoder")
    assert '"small")' in code
    if scale is not None:
        code = code.replace('"small")', f'"{scale}")', 1)
    namespace = {}
    exec(compile(code, "README:encoder", "exec"), namespace)
    return namespace


def _check_snippet(namespace: dict, printed: str) -> None:
    report = namespace["report"]
    assert len(report["errors"]["pi_rand"]) == len(report["error_names"]) == 4
    assert np.all(np.isfinite(report["errors"]["pi_rand"]))
    assert set(report["linear"]["r2"]) == {"pi_rand", "pi_curr", "validation"}
    lines = printed.strip().splitlines()
    assert [line.split(":")[0] for line in lines] == report["error_names"]
    assert all("(true state " in line and ", constant " in line for line in lines)


def test_readme_encoder_snippet_runs_at_the_smoke_scale(run, capsys, monkeypatch):
    """README's snippet with "smoke" for its "small" (the fixture's config: `suite.evaluate`
    gets the fixture's Stream, built from an equal config, whose programs are traced and
    compiled once in this module; the snippet's run still fills its own replay); as written, at
    "small", it is the slow test below."""
    config, s, _ = run
    built = []

    def build(c):
        assert c == config, "the snippet's config is the fixture's"
        built.append(c)
        return s

    monkeypatch.setattr(suite, "build", build)
    namespace = _run_encoder_snippet("smoke")
    assert namespace["config"] == config and built == [config]
    _check_snippet(namespace, capsys.readouterr().out)


# Minutes on two cores: the small scale's fill, sets and four regressor fits.
@pytest.mark.slow
def test_readme_encoder_snippet_runs_as_written_and_ranks_encoders(capsys):
    """As written, at "small": the snippet runs, and the report orders a true state, the pixels'
    PCA and a frame-hash encoder (no information) on π_rand and validation (docs/usage.md,
    "Small runs", for three seeds)."""
    namespace = _run_encoder_snippet()
    _check_snippet(namespace, capsys.readouterr().out)
    config = namespace["config"]
    assert suite.scale_of(config) == "small" and "note" not in namespace["report"]
    noise = suite.evaluate(lambda frames, actions: _frame_hash(frames[:, -1]), config)
    refs = noise["references"]
    for name in ("pi_rand", "validation"):
        level = np.asarray(refs["constant"][name])

        def rel(errors, level=level):
            return float(np.mean(np.asarray(errors) / level))

        truth, pca = rel(refs["true_state"][name]), rel(refs["pca"][name])
        assert truth < 0.5 and truth < pca < rel(noise["errors"][name]), name


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
    printed = capsys.readouterr().out
    assert f"CartPole {spec} (ppo): finished at epoch 4" in printed
    # The reference rows of the first analysis under each test set's errors, and the smoke
    # scale's note, on screen and in the summary.
    refs = summary["references"]
    assert refs["epoch"] == 2 and refs["validation_split"] == "slots"
    assert list(refs)[2:] == ["constant", "true_state", "pca", "random_projection"]
    for row in ("constant", "true_state", "pca", "random_projection"):
        assert printed.count(f"    {row} (epoch 2): theta=") == 3  # π_rand, π_curr, validation
    assert "  validation (slots split): theta=" in printed
    assert summary["scale"] == "smoke" and summary["note"] == suite.SMOKE_NOTE
    assert printed.rstrip().endswith(f"note: {suite.SMOKE_NOTE}")


def test_the_small_scale_is_a_named_scale_of_the_command_line():
    """`jaml suite --scale small` gets `SCALES["small"]`; `scale_of` names a config's scale by
    its set sizes (the smoke scale's note hangs on it) and no other config."""
    from jaml import cli

    parsed = cli.parse(["suite", "--env", "CartPole", "--learner", "VAE_rpl", "--out", "x",
                        "--scale", "small"]).command.stream_config()
    config = suite.scaled(stream.for_env("CartPole", "VAE_rpl"), "small")
    assert parsed == config
    assert (config.num_envs, config.replay.slots, config.eval.train, config.eval.rand,
            config.eval.regressor_iterations) == (16, 64, 1024, 1024, 2000)
    assert suite.scale_of(config) == "small"
    assert suite.scale_of(config.with_overrides({"epochs": 20})) == "small"  # not a set size
    assert suite.scale_of(config.with_overrides({"eval.train": 512})) is None
    assert suite.scale_of(stream.for_env("CartPole", "VAE_rpl")) is None
    assert suite.scale_of(suite.scaled(stream.for_env("Ant", "PRED"), "smoke")) == "smoke"
