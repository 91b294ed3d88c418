"""encoders.csv as evidence in `naocal diagnose LOG` (kinds/duckiebot/drive_diagnostics.encoder_evidence, issue 23):
each wheel's turn from the encoders against the fitted model's ground travel of that wheel. The drives, the true
poses and the encoders come from the independent generator (tests/indep_drive_log.py: its motion and encoder rows,
no frames rendered); the "fitted model" is Duckietown's kinematics (gain, trim, baseline) fitted to the true poses at
the frames' times, what a camera-only fit sees: a slip in turns hides in a larger baseline there."""

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize import least_squares

from naocal.kinds.duckiebot.drive_diagnostics import DriveDiagnosis, encoder_evidence, format_diagnosis
from naocal.kinds.duckiebot.drive_log import read_encoders
from naocal.kinds.duckiebot.fit import Drive, trajectory
from tests.indep_drive_log import Variation, default_truth, encoder_rows, simulate

SMALL = Variation(turn_rate_radps=0.6, line_speed_mps=0.15, line_distance_m=0.4, n_markers=6, encoders=True,
                  encoder_start_ticks=(2 ** 31 - 60, -2 ** 31 + 60))  # counters wrapping around int32 at once
LOG_RADIUS_M, LOG_BASELINE_M = 0.0318, 0.1


def generated(tmp_path, **hidden):
    """(log: its encoders as read from encoders.csv, drive, the kinematics fitted to the true poses)."""
    truth = dataclasses.replace(default_truth(0), **hidden)
    wheel_rows, frame_t, poses_at = simulate(SMALL, truth)
    enc_t, ticks = encoder_rows(SMALL, wheel_rows, truth)
    path = tmp_path / "encoders.csv"
    path.write_text("t_s,left_ticks,right_ticks\n" + "".join(f"{t:.6f},{a},{b}\n" for t, a, b in zip(enc_t, *ticks)))
    wheels = SimpleNamespace(radius_m=LOG_RADIUS_M, baseline_m=LOG_BASELINE_M, k=27.0, limit=1.0,
                             ticks_per_revolution=135)
    t, left, right = read_encoders(path, wheels=wheels)
    log = SimpleNamespace(encoder_t_s=t, left_ticks=left, right_ticks=right, wheels=wheels)
    drive = Drive(*wheel_rows, frame_t, k=27.0, radius_m=LOG_RADIUS_M, baseline_m=LOG_BASELINE_M)
    true = poses_at(frame_t)

    def residual(x):
        poses, _ = trajectory(drive, *x, true[0], frame_t[0], frame_t)
        error = poses - true
        error[:, 2] *= 0.1  # 0.1 m a radian
        return error.ravel()

    x = least_squares(residual, [1.0, 0.0, LOG_BASELINE_M], x_scale=[0.1, 0.05, 0.003]).x
    return log, drive, dict(zip(("gain", "trim", "baseline_m"), x))


def test_a_clean_drive_agrees_with_its_encoders(tmp_path):
    log, drive, values = generated(tmp_path)
    evidence = encoder_evidence(log, drive, values)
    assert not evidence.slip and not evidence.radius_off, evidence
    assert set(evidence.phases) == {"straight", "curving", "in place"}
    assert abs(evidence.phases["straight"]["both"] - 1) < 0.01
    assert "no slip" in evidence.verdict


def test_a_hidden_slip_in_turns_is_seen_by_the_encoders(tmp_path):
    """15 % of the wheels' turning lost on the ground: the camera-only fit takes it up in its baseline (about
    0.102 / 0.85 m), the encoders say the wheels turned ~20 % more than the ground moved in turns, not straight."""
    log, drive, values = generated(tmp_path, turn_slip=0.15)
    assert values["baseline_m"] == pytest.approx(0.102 / 0.85, rel=0.03)  # hidden from the camera's fit
    evidence = encoder_evidence(log, drive, values)
    assert evidence.slip and not evidence.radius_off, evidence
    assert evidence.phases["in place"]["both"] == pytest.approx(0.102 / 0.1 / 0.85, rel=0.03)
    assert "slip in turns" in evidence.verdict
    text = format_diagnosis(DriveDiagnosis((), "plumb_bob", None, np.nan, np.nan, np.nan, [], [], np.nan,
                                           fit_error="x", encoders=evidence))
    assert "ENCODERS" in text and "evidence: slip in turns" in text


def test_a_wrong_radius_is_one_ratio_in_every_phase(tmp_path):
    """The wheels are 34.5 mm, log.json says 31.8: the encoders count 0.92 of the model's turn straight and in turns
    alike; the radius is named, slip is not."""
    log, drive, values = generated(tmp_path, radius_m=0.0345)
    evidence = encoder_evidence(log, drive, values)
    assert evidence.radius_off and not evidence.slip, evidence
    assert evidence.radius_ratio == pytest.approx(0.0318 / 0.0345, rel=0.01)
    assert "34.5" in evidence.verdict


def test_a_log_with_a_break_is_compared_segment_by_segment(tmp_path):
    """A run killed mid-command and resumed 5 s later (drive_log's segments.csv: the robot carried, its wheels not
    turning): the model drives each segment from rest by its own commands, and the interval across the break is left
    out. Integrated as one drive, the killed command would drive on through the pause where the encoders stand
    still."""
    log, drive, values = generated(tmp_path)
    moving = np.flatnonzero((drive.left_duty[:-1] != 0) & (drive.right_duty[:-1] != 0))
    k = int(moving[len(moving) // 2])
    cut, gap = (drive.wheel_t_s[k] + drive.wheel_t_s[k + 1]) / 2, 5.0

    def later(t):
        return np.where(t >= cut, t + gap, t)

    # the resumed run sends the killed command again (from rest) when it goes on
    wheel_t = np.concatenate([drive.wheel_t_s[:k + 1], [cut + gap], later(drive.wheel_t_s[k + 1:])])
    left = np.concatenate([drive.left_duty[:k + 1], [drive.left_duty[k]], drive.left_duty[k + 1:]])
    right = np.concatenate([drive.right_duty[:k + 1], [drive.right_duty[k]], drive.right_duty[k + 1:]])
    split = dataclasses.replace(drive, wheel_t_s=wheel_t, left_duty=left, right_duty=right,
                                frame_t_s=later(drive.frame_t_s), segment_t_s=(cut + gap / 2,))
    resumed = SimpleNamespace(**{**vars(log), "encoder_t_s": later(log.encoder_t_s)})
    evidence = encoder_evidence(resumed, split, values)
    assert not evidence.slip and not evidence.radius_off, evidence
    for phase in evidence.phases.values():
        assert abs(phase["both"] - 1) < phase["tolerance"], evidence.phases
    # the killed command (an in-place turn here) driven on through the pause: 5 s of turning the encoders never saw
    as_one_drive = encoder_evidence(resumed, dataclasses.replace(split, segment_t_s=()), values)
    assert as_one_drive.phases["in place"]["both"] < 0.8, as_one_drive.phases
    assert "in place: the wheels turned 3" in as_one_drive.verdict and "agree" not in as_one_drive.verdict
