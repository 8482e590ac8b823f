"""The Fig. 3 driver: LD groups from the env, the reference's Rearrange settings, the report from
per-seed histories (means and 90 % intervals by hand), the command's wiring (training stubbed)
and its errors; the real tiny end-to-end run compiles RearrangeGeom's stream on CPU (minutes per
learner) and is marked slow."""

import dataclasses
import json
import math

import jax
import numpy as np
import pytest
from matplotlib.image import imsave

from jaml import cli, stream
from jaml.evaluation import history_records
from jaml.experiments import _runs, fig3

T_90_2DOF = 2.9199856  # t(0.95, 2 dof): the 90 % half-width of 3 seeds is this · s / √3
T_90_1DOF = 6.3137515  # t(0.95, 1 dof), for 2 seeds

PAPER_SIZES = _runs.Sizes().overrides()
# The sizes by the flat names of a run record written before the config tree (#45).
FLAT_SIZES = dataclasses.asdict(_runs.Sizes())


def _options(config) -> dict:
    """The learner config fields a config sets beyond the learner's defaults."""
    from jaml.configs.learners import default_config
    from jaml.configs.stream import changed_fields

    return changed_fields(config.learner_config, default_config(config.learner, ld_dim=None))


def test_groups_come_from_the_envs_metadata_and_names():
    import envs_mjx

    env = envs_mjx.make(fig3.ENV)
    names = list(env.ld_state_names)
    layout = fig3.layout()
    assert layout.joints == {"q0": ["sin_q0", "cos_q0"], "q1": ["sin_q1", "cos_q1"]}
    assert layout.positions["obj2"] == ["obj2_x", "obj2_y", "obj2_z"]
    assert layout.rotations["obj0"] == [f"obj0_r{i}{j}" for i in range(3) for j in range(3)]
    # Orientation is scored by each block's principal-axis error, recorded as objK_rotation.
    assert layout.orientations == {f"obj{k}": f"obj{k}_rotation" for k in range(4)}
    groups = layout.groups()
    assert list(groups) == [fig3.ARM, fig3.POSITIONS, fig3.ORIENTATION]
    # Every entry but the version id in exactly one group, each group from the env's metadata.
    grouped = [n for dims in groups.values() for n in dims]
    assert sorted(grouped) == sorted(set(names) - {"version"})
    by_name = dict(zip(names, env.ld_state_groups, strict=True))
    assert {by_name[n] for n in groups[fig3.ORIENTATION]} == {"orientation"}
    assert {by_name[n] for n in groups[fig3.ARM] + groups[fig3.POSITIONS]} == {"position"}
    # Versions 0-3 hold cylinder, cube (a 5 × 10 × 15 cm box), sphere, sphere1 (r 6 cm).
    assert layout.shapes == {"obj0": "cylinder", "obj1": "cube", "obj2": "sphere",
                             "obj3": "sphere1"}
    assert layout.largest == "obj3"
    # The runs' env decides the shapes (JSON lists from config.json accepted): version 5 holds
    # cube, sphere, sphere, cube, two equal largest objects, so no slot is "the largest".
    v5 = fig3.layout(fig3.ENV, {"versions": [5]})
    assert (v5.shapes["obj0"], v5.shapes["obj3"], v5.largest) == ("cube", "cube", None)
    assert "largest object position" not in " ".join(v5.panels())
    mixed = fig3.layout(fig3.ENV, {"versions": [0, 5]})
    assert mixed.shapes["obj0"] == "cylinder/cube" and mixed.largest is None
    panels = layout.panels()
    assert panels["main joint (q0)"] == ["sin_q0", "cos_q0"]
    assert panels["largest object position (obj3: sphere1)"] == ["obj3_x", "obj3_y", "obj3_z"]
    assert panels[fig3.ORIENTATION] == [f"obj{k}_rotation" for k in range(4)]


def test_an_entry_outside_the_layout_is_an_error(monkeypatch):
    import envs_mjx

    class Odd:
        ld_state_names = ("version", "sin_q0", "cos_q0", "gripper")
        ld_state_groups = ("other", "position", "position", "position")

    monkeypatch.setattr(envs_mjx, "make", lambda name: Odd())
    with pytest.raises(ValueError, match=r"'gripper' .* is not an arm joint"):
        fig3.layout("OddRearrange")


