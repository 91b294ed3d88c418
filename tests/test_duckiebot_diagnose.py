"""The mission's loop on the Duckiebot (issue 23): the wheel effects of the joint fit (exact Jacobians), the hidden
effects of the simulated drive, `naocal diagnose` naming a hidden dead zone, slip, speed-dependent trim and a wrong
lens model (each added brings the RMS to the clean drive's), nothing named on clean drives, and the simulate and
diagnose bodies on a rendered log. Full-size numbers: benchmarks/bench_duckiebot_diagnose.py."""

import argparse
import json
from types import SimpleNamespace

import numpy as np
import pytest
from test_duckiebot_fit import LOG_K, pwm_motor_poses, synthetic

from naocal.kinds.duckiebot.diagnose import LENS_CHOICES, parse_effects, run_diagnose
from naocal.kinds.duckiebot.drive_diagnostics import diagnose_fit, diagnose_lenses, format_diagnosis, lens_verdict
from naocal.kinds.duckiebot.fit import EFFECTS, PWM_DRIVER, DriveEquations, Sightings, fit_drive, trajectory
from naocal.kinds.duckiebot.intrinsics import LENS_MODELS, board_points, choose_lens
from naocal.kinds.duckiebot.render import (Renderer, calibration_scene, diagnose_program, hidden_robot,
                                           paper_program, simulate_drive)
from naocal.kinds.duckiebot.robot import camera_mount
from naocal.kinds.duckiebot.simulate import parse_hidden, run_simulate
from naocal.solver.effects import DRIVE_EFFECTS
from naocal.solver.effects import EFFECTS as REGISTRY
from naocal.solver.errors import NaocalError, SolveError

ALL_EFFECTS = {"dead_zone": 0.05, "slip_s_per_m": 0.3, "wheel_lag_s": 0.05, "speed_trim": 0.04}


def drive_of(seed, effects=None):
    """synthetic() through `naocal simulate`'s program (render.diagnose_program, without its board phase)."""
    return synthetic(seed, steps=diagnose_program(board_steps=0), effects=effects)


def in_log_units(robot, parameter, value):
    """A hidden effect's value as the fit sees it: speed_trim, as trim, in the log's k (fit of render's truth)."""
    return value * LOG_K / robot.kinematics.k if parameter == "speed_trim" else value


def central_difference(f, x, j, step=1e-6):
    plus, minus = x.copy(), x.copy()
    plus[j] += step
    minus[j] -= step
    return (f(plus) - f(minus)) / (2 * step)


@pytest.mark.parametrize("values", [ALL_EFFECTS, {**{n: 0.0 for n in ALL_EFFECTS}, "wheel_lag_s": 0.04}],
                         ids=["effects on", "at the base model"])
def test_the_trajectory_jacobian_with_every_effect_is_exact(values):
    """Every column (kinematics, anchor, each effect's parameter) against central differences, with the effects on
    and at 0 (where the score tests take them; the lag at a value: its derivative at 0 is 0 at rest)."""
    _, drive, _, _ = drive_of(2)
    names = list(values)
    x = np.array([1.1, 0.04, 0.102, 0.3, -0.2, 2.9] + [values[n] for n in names])
    anchor_t, times = drive.frame_t_s[3], drive.frame_t_s[3:]

    def poses(v):
        return trajectory(drive, *v[:3], v[3:6], anchor_t, times, dict(zip(names, v[6:])))

    _, J = poses(x)
    assert J.shape[2] == 10
    for j in range(len(x)):
        numeric = central_difference(lambda v: poses(v)[0], x, j)
        np.testing.assert_allclose(J[:, :, j], numeric, atol=1e-6, rtol=1e-5, err_msg=f"column {j}")
    assert np.abs(J[:, :, 6:]).max() > 0.01  # every effect moves the robot


@pytest.mark.parametrize("parameter", [p for e in DRIVE_EFFECTS for p in REGISTRY[e].drive_parameters()],
                         ids=lambda p: p.name)
