"""A printed marker sheet's scale (issue 24): the dual-arm simulation prints each tool's markers a few tenths of a
percent off their typed size; the marker_scale effect (solver/effects/marker_scale.py) fits one scale per sheet,
identified by the URDF's link lengths (their priors), and without priors with free links the check stops naming
the parameter to fix (docs/ARM.md "Print scale")."""

import numpy as np
import pytest

from naocal.solver.effects.marker_scale import PRINT_PRIOR
from naocal.solver.errors import SolveError

EFFECTS = ("joint_offsets", "link_lengths", "tool", "points", "marker_scale")


@pytest.fixture(scope="module")
def printed():
    """Cameras' rows of seed 2, 40 stances, sheets printed 1 % off (one std: R_sheet -1.9 %, L_sheet -0.007 %)."""
    from naocal.kinds.arm.sim import simulate_dualarm

    sim = simulate_dualarm(None, seed=2, n_poses=40, noise_m=1e-5, noise_px=0.1, outlier_fraction=0.0,
                           print_scale_error=0.01, write=False)
    cameras = [s for s in sim["sensors"] if s.kind == "camera"]
    sim["cameras"] = cameras
    sim["camera_rows"] = sim["observations"].subset(np.flatnonzero(sim["observations"].sensor < len(cameras)))
    return sim


def test_the_model_with_each_sheets_scale_is_pybullets_printed_robot():
    """At the hidden truth the model with marker_scale predicts what PyBullet's robot showed with its sheets printed
    off (to the thousandth of a pixel); without it the print shows (tenths of a pixel)."""
    from naocal.kinds.arm.sim import dualarm_model, simulate_dualarm

    sim = simulate_dualarm(None, seed=5, n_poses=8, noise_m=1e-12, noise_px=1e-9, outlier_fraction=0.0,
                           print_scale_error=0.01, write=False)
    assert abs(sim["print_scale"]["L_sheet"] - 1.0) > 1e-3 and sim["truth"]["marker_scale.L_sheet"] != 0.0
    obs = sim["observations"]
    cams = obs.sensor < 2
    worst = {}
    for effects in (EFFECTS, EFFECTS[:-1]):
        model = dualarm_model(effects, sensors=sim["sensors"])
        x = np.array([sim["truth"].get(n, 0.0) for n in model.names])
        worst[effects[-1]] = np.abs((model.predict(x, obs) - obs.measured)[cams][:, :2]).max()
    assert worst["marker_scale"] < 1e-3 < 0.05 < worst["points"]  # px


def test_with_the_priors_each_sheets_scale_is_recovered_from_the_cameras(printed):
    """With the link lengths' priors (the URDF holds the arm's scale) the print's scale comes out near its truth,
    within 3.5 stds, and is no longer in the link lengths."""
    from naocal.kinds.arm.identify import fit, initialise_sensors
    from naocal.kinds.arm.sim import dualarm_model

    obs = printed["camera_rows"]
    model = dualarm_model(EFFECTS, sensors=printed["cameras"])
    result = fit(model, obs, initialise_sensors(model, obs), robust=False)
    for i, p in model.params("marker_scale"):
        true = printed["truth"][p.name]
        assert abs(result.x[i] - true) < 3.5 * result.std[i] and result.std[i] < 3e-3, p.name
    i = model.names.index("marker_scale.R_sheet")
    assert printed["truth"]["marker_scale.R_sheet"] < -0.015 and abs(result.x[i] - printed["truth"][
        "marker_scale.R_sheet"]) < 0.1 * abs(printed["truth"]["marker_scale.R_sheet"])
    assert result.prior_std[i] == PRINT_PRIOR  # the print's plausible size, reported as the prior
    links = [result.x[i] for i, _ in model.params("link_lengths") if result.free[i]]
    assert max(np.abs(links)) < 1e-3  # m: the 1.9 % print is not in the links (0.36 m x 1.9 % = 7 mm)


def test_free_links_without_priors_stop_naming_the_scale_direction_and_the_sheet_to_fix(printed):
    """No priors, links free and the print's scale free: nothing holds the metre. The check stops naming the
    direction (the sheets' scales with the link lengths) and the parameter to fix; fixed as it says, the fit runs
    and the other sheet's scale is the relative print (what the cameras do measure)."""
    from naocal.kinds.arm.identify import fit, initialise_sensors
    from naocal.kinds.arm.sim import dualarm_model

    obs = printed["camera_rows"]
    model = dualarm_model(EFFECTS, sensors=printed["cameras"])
    x0 = initialise_sensors(model, obs)
    with pytest.raises(SolveError) as err:
        fit(model, obs, x0, robust=False, priors=False)
    text = str(err.value)
    assert "1 parameter combination(s)" in text and "marker_scale.L_sheet" in text and "link_length." in text
    named = text.split("--fix ")[1].split("=")[0]
    assert named.startswith("marker_scale.") and "priors on" in text
    x0[model.names.index(named)] = printed["truth"][named]  # the print measured
    result = fit(model, obs, x0, robust=False, priors=False, fixed=(named,))
    for i, p in model.params("marker_scale"):
        assert abs(result.x[i] - printed["truth"][p.name]) < 5e-4, p.name