def test_configs_follow_the_reference_for_rearrange():
    vae = fig3.config_for("VAE_rpl", 2, PAPER_SIZES, fig3.SCHEDULE)
    spair = fig3.config_for("SPAIR_6x6", 0, PAPER_SIZES, fig3.SCHEDULE, {"beta": 0.2},
                            {"versions": (0, 1)})
    assert (vae.env, vae.learner, vae.seed) == ("RearrangeGeom", "VAE_rpl", 2)
    assert (vae.rollout_len, vae.learner_steps) == (10, 50)
    assert stream.resolve(vae, 4, "cpu").replay.slots == 4992
    assert (vae.frames_per_batch, spair.frames_per_batch) == (1024, 64)
    assert not vae.eval.regressor_normalize and not spair.eval.regressor_normalize
    assert (vae.epochs, vae.eval.every, vae.eval.train, vae.eval.rand, vae.eval.curr) == (
        300, 50, 10_000, 10_048, 2_500)
    assert (vae.ppo.hidden, vae.ppo.num_updates, vae.ppo.num_minibatches) == ((256, 256), 50, 4)
    # PARAMS_VAE_REARR: the VAE's latent is as wide as the reacher's LD state.
    assert _options(vae) == {"latent_dim": 53, "mu_nl": False, "logvar_limit": 20.0}
    assert _options(spair) == {"grid_size": 6, "beta": 0.2}
    assert spair.env_config.versions == (0, 1)
    assert fig3.config_for("SPAIR_4x4", 0, PAPER_SIZES, fig3.SCHEDULE).learner_config.grid_size == 4
    ycb = fig3.config_for("VAE_rpl", 0, PAPER_SIZES, fig3.SCHEDULE, env="RearrangeYCB")
    assert (ycb.env, ycb.learner_config.latent_dim, ycb.rollout_len) == (
        "RearrangeYCB", 53, 10)
    with pytest.raises(ValueError, match=r"unknown env 'RearrangeToys' for Fig\. 3; valid: "
                                         r"RearrangeGeom, RearrangeYCB"):
        fig3.config_for("VAE_rpl", 0, PAPER_SIZES, fig3.SCHEDULE, env="RearrangeToys")


def test_learner_options_go_to_every_variant_or_the_named_ones():
    options = fig3.learner_options(["frame_nll=mean", "SPAIR.beta=0.2", "SPAIR_6x6.what_dim=8"],
                                   list(fig3.VARIANTS))
    assert options == {"VAE_rpl": {"frame_nll": "mean"},
                       "SPAIR_4x4": {"frame_nll": "mean", "beta": 0.2},
                       "SPAIR_6x6": {"frame_nll": "mean", "beta": 0.2, "what_dim": 8}}
    with pytest.raises(ValueError, match="'SPAIR_5x5' is no variant or learner"):
        fig3.learner_options(["SPAIR_5x5.beta=1"], list(fig3.VARIANTS))


@pytest.mark.parametrize(("argv", "message"), [
    (["--variants", "SPAIR_5x5"], "invalid choice 'SPAIR_5x5'"),
    (["--learner-opt", "beta"], "expected KEY=VALUE, got 'beta'"),
    (["--learner-opt", "PRED.hist=2"], "'PRED' is no variant or learner"),
    (["--report-only"], "no such directory"),
    (["--env", "RearrangeToys"], "invalid choice 'RearrangeToys'"),
])
def test_bad_input_is_one_clear_line(tmp_path, capsys, argv, message):
    code = None
    try:
        code = cli.main(["fig3", "--out", str(tmp_path / "missing"), *argv])
    except SystemExit as exit_:
        code = exit_.code
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    with pytest.raises(ValueError, match="unknown variant 'VAE'; valid: VAE_rpl, SPAIR_4x4"):
        fig3.config_for("VAE", 0, PAPER_SIZES, fig3.SCHEDULE)


