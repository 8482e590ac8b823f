"""What the figure drivers share (`_runs`): the call flags reach `run_many` as given; a cell's
seeds share their settings."""

import json

import pytest

from jaml.experiments import fig2, fig3

DEFAULTS = dict(stop_after=None, checkpoint_every=None, final_checkpoint=True,
                keep_pi_rand=True)
GIVEN = (["--stop-after", "7", "--checkpoint-every", "1000", "--no-final-checkpoint",
          "--no-keep-pi-rand"],
         dict(stop_after=7, checkpoint_every=1000, final_checkpoint=False, keep_pi_rand=False))
DRIVERS = {
    "fig2": (fig2, ["--envs", "CartPole", "--variants", "PRED"]),
    "fig3": (fig3, ["--variants", "VAE_rpl"]),
}


@pytest.mark.parametrize("driver", DRIVERS)
@pytest.mark.parametrize("flags, expected", [([], DEFAULTS), GIVEN],
                         ids=["defaults", "every-flag"])
def test_the_call_flags_reach_the_runs(tmp_path, monkeypatch, driver, flags, expected):
    from jaml.stream import run as run_lib

    calls = []

    def run_many(configs, dirs, **kwargs):
        calls.append(kwargs)
        return [{"status": "interrupted", "epoch": 0, "seconds_by_phase": {}} for _ in configs]

    monkeypatch.setattr(run_lib, "run_many", run_many)
    module, args = DRIVERS[driver]
    assert module.main(["--out", str(tmp_path), *args, "--seeds", "0", "1", *flags]) == 0
    assert len(calls) == 1
    assert {k: calls[0][k] for k in expected} == expected


def _seed(directory, seed, **config):
    (directory / f"seed_{seed}").mkdir(parents=True)
    (directory / f"seed_{seed}" / "config.json").write_text(json.dumps({"seed": seed, **config}))


def test_a_cell_compares_its_seeds_resolved_configs_and_reads_older_records_beside_newer(
        tmp_path):
    from jaml.experiments import _runs

    resolved = {"learner": {"beta": 1.0}, "env": {"multicolor": True}}
    _seed(tmp_path / "new", 0, epochs=20, resolved=resolved)
    _seed(tmp_path / "new", 1, epochs=20, resolved=resolved)
    # Compared whole; returned as the reports show them (`_runs.settings`: no "resolved").
    assert _runs.cell_config(tmp_path / "new") == {"epochs": 20}
    _seed(tmp_path / "new", 2, epochs=20, resolved={**resolved, "learner": {"beta": 2.0}})
    with pytest.raises(ValueError, match="seed_0 and seed_2 differ in resolved"):
        _runs.cell_config(tmp_path / "new")
    _seed(tmp_path / "mixed", 0, epochs=20)  # an older record: no resolved configs
    _seed(tmp_path / "mixed", 1, epochs=20, resolved=resolved)
    assert _runs.cell_config(tmp_path / "mixed") == {"epochs": 20}