def test_every_registered_wheel_parameter_has_an_exact_term_in_the_drive_model(parameter):
    """Issue 22: each parameter of a wheel effect module (solver/effects/, drive_parameters) moves the robot in
    the Duckiebot's drive model, its Jacobian column exact (a module without a term there would fail here, not fit
    a parameter of zero signature)."""
    _, drive, _, _ = drive_of(2)
    values = {"wheel_lag_s": 0.04, parameter.name: parameter.scale}  # a lag difference needs a lag
    names = list(values)
    x = np.array([1.1, 0.04, 0.102, 0.3, -0.2, 2.9] + [values[n] for n in names])
    anchor_t, times = drive.frame_t_s[3], drive.frame_t_s[3:]

    def poses(v):
        return trajectory(drive, *v[:3], v[3:6], anchor_t, times, dict(zip(names, v[6:])))

    j = 6 + names.index(parameter.name)
    column = poses(x)[1][:, :, j]
    np.testing.assert_allclose(column, central_difference(lambda v: poses(v)[0], x, j), atol=1e-6, rtol=1e-5)
    assert np.abs(column).max() > 1e-3


def test_the_equations_jacobian_with_effects_is_exact():
    """The corners' Jacobian columns of the kinematics and the effects, through the camera, against central
    differences (the other columns are fit.py's own test's; the lag's path to the pose is the trajectory's test)."""
    robot, drive, sightings, K = drive_of(1)
    fit = fit_drive(drive, sightings, K, 0.065, camera_mount())
    values = {n: v for n, v in ALL_EFFECTS.items() if n != "wheel_lag_s"}
    names, x = fit.names + list(values), np.concatenate([fit.x, list(values.values())])
    eq = DriveEquations(drive, sightings, K, 0.065, fit.reference_marker, names, x, np.ones(len(x), bool))
    _, J = eq.predict(x)
    for name in ("gain", "trim", "baseline_m", *values):
        j = names.index(name)
        numeric = central_difference(lambda v: eq.predict(v, jacobian=False)[0], x, j)
        np.testing.assert_allclose(J[:, :, j], numeric, atol=2e-4 * np.abs(J[:, :, j]).max(), rtol=1e-5,
                                   err_msg=name)


def test_a_fit_with_the_hidden_effects_recovers_them():
    """Dead zone, slip and speed trim hidden at once and fitted at once, then a wheel lag alone: each within 4
    stds (cluster-robust) of the truth."""
    for truth in ({"dead_zone": 0.06, "slip_s_per_m": 0.4, "speed_trim": 0.05}, {"wheel_lag_s": 0.08}):
        robot, drive, sightings, K = drive_of(2, effects=truth)
        effects = tuple(e for e, names in EFFECTS.items() if names[0] in truth)
        fit = fit_drive(drive, sightings, K, 0.065, camera_mount(), effects=effects)
        assert fit.success
        for name, value in truth.items():
            value = in_log_units(robot, name, value)
            assert abs(fit.value(name) - value) < 4 * fit.stdev(name), (name, fit.value(name), value, fit.stdev(name))


def diagnosed(seed, effects=None):
    """(diagnosis of the base model with refits, the clean drive's RMS, robot) of drive_of(seed, effects)."""
    robot, drive, sightings, K = drive_of(seed, effects)

    def refit(with_effects):
        return fit_drive(drive, sightings, K, 0.065, camera_mount(), effects=with_effects)

    _, clean_drive, clean_sightings, _ = drive_of(seed)
    floor = fit_drive(clean_drive, clean_sightings, K, 0.065, camera_mount()).rms_px
    return diagnose_fit(drive, refit(()), K, 0.065, refit=refit), floor, robot


@pytest.mark.parametrize("seed, effect, value", [(2, "dead_zone", 0.08), (2, "slip", 0.3), (2, "speed_trim", 0.08),
                                                 (3, "slip", 0.3)],
                         ids=["dead zone", "slip", "speed trim", "slip far from the floor"])