# ---------------------------------------------------------------------------------------------
# The report from fake histories.


NAMES = None


def _names():
    """The names of a Rearrange run's errors: the LD state's, then objK_rotation per object
    (the principal-axis error of its rotation block)."""
    global NAMES
    if NAMES is None:
        import envs_mjx

        NAMES = [*envs_mjx.make(fig3.ENV).ld_state_names,
                 *(f"obj{k}_rotation" for k in range(4))]
    return NAMES


def _errors(q0, q1, obj_pos, axes=(0.5, 0.5, 0.5, 0.5), rot=0.9):
    """An error vector: q0 / q1 on their sin and cos, obj_pos[k] on object k's x, y, z, axes[k]
    on its principal-axis error and `rot` on every rotation entry (which the report ignores)."""
    values = {}
    for n in _names():
        if n.endswith("_q0"):
            values[n] = q0
        elif n.endswith("_q1"):
            values[n] = q1
        elif n[-2:] in ("_x", "_y", "_z"):
            values[n] = obj_pos[int(n[3])]
        elif n.endswith("_rotation"):
            values[n] = axes[int(n[3])]
        else:
            values[n] = rot
    return [values[n] for n in _names()]


def _write_run(path, variant, seed, by_step, fill=2, baseline=None, env=fig3.ENV):
    """A seed directory: config.json, history.jsonl with π_curr and π_rand records per step
    (π_rand = π_curr + 0.1; with `baseline`, every record's constant-prediction errors are that
    value), a recon image per step."""
    learner = fig3.VARIANTS[variant][0]
    path.mkdir(parents=True)
    config = {**FLAT_SIZES, "num_envs": 4, "replay_slots": 4 * fill, "epochs": 6,
              "eval_every": 2, "learner": learner, "seed": seed, "env": env}
    (path / "config.json").write_text(json.dumps(config))
    records = []
    for step, errors in by_step.items():
        records += history_records(step, learner, {"pi_curr": errors,
                                                   "pi_rand": [e + 0.1 for e in errors]},
                                   _names(), run=seed)
        if baseline is not None:
            records = [r | {"baseline": dict.fromkeys(_names(), baseline)} for r in records]
        (path / "recon").mkdir(exist_ok=True)
        imsave(path / "recon" / f"epoch_{step:06d}.png", np.full((8, 16, 3), step, np.uint8))
    (path / "history.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))


def _row(text, variant, test_set, header):
    """A table row's cells by column name, from the table whose header line starts `header`."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header))
    columns = [c.strip() for c in lines[start].strip("|").split("|")]
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        if cells[:2] == [variant, test_set]:
            return dict(zip(columns, cells, strict=True))
    raise AssertionError(f"no row {variant} {test_set}")


def _half(values):
    return T_90_2DOF * np.std(values, ddof=1) / math.sqrt(len(values))


@pytest.fixture
def fake_grid(tmp_path):
    """VAE_rpl: 3 seeds to epoch 6; SPAIR_4x4: 3 seeds, the last one only to epoch 4."""
    q0 = {0: 0.10, 1: 0.20, 2: 0.30}
    for seed in range(3):
        steps = {2: _errors(0.9, 0.9, [0.8] * 4),
                 4: _errors(0.5, 0.6, [0.5, 0.5, 0.5, 0.4 + 0.06 * seed]),
                 6: _errors(q0[seed], 0.4 + 0.1 * seed, [0.3, 0.3, 0.3, 0.1 * seed],
                            axes=[0.1, 0.2, 0.3, 0.2 + 0.1 * seed])}
        _write_run(tmp_path / "VAE_rpl" / f"seed_{seed}", "VAE_rpl", seed, steps)
        spair = {2: _errors(0.9, 0.9, [0.9] * 4), 4: _errors(0.8, 0.8, [0.3 + 0.1 * seed] * 4),
                 6: _errors(0.8, 0.8, [0.2] * 4)}
        if seed == 2:
            del spair[6]
        _write_run(tmp_path / "SPAIR_4x4" / f"seed_{seed}", "SPAIR_4x4", seed, spair)
    return tmp_path


def test_report_averages_groups_per_seed_then_seeds_with_a_t_interval(fake_grid):
    text = fig3.report(fake_grid)
    assert (fake_grid / "fig3.md").read_text() == text
    head = "| variant | test set | arm joint angles"
    vae = _row(text, "VAE_rpl", "pi_curr", head)
    q0 = np.array([0.1, 0.2, 0.3])
    assert vae["main joint (q0)"] == f"{q0.mean():.3f} ± {_half(q0):.3f}"
    arm = (q0 + np.array([0.4, 0.5, 0.6])) / 2  # per seed the mean over its 4 joint entries
    assert vae["arm joint angles"] == f"{arm.mean():.3f} ± {_half(arm):.3f}"
    largest = np.array([0.0, 0.1, 0.2])
    assert vae["largest object position (obj3: sphere1)"] == (
        f"{largest.mean():.3f} ± {_half(largest):.3f}")
    positions = (0.9 + largest) / 4  # three objects at 0.3, the largest at 0.1·seed
    assert vae["object positions"] == f"{positions.mean():.3f} ± {_half(positions):.3f}"
    # Per seed the mean of the 4 objects' principal-axis errors (0.1, 0.2, 0.3, 0.2 + 0.1·seed).
    orientation = np.array([0.2, 0.225, 0.25])
    assert vae["object orientation"] == f"{orientation.mean():.3f} ± {_half(orientation):.3f}"
    assert (vae["epoch"], vae["seeds"]) == ("6", "3")
    assert _row(text, "VAE_rpl", "pi_rand", head)["object orientation"] == (
        f"{orientation.mean() + 0.1:.3f} ± {_half(orientation):.3f}")
    # SPAIR's third seed stopped at epoch 4: the table is at epoch 4, where all three are.
    spair = _row(text, "SPAIR_4x4", "pi_curr", head)
    assert (spair["epoch"], spair["seeds"]) == ("4", "3")
    pos = np.array([0.3, 0.4, 0.5])
    assert spair["object positions"] == f"{pos.mean():.3f} ± {_half(pos):.3f}"
    # Per object: shapes named, position and orientation per slot.
    per_object = _row(text, "VAE_rpl", "pi_curr", "| variant | test set | obj0")
    assert per_object["obj1 (cube) position"] == "0.300 ± 0.000"
    assert per_object["obj0 (cylinder) orientation"] == "0.100 ± 0.000"
    obj3 = np.array([0.2, 0.3, 0.4])
    assert per_object["obj3 (sphere1) orientation"] == f"{obj3.mean():.3f} ± {_half(obj3):.3f}"
    assert (fake_grid / "fig3.png").stat().st_size > 0
    # The newest image of the first seed, copied next to fig3.md.
    assert "![VAE_rpl, seed_0, epoch 6](fig3_recon_VAE_rpl.png)" in text
    assert "![SPAIR_4x4, seed_0, epoch 6](fig3_recon_SPAIR_4x4.png)" in text
    assert (fake_grid / "fig3_recon_SPAIR_4x4.png").read_bytes() == (
        fake_grid / "SPAIR_4x4" / "seed_0" / "recon" / "epoch_000006.png").read_bytes()


def test_constant_prediction_rows_come_from_the_records_baselines(tmp_path):
    for seed in range(2):
        _write_run(tmp_path / "VAE_rpl" / f"seed_{seed}", "VAE_rpl", seed,
                   {2: _errors(0.5, 0.5, [0.3] * 4)}, baseline=0.6 + 0.1 * seed)
        _write_run(tmp_path / "SPAIR_4x4" / f"seed_{seed}", "SPAIR_4x4", seed,
                   {2: _errors(0.5, 0.5, [0.3] * 4)})  # analysed before baselines existed
    text = fig3.report(tmp_path)
    head = "| variant | test set | arm joint angles"
    row = _row(text, "VAE_rpl: constant prediction", "pi_rand", head)
    level = np.array([0.6, 0.7])
    half = T_90_1DOF * np.std(level, ddof=1) / math.sqrt(2)
    assert row["main joint (q0)"] == f"{level.mean():.3f} ± {half:.3f}"
    assert (row["epoch"], row["seeds"]) == ("2", "2")
    assert "SPAIR_4x4: constant prediction" not in text


def test_true_state_rows_come_from_the_runs_summaries(tmp_path):
    """The floor: the regressor's errors with the true state as the latent, from each run's
    summary.json "references"; a variant whose runs did not record it has no row."""
    for seed in range(2):
        run = tmp_path / "VAE_rpl" / f"seed_{seed}"
        _write_run(run, "VAE_rpl", seed, {2: _errors(0.5, 0.5, [0.3] * 4)})
        floor = [0.01 * (seed + 1)] * len(_names())
        (run / "summary.json").write_text(json.dumps(
            {"references": {"epoch": 2, "true_state": {"pi_rand": floor}}}))
        _write_run(tmp_path / "SPAIR_4x4" / f"seed_{seed}", "SPAIR_4x4", seed,
                   {2: _errors(0.5, 0.5, [0.3] * 4)})
    text = fig3.report(tmp_path)
    row = _row(text, "VAE_rpl: true state", "pi_rand", "| variant | test set | arm joint angles")
    half = T_90_1DOF * np.std([0.01, 0.02], ddof=1) / math.sqrt(2)
    assert row["main joint (q0)"] == f"0.015 ± {half:.3f}"
    assert (row["epoch"], row["seeds"]) == ("—", "2")
    assert "VAE_rpl: true state | pi_curr" not in text and "SPAIR_4x4: true state" not in text


def test_claims_table_pairs_seeds_within_a_variant_and_welch_between(fake_grid):
    from scipy import stats

    text = fig3.report(fake_grid)
    head = "| paper | measure"
    rows = [line for line in text.splitlines() if line.startswith("| ")]
    start = rows.index(next(r for r in rows if r.startswith(head)))
    claims = {r.split(" | ")[1] + " / " + r.split(" | ")[2]: [c.strip() for c in
                                                             r.strip("|").split("|")]
              for r in rows[start + 1:] if not r.startswith("|---")}
    # Main joint: per seed q0 − q1 = −0.3 every seed.
    main = claims["q0 − q1 error, epoch 6 / VAE_rpl"]
    assert main[3] == "-0.300 ± 0.000" and main[4] == "-0.300 ± 0.000"
    # Largest object: per seed obj3 − mean(others) = 0.1·seed − 0.3.
    diffs = np.array([-0.3, -0.2, -0.1])
    largest = claims["obj3 − other objects' position error, epoch 6 / VAE_rpl"]
    assert largest[3] == f"{diffs.mean():.3f} ± {_half(diffs):.3f}"
    # SPAIR: position error at the last common epoch (4; the first trained analysis is also 4,
    # the fill ends at 2): one trained step only, so no "longer training" row.
    assert not any(k.startswith("object position error, epoch 4 − epoch 4") for k in claims)
    # What training changed, from the first analysis (epoch 2, no learner step) to the last
    # common one: per seed mean position error over the four objects.
    vae_change = (0.9 + 0.1 * np.arange(3)) / 4 - 0.8
    row = claims["object position error, epoch 6 − epoch 2 (no learner step yet) / VAE_rpl"]
    assert row[3] == f"{vae_change.mean():+.3f} ± {_half(vae_change):.3f}"
    obj3 = claims["obj3 position error, epoch 6 − epoch 2 / VAE_rpl"]
    obj3_change = 0.1 * np.arange(3) - 0.8
    assert obj3[3] == f"{obj3_change.mean():+.3f} ± {_half(obj3_change):.3f}"
    spair_change = 0.3 + 0.1 * np.arange(3) - 0.9  # seed 2 stops at 4: epoch 4 − epoch 2
    row = claims["object position error, epoch 4 − epoch 2 (no learner step yet) / SPAIR_4x4"]
    assert row[3] == f"{spair_change.mean():+.3f} ± {_half(spair_change):.3f}"
    # SPAIR against VAE_rpl at epoch 4, Welch's interval over the seeds' position errors.
    against = claims["object position error − VAE_rpl's, epoch 4 / SPAIR_4x4"]
    spair, vae = np.array([0.3, 0.4, 0.5]), 0.475 + 0.015 * np.arange(3)
    ci = stats.ttest_ind(spair, vae, equal_var=False).confidence_interval(0.90)
    assert against[3] == f"{spair.mean() - vae.mean():+.3f} [{ci.low:+.3f}, {ci.high:+.3f}]"


def test_longer_training_row_compares_first_and_last_trained_analyses(tmp_path):
    for seed, last in enumerate([0.35, 0.30, 0.28]):
        _write_run(tmp_path / "SPAIR_6x6" / f"seed_{seed}", "SPAIR_6x6", seed,
                   {2: _errors(1, 1, [1] * 4), 4: _errors(1, 1, [0.3] * 4),
                    6: _errors(1, 1, [last] * 4)})
    text = fig3.report(tmp_path, ["SPAIR_6x6"])
    row = next(line for line in text.splitlines()
               if "object position error, epoch 6 − epoch 4" in line)
    diffs = np.array([0.05, 0.0, -0.02])
    assert f"| {diffs.mean():+.3f} ± {_half(diffs):.3f} |" in row
    assert "VAE_rpl" not in text.split("## The paper's claims")[1]


def test_histories_without_principal_axis_errors_show_no_orientation(tmp_path):
    """Runs analysed before the stream recorded objK_rotation: orientation is "–", the rest
    as usual."""
    global NAMES
    names = _names()
    NAMES = names[:-4]  # the LD state's names only
    try:
        for seed in range(2):
            _write_run(tmp_path / "VAE_rpl" / f"seed_{seed}", "VAE_rpl", seed,
                       {2: _errors(0.5, 0.5, [0.4] * 4)})
    finally:
        NAMES = names
    text = fig3.report(tmp_path, ["VAE_rpl"])
    row = _row(text, "VAE_rpl", "pi_curr", "| variant | test set | arm joint angles")
    assert (row["object orientation"], row["object positions"]) == ("–", "0.400 ± 0.000")


def test_one_out_directory_holds_one_env(tmp_path):
    _write_run(tmp_path / "VAE_rpl" / "seed_0", "VAE_rpl", 0, {2: _errors(0.5, 0.5, [0.5] * 4)})
    _write_run(tmp_path / "SPAIR_4x4" / "seed_0", "SPAIR_4x4", 0,
               {2: _errors(0.5, 0.5, [0.5] * 4)}, env="RearrangeYCB")
    with pytest.raises(ValueError, match=r"runs of several envs \(RearrangeGeom, RearrangeYCB\)"):
        fig3.report(tmp_path)


@pytest.mark.parametrize("env, note", [(fig3.ENV, True), ("RearrangeYCB", False)])
def test_the_sphere_note_comes_only_with_spheres(tmp_path, env, note):
    # RearrangeGeom's slots hold spheres; RearrangeYCB's fruit are textured meshes.
    _write_run(tmp_path / "VAE_rpl" / "seed_0", "VAE_rpl", 0, {2: _errors(0.5, 0.5, [0.5] * 4)},
               env=env)
    assert ("Spheres are one colour" in fig3.report(tmp_path)) is note


def test_an_empty_out_says_so(tmp_path):
    assert "No analysed runs" in fig3.report(tmp_path)
    assert (tmp_path / "fig3.md").exists() and not (tmp_path / "fig3.png").exists()


# ---------------------------------------------------------------------------------------------
# The command, with training stubbed.


def test_the_command_trains_each_variant_then_reports(tmp_path, monkeypatch, capsys):
    from jaml.stream import run as run_lib

    calls = []

    def fake_run_many(configs, outs, *, progress, stop_after, checkpoint_every, final_checkpoint,
                      keep_pi_rand, deadline):
        assert keep_pi_rand and deadline is None  # the defaults: π_rand sets kept, no limit
        calls.append(([c.seed for c in configs], [str(o) for o in outs], stop_after,
                      configs[0]))
        assert checkpoint_every == 100
        summaries = []
        for c, o in zip(configs, outs, strict=True):
            _write_run(o, o.parent.name, c.seed, {2: _errors(0.5, 0.5, [0.5] * 4)}, env=c.env)
            summaries.append({"status": "interrupted", "epoch": 2,
                              "seconds_by_phase": {"epochs": 1.0}})
        return summaries

    monkeypatch.setattr(run_lib, "run_many", fake_run_many)
    argv = ["fig3", "--out", str(tmp_path), "--variants", "SPAIR_6x6", "VAE_rpl", "--seeds", "3",
            "5", "--stop-after", "7", "--epochs", "20", "--eval-every", "5",
            "--learner-opt", "SPAIR.beta=0.3", "--env-opt", "versions=[0,1]",
            "--checkpoint-every", "100", "--env", "RearrangeYCB"]
    assert cli.main(argv) == 0
    assert [c[:3] for c in calls] == [
        ([3, 5], [str(tmp_path / "SPAIR_6x6" / "seed_3"), str(tmp_path / "SPAIR_6x6" / "seed_5")],
         7),
        ([3, 5], [str(tmp_path / "VAE_rpl" / "seed_3"), str(tmp_path / "VAE_rpl" / "seed_5")], 7)]
    spair, vae = calls[0][3], calls[1][3]
    assert _options(spair) == {"grid_size": 6, "beta": 0.3}
    assert "beta" not in _options(vae)
    assert (spair.epochs, spair.eval.every, spair.env_config.versions) == (20, 5, (0, 1))
    assert spair.env == vae.env == "RearrangeYCB"
    out = capsys.readouterr().out
    assert "SPAIR_6x6 seed 3: interrupted at epoch 2" in out
    assert "# Fig. 3: RearrangeYCB (reacher)" in out and (tmp_path / "fig3.md").exists()
    calls.clear()
    assert cli.main(["fig3", "--out", str(tmp_path), "--report-only"]) == 0
    assert not calls  # --report-only trains nothing


# ---------------------------------------------------------------------------------------------
# The real thing, tiny.

TINY = {"num_envs": 4, "rollout_len": 2, "replay.slots": 8, "frames_per_batch": 4,
        "learner_steps": 1, "eval.train": 8, "eval.rand": 8, "eval.curr": 8, "eval.transient": 2,
        "eval.regressor_iterations": 5}
TINY_LEARNERS = {
    "VAE_rpl": {"mlp_widths": (32, 32), "conv_filters": (8, 8, 8, 8), "conv_features": 16,
                "deconv_filters": (8, 8, 8, 8)},
    "SPAIR_4x4": {"backbone_filters": (8, 8, 8), "conv_features": 16, "lateral_widths": (16,),
                  "passthrough": 8, "glimpse_size": 8, "what_dim": 2, "bg_dim": 2,
                  "object_filters": (8, 8), "object_hidden": 16, "bg_hidden": 16},
}


@pytest.mark.slow
@pytest.mark.parametrize("variant", list(TINY_LEARNERS))
def test_tiny_runs_resume_and_report(tmp_path, variant):
    """Two seeds trained together on RearrangeGeom (tiny shapes), interrupted after the fill
    epochs and resumed to the end; then the report. ~10 minutes of CPU compilation each."""
    from jaml import stream

    scale = {**TINY, "ppo": stream.PPOConfig(hidden=(16,), num_updates=1, num_minibatches=2)}
    with jax.threefry_partitionable(False):  # compiles several times faster on CPU
        first = fig3.run_cell(tmp_path, variant, [0, 1], scale, (4, 2), TINY_LEARNERS[variant],
                              stop_after=2)
        assert [s["status"] for s in first] == ["interrupted"] * 2
        assert [s["epoch"] for s in first] == [2, 2]
        assert [s["checkpoint_epoch"] for s in first] == [2, 2]  # a --stop-after stop saves
        second = fig3.run_cell(tmp_path, variant, [0, 1], scale, (4, 2), TINY_LEARNERS[variant])
    assert [s["status"] for s in second] == ["finished"] * 2
    run = tmp_path / variant / "seed_1"
    history = [json.loads(x) for x in (run / "history.jsonl").read_text().splitlines()]
    # Resumed, not retrained: each analysis once, in order, and each epoch logged once.
    assert [(r["step"], r["test_set"]) for r in history] == [
        (2, "pi_rand"), (2, "pi_curr"), (4, "pi_rand"), (4, "pi_curr")]
    assert [json.loads(x)["epoch"] for x in (run / "metrics.jsonl").read_text().splitlines()
            ] == [1, 2, 3, 4]
    assert all(np.isfinite(list(r["errors"].values())).all() for r in history)
    assert all(list(r["baseline"]) == list(r["errors"])
               and np.isfinite(list(r["baseline"].values())).all() for r in history)
    # The stream records each object's principal-axis error after the LD entries.
    assert all(list(r["errors"])[-4:] == [f"obj{k}_rotation" for k in range(4)]
               for r in history)
    text = fig3.report(tmp_path, [variant])
    row = _row(text, variant, "pi_rand", "| variant | test set | arm joint angles")
    assert (row["epoch"], row["seeds"]) == ("4", "2")
    assert row["object orientation"] != "–"
    assert (tmp_path / f"fig3_recon_{variant}.png").stat().st_size > 0
    assert (tmp_path / "fig3.png").stat().st_size > 0


@pytest.mark.slow
def test_a_tiny_ycb_run_trains_to_its_end_and_reports(tmp_path):
    """RearrangeYCB (the textured stand-ins for the YCB objects) through the same driver, one
    seed of VAE_rpl, physics in C MuJoCo as on a CPU one would run it: every analysis finite,
    the objects' rotation errors recorded, the report written."""
    from jaml import stream

    scale = {**TINY, "ppo": stream.PPOConfig(hidden=(16,), num_updates=1, num_minibatches=2)}
    with jax.threefry_partitionable(False):
        done = fig3.run_cell(tmp_path, "VAE_rpl", [0], scale, (4, 2), TINY_LEARNERS["VAE_rpl"],
                             {"physics": "c"}, "RearrangeYCB")
    assert [(s["status"], s["epoch"]) for s in done] == [("finished", 4)]
    run = tmp_path / "VAE_rpl" / "seed_0"
    assert json.loads((run / "config.json").read_text())["env"] == "RearrangeYCB"
    history = [json.loads(x) for x in (run / "history.jsonl").read_text().splitlines()]
    assert [(r["step"], r["test_set"]) for r in history] == [
        (2, "pi_rand"), (2, "pi_curr"), (4, "pi_rand"), (4, "pi_curr")]
    assert all(np.isfinite(list(r["errors"].values())).all() for r in history)
    assert all(list(r["errors"])[-4:] == [f"obj{k}_rotation" for k in range(4)]
               for r in history)
    text = fig3.report(tmp_path, ["VAE_rpl"])
    row = _row(text, "VAE_rpl", "pi_rand", "| variant | test set | arm joint angles")
    assert (row["epoch"], row["seeds"]) == ("4", "1")


def test_a_run_stopped_by_a_non_finite_loss_is_named_and_left_out(fake_grid):
    # SPAIR's third seed stopped at epoch 4 (fake_grid); say its loss turned non-finite then.
    stopped = fake_grid / "SPAIR_4x4" / "seed_2"
    error = ("learner loss became non-finite at epoch 5; the run stopped and its last good "
             "checkpoint is kept (lower the learning rate or check the inputs)")
    (stopped / "summary.json").write_text(json.dumps({"status": "nonfinite", "error": error}))
    text = fig3.report(fake_grid)
    spair = _row(text, "SPAIR_4x4", "pi_curr", "| variant | test set | arm joint angles")
    # The two runs that went on set the epoch: 6, not the stopped run's 4.
    assert (spair["epoch"], spair["seeds"]) == ("6", "2")
    assert spair["object positions"] == "0.200 ± 0.000"
    assert ("- SPAIR_4x4 seed_2: stopped, learner loss became non-finite at epoch 5; left out "
            "of every table and figure.") in text.splitlines()
    assert "seed_2" not in text.replace("SPAIR_4x4 seed_2: stopped", "")
