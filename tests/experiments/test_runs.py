"""The flags every cell-training driver shares (`_runs.CallOptions`) reach `run_many` as given."""

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