def test_a_hidden_effect_is_named_first_and_adding_it_reaches_the_floor(seed, effect, value):
    """The base model on a drive with one hidden effect: the effect named first, the RMS above the clean drive's;
    with it added, the RMS within 5 % of the clean drive's and its value within 3 stds of the truth. Seed 3's robot
    (trim -0.12) with slip: the base fit lands far off (10.8 px), no score is significant, the refits name it."""
    parameter = EFFECTS[effect][0]
    diagnosis, floor, robot = diagnosed(seed, {parameter: value})
    assert diagnosis.named == effect, [(t.effect, t.statistic, t.p_value, t.refit_rms_px) for t in diagnosis.tests]
    assert diagnosis.tests[0].effect == effect and diagnosis.rms_px > 1.5 * floor
    assert diagnosis.tests[0].confirmed_by_refit == (seed == 3)
    after = diagnosis.after
    assert after["rms_px"] < 1.05 * floor, (after["rms_px"], floor)
    fitted = after["values"][parameter]
    assert abs(fitted["value"] - in_log_units(robot, parameter, value)) < 3 * fitted["std"], fitted


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_a_clean_drive_names_nothing(seed):
    """No false alarm: the base model on a drive with nothing hidden names no effect (Bonferroni over the tests)."""
    diagnosis, _, _ = diagnosed(seed)
    assert diagnosis.named is None and diagnosis.after is None, [(t.effect, t.p_value) for t in diagnosis.tests]
    assert {t.effect for t in diagnosis.tests} == set(EFFECTS) | {PWM_DRIVER}


def with_expected_noise(sightings, noise_px=0.3):
    """synthetic()'s corners with their expected noise, as a log's detections have it (the whitened statistics')."""
    return Sightings(sightings.frame, sightings.marker, sightings.corner, sightings.uv_px,
                     np.full(len(sightings.frame), noise_px))


@pytest.mark.parametrize("seed", [1, 2])
def test_duckietowns_wheel_driver_is_named_only_where_the_duties_were_quantised(seed):
    """The duties through Duckietown's 8-bit driver (floored PWM; the motors start at its floor, PWM 60): the base
    model names the driver (its refit's likelihood ratio, drive_diagnostics.driver_test) and with it the RMS is the
    clean drive's; on the clean drive the driver fits worse and is not named."""
    def diagnosed_drive(pwm_start):
        _, drive, sightings, K = synthetic(seed, steps=diagnose_program(board_steps=0), pwm_start=pwm_start)
        sightings = with_expected_noise(sightings)

        def refit(effects):
            return fit_drive(drive, sightings, K, 0.065, camera_mount(), effects=effects)

        diagnosis = diagnose_fit(drive, refit(()), K, 0.065, refit=refit)
        return diagnosis, next(t for t in diagnosis.tests if t.effect == PWM_DRIVER)

    clean, clean_test = diagnosed_drive(None)
    assert clean.named is None and clean_test.statistic < 0 and not clean_test.significant
    quantised, test = diagnosed_drive(60.0)
    assert quantised.named == PWM_DRIVER, [(t.effect, t.statistic, t.p_value, t.refit_rms_px) for t in quantised.tests]
    assert test.p_value < quantised.threshold and quantised.rms_px > 1.03 * clean.rms_px
    assert quantised.after["added"] == [PWM_DRIVER] and quantised.after["rms_px"] < 1.02 * clean.rms_px


def test_the_simulated_drive_hides_duckietowns_wheel_driver():
    """`naocal simulate --hidden-effects pwm_driver`: the duties logged, the motors driven by the driver's floored PWM
    (the test's own small simulator, pwm_motor_poses, agrees to 1e-9 m); truth.json records it; off without it."""
    assert parse_hidden("pwm_driver") == {PWM_DRIVER: 1.0}
    robot = hidden_robot(2, {PWM_DRIVER: 1.0})
    assert robot.truth()["effects"] == {PWM_DRIVER: 1.0}
    steps = diagnose_program(board_steps=0)
    drive = simulate_drive(steps, robot.kinematics, effects=robot.effects)
    expected = pwm_motor_poses(drive, robot.kinematics, 60.0)
    assert np.abs(drive.frame_poses - expected).max() < 1e-9
    exact = simulate_drive(steps, robot.kinematics)
    assert np.abs(exact.frame_poses[:, :2] - expected[:, :2]).max() > 1e-3  # the floor matters: not a no-op
    assert np.array_equal(exact.left_duty, drive.left_duty)  # the duties logged are those sent


