"""`jaml envs list` and `jaml envs show`, driven through jaml.cli.main."""

import numpy as np
import pytest
from PIL import Image

import envs_mjx
from jaml.cli import main


def test_envs_list_prints_every_env_with_sizes_and_names(capsys):
    assert main(["envs", "list"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in out] == list(envs_mjx.ALL_ENVS)
    cartpole = next(line for line in out if line.startswith("CartPole:"))
    assert cartpole == "CartPole: action 1, LD state 4 [theta, theta_dot, x, x_dot]"
    ant = next(line for line in out if line.startswith("Ant:"))
    assert "action 8, LD state 28 [z_rel," in ant


def test_envs_show_unknown_name_lists_valid_ones(capsys, tmp_path):
    with pytest.raises(SystemExit) as exit_info:
        main(["envs", "show", "--env", "Nope", "--out", str(tmp_path / "x.png")])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2
    assert "invalid choice 'Nope'" in err and "CartPole" in err and "GeomOnIncline" in err
    assert not (tmp_path / "x.png").exists()


def test_envs_show_writes_a_resets_by_time_grid(tmp_path, capsys):
    out = tmp_path / "cartpole.png"
    argv = ["envs", "show", "--env", "CartPole", "--out", str(out), "--resets", "2", "--steps",
            "3"]
    assert main([*argv, "--seed", "1"]) == 0
    assert str(out) in capsys.readouterr().out
    img = np.asarray(Image.open(out))
    gap = 2
    assert img.shape == (2 * 64 + gap, 3 * 64 + 2 * gap, 3)
    frames = [
        [img[i * 66 : i * 66 + 64, j * 66 : j * 66 + 64].astype(int) for j in range(3)]
        for i in range(2)
    ]
    # Gaps are white; frames are drawn (several colours), and the rollout moves the scene.
    assert (img[64:66] == 255).all() and (img[:, 64:66] == 255).all()
    for row in frames:
        for f in row:
            assert len(np.unique(f.reshape(-1, 3), axis=0)) > 3
        assert np.abs(row[-1] - row[0]).max() > 0
    # Different resets start from different states.
    assert np.abs(frames[0][0] - frames[1][0]).max() > 0
