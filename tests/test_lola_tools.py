"""`naocal bridge serve --driver lola`, `naocal bridge status` and `naocal bridge move` as a team uses them: a fake
LoLA on a Unix socket in this process, the bridge and the tools as separate processes."""

import json
import math
import os
import selectors
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from naocal.backends.lola_driver import CYCLE_S, LOLA_INDEX, LOLA_JOINTS
from naocal.solver import limits
from tests.cli_runner import naocal_process
from tests.lola_fakes import BODY_ID, HEAD_ID, FakeLola, SimpleServos, answer_series

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SPEEDS = limits.max_speeds()


def naocal(*argv, timeout=60):
    return naocal_process(*argv, timeout=timeout)


class StuckServos(SimpleServos):
    """A robot whose joints do not follow their commands (a blocked leg, a cut motor)."""

    def advance(self, now_s):
        pass


@pytest.fixture
def robot(tmp_path, request):
    """(fake LoLA, endpoint) with `naocal bridge serve --driver lola` running against it."""
    path = str(tmp_path / "robocup")
    box = limits.joint_limits()  # distinct, and possible: inside each joint's limits
    distinct = {name: float(np.clip(0.01 * (i + 1) * (-1) ** i, box[name][0] + 0.01, box[name][1] - 0.01))
                for i, name in enumerate(LOLA_JOINTS)}
    servos = getattr(request, "param", SimpleServos)()
    for name, angle in distinct.items():
        servos.q[LOLA_INDEX[name]] = angle
    slow = request.node.get_closest_marker("lola_cycle_s")
    with FakeLola(path, servos, cycle_s=slow.args[0] if slow else CYCLE_S) as fake:
        fake.distinct = distinct
        server = subprocess.Popen([sys.executable, "-m", "naocal", "bridge", "serve", "--driver", "lola",
                                   "--lola-socket", path, "--bind", "tcp://127.0.0.1:0", "--hold-s", "0.5",
                                   "--ramp-s", "0.5", "--no-camera"],
                                  cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            selector = selectors.DefaultSelector()
            selector.register(server.stdout, selectors.EVENT_READ)
            assert selector.select(timeout=60), "the bridge did not start"
            line = server.stdout.readline()
            assert line.startswith("naocal bridge: serving lola on"), server.stderr.read()
            yield fake, line.split(" on ")[1].strip()
        finally:
            server.send_signal(signal.SIGTERM)
            try:
                server.wait(timeout=30)
            finally:
                if server.poll() is None:
                    server.kill()
                    server.wait()


def offsets_file(tmp_path, c):
    from naocal.solver.offsets import offsets_from_alpha, write_offsets

    alpha = {j: -c.get(j, 0.0) for j in ("LHipYawPitch", "LHipRoll", "LHipPitch", "LKneePitch", "LAnklePitch",
                                         "LAnkleRoll", "RHipYawPitch", "RHipRoll", "RHipPitch", "RKneePitch",
                                         "RAnklePitch", "RAnkleRoll", "HeadYaw", "HeadPitch")}
    offsets = offsets_from_alpha(alpha, (0.0, 0.0, 0.0), {leg: (0.0, 0.0, 0.0) for leg in "LR"},
                                 robot={"body_id": BODY_ID, "head_id": HEAD_ID},
                                 fit={"rms_px": [0.1, 0.1], "n_vertices": 1152, "n_images": 48})
    path = tmp_path / "offsets.json"
    write_offsets(offsets, path)
    return path


def test_status_json_maps_every_lola_joint_by_name(robot, tmp_path):
    fake, endpoint = robot
    c = {"LKneePitch": 0.02, "HeadYaw": -0.01, "RHipYawPitch": 0.005}
    result = naocal("bridge", "status", "--endpoint", endpoint, "--json", "--offsets", str(offsets_file(tmp_path, c)))
    assert result.returncode == 0, result.stderr
    data = json.loads(result.stdout)
    robot_info = data.pop("robot")
    assert (robot_info["body_id"], robot_info["head_id"]) == (BODY_ID, HEAD_ID)
    assert robot_info["body_version"] == robot_info["head_version"] == "6.0.0.0" and robot_info["driver"] == "lola"
    assert set(data) == set(LOLA_JOINTS) | {"RHipYawPitch"}
    for name, entry in data.items():
        raw = float(np.float32(fake.distinct["LHipYawPitch" if name == "RHipYawPitch" else name]))
        assert entry["raw_rad"] == raw, name  # exactly what LoLA sent, under the right name
        assert entry["corrected_rad"] == pytest.approx(raw - c.get(name, 0.0), abs=1e-12), name
        assert entry["stiffness"] == 0.0 and entry["temperature_c"] == 35.0 and entry["status"] == 0
    text = naocal("bridge", "status", "--endpoint", endpoint)
    assert text.returncode == 0 and "LKneePitch" in text.stdout and BODY_ID in text.stdout


def test_move_goes_gradually_through_the_offsets_and_releases(robot, tmp_path):
    fake, endpoint = robot
    c = {"HeadYaw": 0.03, "LKneePitch": -0.02}
    t0 = time.monotonic()
    result = naocal("bridge", "move", "--endpoint", endpoint, "--offsets", str(offsets_file(tmp_path, c)),
                    "HeadYaw=20", "LKneePitch=40")
    assert result.returncode == 0, result.stderr
    assert "HeadYaw: target 20.00 deg" in result.stdout
    assert fake.wait_for(lambda f: max(answer_series(f.records[-5:])[2][-1:].ravel(), default=1.0) == 0.0,
                         timeout_s=10.0)  # released: held, then ramped to 0
    with fake.lock:
        records = [r for r in fake.records if r["t"] >= t0]
    sent_messages = sum(r["client"] for r in records)
    _, position, stiffness = answer_series(records)
    assert sent_messages - 2 <= len(position) <= sent_messages + 1  # the bridge answered every message
    for name, target_deg in (("HeadYaw", 20.0), ("LKneePitch", 40.0)):
        i = LOLA_INDEX[name]
        command = math.radians(target_deg) + c[name]  # target + c
        assert position[:, i].max() == pytest.approx(command, abs=1e-6) if command > 0 else True
        steps = np.abs(np.diff(position[:, i]))
        assert steps.max() <= 0.1 * SPEEDS[name] * CYCLE_S * (1 + 1e-5), name  # default speed 0.1, every cycle
        low, high = limits.joint_limits()[name]
        assert np.all((position[:, i] >= low) & (position[:, i] <= high))
    moved = {LOLA_INDEX["HeadYaw"], LOLA_INDEX["LKneePitch"]}
    others = [i for i in range(len(LOLA_JOINTS)) if i not in moved]
    assert np.all(stiffness[:, others] == 0.0)  # only the named joints were stiffened
    assert np.abs(np.diff(stiffness[:, LOLA_INDEX["HeadYaw"]])).max() <= CYCLE_S / 0.5 + 1e-6  # ramps, no drop


@pytest.mark.parametrize("angles, match", [
    (["HeadYaw=100", "HeadPitch=25"], "HeadPitch 0.4363 rad outside .* HeadYaw 1.7453"),
    (["LKneePitch=130"], "LKneePitch target 2.2689 rad outside its limits"),
    (["LShoulderPitch=10"], "moves only .*not LShoulderPitch"),
    (["HeadYaw=abc"], "not a number"),
    (["HeadYaw"], "JOINT=ANGLE"),
    (["HeadYaw=1", "HeadYaw=2"], "HeadYaw given twice"),
])
def test_move_refuses_unsafe_or_bad_targets_before_anything_moves(robot, angles, match):
    fake, endpoint = robot
    with fake.lock:
        n_before = len(fake.records)
    result = naocal("bridge", "move", "--endpoint", endpoint, *angles)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr
    assert __import__("re").search(match, lines[0]), lines[0]
    with fake.lock:
        after = [r for r in fake.records[n_before:] if r["stiffness"] is not None]
    assert all(max(r["stiffness"]) == 0.0 for r in after)  # nothing was stiffened, nothing moved


def test_bad_tool_and_serve_arguments_are_one_line_errors(robot, tmp_path):
    fake, endpoint = robot
    for argv, match in [(["bridge", "move", "--endpoint", endpoint, "--speed", "0.9", "HeadYaw=1"], "--speed"),
                        (["bridge", "status", "--endpoint", endpoint, "--offsets", str(tmp_path / "no.json")],
                         "no.json"),
                        (["bridge", "serve", "--driver", "lola", "--lola-socket", str(tmp_path / "none")],
                         "no LoLA socket"),
                        (["bridge", "serve", "--driver", "lola", "--lola-socket", fake.path, "--hold-s", "-1"],
                         "--hold-s"),
                        (["bridge", "serve", "--driver", "lola", "--lola-socket", fake.path, "--cameras",
                          "bottom,side"], "--cameras")]:
        result = naocal(*argv)
        assert result.returncode == 2, argv
        assert match in result.stderr and "Traceback" not in result.stderr and \
            len(result.stderr.strip().splitlines()) == 1, result.stderr


@pytest.mark.parametrize("robot", [StuckServos], indirect=True)
def test_move_gives_up_at_its_deadline_when_a_joint_does_not_follow(robot):
    fake, endpoint = robot
    t0 = time.monotonic()
    result = naocal("bridge", "move", "--endpoint", endpoint, "--timeout-s", "0.5", "HeadYaw=5")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "not there within" in result.stderr and "HeadYaw reads" in result.stderr
    assert time.monotonic() - t0 < 20.0
    assert fake.wait_for(lambda f: max(answer_series(f.records[-5:])[2][-1:].ravel(), default=1.0) == 0.0,
                         timeout_s=10.0)  # released all the same: held, then ramped to 0


@pytest.mark.parametrize("cycle_s", [CYCLE_S, 4 * CYCLE_S])
def test_move_does_not_release_before_the_motion_has_reached_its_target(request, cycle_s):
    request.applymarker(pytest.mark.lola_cycle_s(cycle_s))  # 4x: a LoLA running slow (the driver steps per cycle)
    _release_at_target(request.getfixturevalue("robot"))


def _release_at_target(robot):
    """A joint reads within --tolerance-deg before the driver's interpolation ends; releasing then would freeze
    it short of the target (release holds where the joints are commanded at that moment)."""
    fake, endpoint = robot
    result = naocal("bridge", "move", "--endpoint", endpoint, "--tolerance-deg", "5", "HeadYaw=20")
    assert result.returncode == 0, result.stderr
    # The last answer can still be in the socket when `move` exits: the fake reads answers on its next tick.
    # Released short, the driver would hold short of 20 deg for ever and this wait would time out.
    def reached(f):
        _, position, _ = answer_series(f.records)
        return len(position) > 0 and abs(position[:, LOLA_INDEX["HeadYaw"]].max() - math.radians(20.0)) < 1e-6
    assert fake.wait_for(reached, timeout_s=2.0), answer_series(fake.records)[1][-3:, LOLA_INDEX["HeadYaw"]]