def board_views(hidden, noise_px=0.1):
    """(object points, image points, groups) of every board fully in view while the hidden robot turns in one-wheel
    steps (the paper's board phase), projected through its lens (no rendering) plus noise."""
    robot, scene = hidden_robot(1, hidden), calibration_scene()
    renderer = Renderer(scene, robot.camera, robot.T_base_camera, supersample=1, lens=robot.lens)
    drive = simulate_drive(paper_program(board_steps=4, marker_drives=0), robot.kinematics)
    corners = scene.board_corners()
    rng = np.random.default_rng(7)
    obj = board_points(scene.inner_corners, scene.square_m)
    views = []
    for pose in drive.frame_poses:
        uv, front = renderer.project(pose, corners)
        for b in np.flatnonzero(np.all(front & renderer.in_image(uv, margin_px=10.0), axis=(1, 2))):
            views.append(uv[b].reshape(-1, 2) + rng.normal(0.0, noise_px, (obj.shape[0], 2)))
    groups = np.arange(len(views)) * 3 // len(views)
    return [obj] * len(views), views, groups


@pytest.mark.parametrize("hidden, wrong", [({"wide_lens": 1.0}, True), ({}, False)], ids=["wide lens", "plumb_bob"])
def test_the_wrong_lens_model_is_named_by_the_held_out_error(hidden, wrong):
    """A 150-degree fisheye: plumb_bob's held-out board error several times the fisheye's, the wrong lens model
    named; a plumb_bob lens: plumb_bob kept."""
    obj, views, groups = board_views(hidden)
    assert len(views) >= 6
    _, fits = choose_lens(obj, views, (640, 480), groups)
    verdict = lens_verdict(fits, "plumb_bob")
    assert verdict.wrong == wrong, verdict
    if wrong:
        assert verdict.best == "fisheye" and verdict.ratio > 2  # 2.8 with the own-LM plumb_bob (k3 = 0); the verdict needs 1.5


def test_bad_hidden_and_effects_are_refused_in_one_line():
    assert parse_hidden("dead_zone=0.05,slip") == {"dead_zone": 0.05, "slip": 0.5}
    for text, message in [("wobble", "unknown Duckiebot effect 'wobble'"), ("slip=fast", "is not a number"),
                          ("slip=nan", "finite"), ("dead_zone=0.3", "below 0.2"), ("slip,,", "empty name")]:
        with pytest.raises(NaocalError, match=message):
            parse_hidden(text)
    assert parse_effects("slip,dead_zone") == ("dead_zone", "slip")
    assert parse_effects("pwm_driver,dead_zone") == ("dead_zone", PWM_DRIVER)  # the driver model: identify --effects
    assert LENS_CHOICES == LENS_MODELS  # --lens's choices, listed without importing cv2
    with pytest.raises(NaocalError, match="unknown Duckiebot effect 'camera_tilt'"):
        parse_effects("camera_tilt")


@pytest.mark.slow
def test_simulate_then_diagnose_a_clean_rendered_log(tmp_path, capsys):
    """`naocal simulate --robot duckiebot` writes a drive log and its truth; `naocal diagnose` on it (rendered,
    detected, lens fitted, joint fit) names nothing, and its encoders' evidence says no slip; a second simulate into the same directory is refused and
    changes nothing."""
    out = tmp_path / "LOG"
    assert run_simulate(argparse.Namespace(seed=1, out=str(out), hidden_effects="")) == 0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["effects"] == {} and truth["lens"]["model"] == "plumb_bob"
    assert (out / "log.json").exists() and (out / "wheels.csv").exists()
    before = sorted(p.name for p in out.iterdir())
    with pytest.raises(NaocalError, match="not an empty directory"):
        run_simulate(argparse.Namespace(seed=2, out=str(out), hidden_effects="slip"))
    assert sorted(p.name for p in out.iterdir()) == before
    capsys.readouterr()
    assert run_diagnose(argparse.Namespace(dataset=str(out), effects="", lens="plumb_bob", json=True)) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["named"] is None and report["after"] is None
    assert report["lens_verdict"]["best"] in ("plumb_bob", "rational") and not report["lens_verdict"]["wrong"]
    assert [t["effect"] for t in report["tests"] if t["significant"]] == []
    # its encoders.csv agrees with the fitted model: evidence of neither slip nor a wrong radius
    assert report["encoders"] is not None and "straight" in report["encoders"]["phases"]
    assert not report["encoders"]["slip"] and not report["encoders"]["radius_off"], report["encoders"]


