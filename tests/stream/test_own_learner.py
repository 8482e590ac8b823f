"""Your own learner on the suite's stream: `jaml suite --learner MODULE:FACTORY` (its whole run
is in tests/test_suite_api.py, which compiles the same env programs first)."""


import flax.linen as nn
import jax.numpy as jnp
import pytest

from jaml.cli import main, parse
from jaml.configs.stream import for_env
from jaml.learners import Learner, Outputs, SingleFrameConfig


class TinyAE(nn.Module):
    """A deterministic autoencoder on 8×8-pooled frames: the protocol's smallest member."""

    latent: int

    def setup(self):
        self.enc = nn.Dense(self.latent)
        self.norm = nn.BatchNorm()  # the stream's train step keeps batch statistics
        self.dec = nn.Dense(64 * 64 * 3)

    def _z(self, x, train: bool):
        pooled = nn.avg_pool(x[:, -1], (8, 8), (8, 8)).reshape(len(x), -1)
        return self.enc(self.norm(pooled, use_running_average=not train))

    def _decode(self, z):
        return nn.sigmoid(self.dec(z)).reshape(len(z), 1, 64, 64, 3)

    def __call__(self, x, a, key, train: bool = True):
        z = self._z(x, train)
        return Outputs(recon=self._decode(z), kl={"kl": jnp.zeros(len(x))}, z=z[:, None])

    def encode(self, x, a):
        return self._z(x, False)

    def reconstruct(self, x, a):
        return self._decode(self._z(x, False))


def make_tiny(ld_dim: int, latent_dim: int = 6, **overrides) -> Learner:
    """The factory `--learner tests.stream.test_own_learner:make_tiny` names."""
    config = SingleFrameConfig(ld_dim=ld_dim, latent_dim=latent_dim, learning_rate=1e-3,
                               **overrides)
    return Learner("TinyAE", config, TinyAE(latent_dim), kl_weights={"kl": 0.0})


def test_a_factory_that_cannot_be_imported_is_one_line(tmp_path, capsys):
    assert main(["suite", "--env", "CartPole", "--learner", "no_such_pkg:make", "--out",
                 str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot import make from no_such_pkg" in err[0]


def test_a_factory_learner_takes_the_envs_typed_options_and_the_envs_settings(capsys):
    """`--learner MODULE:FACTORY` keeps the env's typed options (env-config) in the help and
    the parse, and the env's family settings (Ant's rollout and PPO network), at the scale."""
    spec = "tests.stream.test_own_learner:make_tiny"
    with pytest.raises(SystemExit):
        main(["suite", "--env", "RearrangeGeom", "--learner", spec, "--help"])
    out = " ".join(capsys.readouterr().out.replace("│", " ").split())
    assert "--env-config.arm {" in out and "--learner-config." not in out
    config = parse(["suite", "--env", "RearrangeGeom", "--learner", spec, "--out", "x",
                    "--env-config.arm", "franka", "--scale", "smoke", "--replay.slots", "32"]
                   ).command.stream_config()
    assert config.env_config.arm == "franka" and config.learner_config is None
    assert (config.num_envs, config.replay.slots) == (8, 32)
    ant = parse(["suite", "--env", "Ant", "--learner", spec, "--out", "x"]).command
    assert ant.stream_config() == for_env("Ant", spec)
    assert (ant.stream_config().rollout_len, ant.stream_config().ppo.hidden) == (64, (256, 256))


def not_a_learner(ld_dim: int):
    return {"ld_dim": ld_dim}


def test_a_factory_must_return_a_learner():
    from jaml import learners

    with pytest.raises(ValueError, match=r"returned a dict, not a jaml\.learners\.Learner"):
        learners.make(f"{__name__}:not_a_learner", ld_dim=4)


def test_a_learner_of_your_own_is_made_from_ld_dim_alone():
    """Its factory makes its config: `learners.make` refuses one, or other options, for it."""
    from jaml import learners

    assert learners.make(f"{__name__}:make_tiny", ld_dim=4).config.ld_dim == 4
    for config, options in ((SingleFrameConfig(ld_dim=4), {"ld_dim": 4}), (None, {}),
                            (None, {"ld_dim": 4, "latent_dim": 3})):
        with pytest.raises(ValueError, match=r"makes its own config from ld_dim alone"):
            learners.make(f"{__name__}:make_tiny", config, **options)


def test_the_docs_learner_runs_as_written_and_needs_no_batchnorm():
    """docs/own_learner.md's example runs as written (its imports from jaml.learners) and
    trains without a BatchNorm: the train step keeps an empty batch_stats."""
    import re
    from pathlib import Path

    import jax
    import numpy as np

    from jaml import learners

    doc = (Path(__file__).parents[2] / "docs" / "own_learner.md").read_text()
    (code,) = re.findall(r"```python\n(.*?)```", doc, re.S)
    namespace = {}
    exec(compile(code, "docs/own_learner.md", "exec"), namespace)
    learner = namespace["make_learner"](ld_dim=4)
    batch = (np.zeros((2, 1, 64, 64, 3), np.uint8), np.zeros((2, 1, 3), np.float32))
    optimizer = learners.default_optimizer(learner)
    state = learners.init_train_state(learner, optimizer, jax.random.key(0), batch)
    state, metrics = learners.make_train_step(learner, optimizer)(state, batch, jax.random.key(1))
    assert state.batch_stats == {} and np.isfinite(float(metrics["loss"]))
    assert learner.encode(state.variables, *batch).shape == (2, 8)


class WrongRecon(TinyAE):
    """TinyAE decoding a 32×32 frame without its step axis."""

    def __call__(self, x, a, key, train: bool = True):
        z = self._z(x, train)
        return Outputs(recon=jnp.zeros((len(x), 32, 32, 3)) + z.sum(), kl={}, z=z[:, None])


def no_ld_dim():
    return make_tiny(4)


def test_a_wrong_recon_or_factory_signature_is_one_line_naming_the_fix():
    """A recon of the wrong shape fails where the loss is first traced, naming the shape
    expected; a factory without ld_dim fails where it is called, naming FACTORY(ld_dim=D)."""
    import jax
    import numpy as np

    from jaml import learners

    learner = Learner("Wrong", make_tiny(4).config, WrongRecon(6), kl_weights={})
    frames, actions = np.zeros((2, 1, 64, 64, 3), np.uint8), np.zeros((2, 1, 3), np.float32)
    variables = learner.init(jax.random.key(0), frames, actions)
    with pytest.raises(ValueError, match=r"^Wrong: Outputs.recon must be \[B, S, 64, 64, 3\] "
                                         r"= \[2, 1, 64, 64, 3\] .* got \[2, 32, 32, 3\]; "):
        jax.jit(lambda v: learner.loss(v, jax.random.key(1), frames, actions))(variables)
    with pytest.raises(ValueError, match=r"no_ld_dim must take the keyword ld_dim .* calls "
                                         r"no_ld_dim\(ld_dim=D\)") as error:
        learners.make(f"{__name__}:no_ld_dim", ld_dim=4)
    assert "\n" not in str(error.value)