def test_a_sheet_named_for_no_marker_is_refused():
    from naocal.kinds.arm.model import ArmModel
    from naocal.kinds.arm.sim import dualarm_markers, dualarm_model, dualarm_points

    model = dualarm_model(("points",))
    points = {n: xyz for n, (xyz, _, _) in dualarm_points().items()}
    with pytest.raises(ValueError, match="'R_smr' has a sheet but is no marker"):
        ArmModel(model.arm_chains, points, model.sensors, ("marker_scale",), markers=dualarm_markers(),
                 sheets={"R_smr": "S"})


def test_identify_fits_the_sheets_writes_them_and_refuses_free_links_without_priors_in_one_line(tmp_path):
    """The command line: dataset.json's `sheet` read, marker_scale fitted and written to a calibration file that
    offsets validates; --no-priors stops (exit 3) on one line naming the sheet to fix."""
    import csv
    import json

    from naocal.kinds.arm.sim import simulate_dualarm
    from tests.cli_runner import naocal

    out = tmp_path / "dual"
    simulate_dualarm(out, seed=2, n_poses=16, print_scale_error=0.01)
    with open(out / "observations.csv", newline="") as f:
        rows = [r for r in csv.reader(f)]
    column = rows[0].index("sensor")
    with open(out / "observations.csv", "w", newline="") as f:
        csv.writer(f, lineterminator="\n").writerows([rows[0]] + [r for r in rows[1:] if r[column] != "tracker"])
    assert json.loads((out / "dataset.json").read_text())["points"]["R_m1_c1"]["sheet"] == "R_sheet"
    effects = "joint_offsets,link_lengths,tool,points,marker_scale"
    cal = tmp_path / "cal.json"
    run = naocal("identify", out, "--effects", effects, "--out", cal)
    assert run.returncode == 0, run.stderr
    assert {"marker_scale.L_sheet", "marker_scale.R_sheet"} <= set(json.loads(cal.read_text())["model"]["parameters"])
    assert naocal("offsets", "validate", cal).returncode == 0
    run = naocal("identify", out, "--effects", effects, "--no-priors", "--out", tmp_path / "free.json")
    error = [line for line in run.stderr.splitlines() if "error" in line]
    assert run.returncode == 3 and len(error) == 1 and "--fix marker_scale." in error[0], run.stderr
    assert not (tmp_path / "free.json").exists()


def test_simulate_dualarm_print_scale_error_on_the_command_line(tmp_path):
    """`naocal simulate --robot dualarm --print-scale-error REL`: 0 prints exactly, a spread is drawn per sheet and kept
    in truth.json; NaN or beyond 5 % and another arm refused in one line, nothing written."""
    import json

    from tests.cli_runner import naocal

    exact = naocal("simulate", "--robot", "dualarm", "--print-scale-error", "0", "--poses", "10", "--out",
                   tmp_path / "exact")
    assert exact.returncode == 0, exact.stderr
    assert json.loads((tmp_path / "exact" / "truth.json").read_text())["print_scale"] == {"L_sheet": 1.0,
                                                                                         "R_sheet": 1.0}
    assert "marker_scale" not in json.loads((tmp_path / "exact" / "truth.json").read_text())["hidden"]
    drawn = naocal("simulate", "--robot", "dualarm", "--print-scale-error", "0.01", "--poses", "10", "--out",
                   tmp_path / "drawn")
    assert drawn.returncode == 0, drawn.stderr
    truth = json.loads((tmp_path / "drawn" / "truth.json").read_text())
    scales = truth["print_scale"]
    assert "marker_scale" in truth["hidden"]
    assert all(s != 1.0 and abs(s - 1.0) < 0.05 for s in scales.values())
    for value in ("nan", "0.2", "-0.01"):
        bad = naocal("simulate", "--robot", "dualarm", "--print-scale-error", value, "--out", tmp_path / value)
        assert bad.returncode == 2 and "--print-scale-error" in bad.stderr and bad.stderr.count("\n") == 1
        assert not (tmp_path / value).exists()
    other = naocal("simulate", "--robot", "franka_panda", "--chain", "panda_link0:panda_hand", "--print-scale-error",
                   "0.01", "--out", tmp_path / "panda")
    assert other.returncode == 2 and "--print-scale-error: only with --robot dualarm" in other.stderr


def test_diagnose_s_refits_keep_the_sheets_one_scale_each():
    """diagnose refits a model like the fitted one (kinds.arm.diagnose._model_like): its markers keep their sheets
    (they were dropped: a marker_scale candidate got one scale per marker, ten where the print has two)."""
    from naocal.kinds.arm.diagnose import _model_like
    from naocal.kinds.arm.sim import dualarm_markers, dualarm_model

    model = dualarm_model(("joint_offsets", "marker_scale"))
    assert len(model.sheet_names) == 2 and len(set(dualarm_markers().values())) > 2
    like = _model_like(model, ("joint_offsets", "marker_scale"), range(len(model.sensors)))
    assert like.sheet_names == model.sheet_names and like.sheets == model.sheets
