"""`naocal simulate`: a naocal.dataset/2 directory plus truth.json from the mock; bad input refused."""

import json

import numpy as np
import pytest

from naocal.solver.dataset import read_dataset
from naocal.solver.joints import JOINTS
from tests.cli_runner import naocal
from naocal.tools import cli

@pytest.mark.slow
def test_simulate_writes_a_dataset_and_the_hidden_truth(tmp_path):
    out = tmp_path / "sim"
    done = naocal("simulate", "--out", out, "--seed", "4", "--stances-per-leg", "3", "--effect", "time_lag=0.02",
                  "--no-progress", "--mock", "ideal")
    assert done.returncode == 0, done.stderr
    assert "naocal simulate: wrote" in done.stdout
    assert sorted(p.name for p in out.iterdir()) == ["dataset.json", "images", "observations.csv", "truth.json",
                                                     "truth_effects.json"]
    drawn = json.loads((out / "truth_effects.json").read_text())
    assert drawn["effects"] == {"time_lag": {"image_stamp_late_s": 0.02}}
    data = read_dataset(out)
    n_images = len(np.unique(data.columns["image"]))
    # 3 stances x 3 head postures + 3 lag-probe images, and 2 top-camera stances x 2 head postures, per leg
    assert n_images == 2 * (3 * 3 + 3 + 2 * 2)
    assert len(list((out / "images").glob("*.png"))) == n_images
    assert data.meta["schema"] == "naocal.dataset/2"
    assert set(data.columns["target"]) == {"L", "R"} and set(data.columns["camera"]) == {"bottom", "top"}
    assert data.has_velocities
    truth = json.loads((out / "truth.json").read_text())
    assert truth["schema"] == "naocal.truth/2"
    assert set(truth["alpha_rad"]) == set(JOINTS)
    assert set(truth["camera_rotation_rad"]) == {"bottom", "top"}
    assert set(truth["board_mount"]["L"]) == {"rot_z_rad", "trans_x_m", "trans_y_m"}
    assert truth["effects"] == {"time_lag": 0.02}
    assert data.meta["source"].startswith("naocal simulate")


@pytest.mark.parametrize("argv, message", [
    (["simulate", "--out", "X", "--effect", "elasticity"], "NAME=SIZE"),
    (["simulate", "--out", "X", "--effect", "gravity=2"], "unknown effect"),
    (["simulate", "--out", "X", "--effect", "backlash=-0.002"], "at least 0 rad"),  # a play is never negative
    (["simulate", "--out", "X", "--effect", "elasticity=-0.02"], "at least 0 rad/(N m)"),
    (["simulate", "--out", "X", "--seed", "-3"], "--seed"),
])
def test_bad_input_is_one_line_and_exit_2(argv, message, tmp_path, capsys):
    argv = [str(tmp_path / "sim") if a == "X" else a for a in argv]
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert code == 2 and message in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_an_existing_directory_is_not_overwritten(tmp_path, capsys):
    (tmp_path / "observations.csv").write_text("keep me")
    code = cli.main(["simulate", "--out", str(tmp_path)])
    assert code == 2 and "not an empty directory" in capsys.readouterr().err
    assert (tmp_path / "observations.csv").read_text() == "keep me"