def test_a_marker_tied_to_no_other_is_set_aside():
    """A frame seeing only a marker no other frame sees (no start value: start_values chains markers through shared
    frames) is set aside with the outliers; it was a KeyError (hidden slip on seed 3's robot)."""
    _, drive, sightings, K = synthetic(1)
    frame = sightings.frame[-1]
    marker = np.where(sightings.frame == frame, 99, sightings.marker)
    lonely = Sightings(sightings.frame, marker, sightings.corner, sightings.uv_px)
    fit = fit_drive(drive, lonely, K, 0.065, camera_mount())
    assert fit.success and set(fit.outliers.marker) == {99} and 99 not in set(fit.sightings.marker)
    assert not any(n.startswith("marker99.") for n in fit.names)


def test_a_wrong_lens_that_leaves_the_joint_fit_undetermined_is_still_named():
    """Seed 3's wide-lens log: the plumb_bob fitted to its boards put the principal point 116 px low (cy 335 px for
    219), the first marker's rays then miss the floor, the start puts it 60 km away and the joint fit through
    plumb_bob cannot be made (17 undetermined combinations). The lens is judged by the board views alone: the
    diagnosis names it, says why the fit could not be made, and the refit with the right lens reaches the noise
    (0.3 px). `naocal diagnose` refused the whole log. Without a wrong lens to name, the SolveError is the answer."""
    _, drive, sightings, K = drive_of(3)
    plumb_bob = K.copy()
    plumb_bob[1, 2] += 116.0
    cameras = {"plumb_bob": plumb_bob, "fisheye": K}  # the corners rectified with each: only K differs here

    def fit_with(lens, effects, start=None):
        return fit_drive(drive, sightings, cameras[lens], 0.065, camera_mount(), effects=effects,
                         start=start), cameras[lens]

    def held_out(**rms_px):  # the lens fits as lens_verdict reads them
        return {m: SimpleNamespace(held_out_rms_px=v) for m, v in rms_px.items()}

    with pytest.raises(SolveError, match="cannot determine"):
        fit_with("plumb_bob", ())
    wide = held_out(plumb_bob=0.376, rational=0.239, fisheye=0.039)  # seed 3's wide-lens log's, px
    diagnosis = diagnose_lenses(drive, fit_with, 0.065, (), "plumb_bob", wide)
    assert diagnosis.named == "lens=fisheye" and diagnosis.fit is None
    assert "cannot determine" in diagnosis.fit_error
    assert "error" not in diagnosis.after and diagnosis.after["rms_px"] < 0.33, diagnosis.after
    text = format_diagnosis(diagnosis, "LOG")
    assert "the joint fit cannot be made: the data cannot determine" in text
    assert "add it: naocal diagnose LOG --lens fisheye" in text and "without it the fit could not be made" in text
    json.dumps(diagnosis.as_dict(), default=float)
    with pytest.raises(SolveError, match="cannot determine"):
        diagnose_lenses(drive, fit_with, 0.065, (), "plumb_bob", held_out(plumb_bob=0.04, fisheye=0.039))


def test_a_candidate_whose_refit_cannot_be_made_is_reported_not_named():
    """A significant candidate whose refit the data cannot determine is no remedy: not named, and the report says
    why (the SolveError's words) instead of dropping it silently."""
    _, drive, sightings, K = drive_of(2, {"slip_s_per_m": 0.3})

    def refit(effects):
        if "slip" in effects:
            raise SolveError("the data cannot determine 1 parameter combination(s) (slip_s_per_m)")
        return fit_drive(drive, sightings, K, 0.065, camera_mount(), effects=effects)

    diagnosis = diagnose_fit(drive, refit(()), K, 0.065, refit=refit)
    slip = next(t for t in diagnosis.tests if t.effect == "slip")
    assert diagnosis.named != "slip" and not slip.significant
    assert slip.refit_error.startswith("the data cannot determine")
    assert "slip" in format_diagnosis(diagnosis) and "its refit cannot be made: the data cannot" in \
        format_diagnosis(diagnosis)
