"""Your own learner on the suite's stream: `jaml suite --learner MODULE:FACTORY`, every analysis."""

import json

import flax.linen as nn
import jax.numpy as jnp
import pytest

from jaml.cli import main
from jaml.learners.learner import Learner, Outputs, SingleFrameConfig

# A whole suite run (~100 s on two cores): scheduled early, so that it does not end the run on
# one worker (tests/conftest.py).
pytestmark = pytest.mark.first


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


def test_own_learner_trains_on_the_stream_with_every_analysis(tmp_path, capsys):
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


def test_a_factory_that_cannot_be_imported_is_one_line(tmp_path, capsys):
    assert main(["suite", "--env", "CartPole", "--learner", "no_such_pkg:make", "--out",
                 str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot import make from no_such_pkg" in err[0]


def not_a_learner(ld_dim: int):
    return {"ld_dim": ld_dim}


def test_a_factory_must_return_a_learner():
    from jaml.stream.loop import make_learner

    with pytest.raises(ValueError, match=r"returned a dict, not a jaml\.learners\.Learner"):
        make_learner(f"{__name__}:not_a_learner", 4, {})
