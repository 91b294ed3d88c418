"""The LoLA driver against a fake LoLA on a real Unix socket (tests/lola_fakes.py), and its pure cycle controller."""

import math
import socket
import threading
import time

import msgpack
import numpy as np
import pytest

from naocal.backends.bridge import BridgeBackend
from naocal.backends.bridge_server import BridgeServer
from naocal.backends.errors import RobotFault
from naocal.backends.lola_driver import (CALIBRATED_MOTORS, CYCLE_S, LOLA_INDEX, LOLA_JOINTS, LOLA_LIMITS, MOTOR_OF, N_LOLA,
                                  BadReading, JointControl, LolaBackend, LolaFrame, pack_answer, parse_sensor_message)
from naocal.backends.v4l2_camera import V4L2Camera
from naocal.solver import limits
from naocal.backends.errors import RobotTimeout
from naocal.solver.errors import NaocalError, SafetyError
from naocal.solver.joints import JOINTS
from tests.backend_contract import check_backend_contract
from tests.lola_fakes import (BODY_ID, HEAD_ID, FakeLola, SimpleServos, SyntheticCapture, answer_series,
                              lola_speeds)

SPEEDS = limits.max_speeds()


@pytest.fixture
def lola_path(tmp_path):
    return str(tmp_path / "robocup")


@pytest.fixture
def fake(lola_path):
    with FakeLola(lola_path) as lola:
        yield lola


def answers(fake, since_t=-math.inf):
    """(times, positions (n, 25), stiffnesses (n, 25)) of every answer the fake received after `since_t`."""
    with fake.lock:
        return answer_series(list(fake.records), since_t)


def last_stiffness(fake) -> np.ndarray:
    """The stiffness of the newest answer (call with fake.lock held, as FakeLola.wait_for does)."""
    stiffness = answer_series(fake.records[-10:])[2]
    return stiffness[-1] if len(stiffness) else np.full(N_LOLA, np.nan)


# ---------------------------------------------------------------------------------------------- mapping
def test_readings_map_lola_order_to_joint_names_exactly(lola_path):
    distinct = {name: sum(LOLA_LIMITS[name]) / 2 + 0.001 * (i + 1) for i, name in enumerate(LOLA_JOINTS)}
    servos = SimpleServos()
    for name, angle in distinct.items():
        servos.q[LOLA_INDEX[name]] = angle
    with FakeLola(lola_path, servos):
        backend = LolaBackend(lola_path)
        try:
            reading = backend.read_joints()
            for name in JOINTS:
                lola_name = "LHipYawPitch" if name == "RHipYawPitch" else name  # one motor, one sensor
                assert reading.angles_rad[name] == float(np.float32(distinct[lola_name])), name
            status = backend.status()
            assert set(status["joints"]) == set(LOLA_JOINTS) | {"RHipYawPitch"}
            for name in LOLA_JOINTS:
                assert status["joints"][name]["raw_rad"] == float(np.float32(distinct[name])), name
                assert status["joints"][name]["temperature_c"] == 35.0
            assert status["robot"]["body_id"] == BODY_ID and status["robot"]["head_id"] == HEAD_ID
            assert backend.robot_identity()["head_id"] == HEAD_ID
        finally:
            backend.close()


def test_parse_sensor_message_names_the_bad_key():
    good = {"Position": [0.0] * 25, "Stiffness": [0.0] * 25, "Temperature": [30.0] * 25, "Status": [0] * 25,
            "Current": [0.0] * 25, "RobotConfig": ["b", "6.0.0.0", "h", "6.0.0.0"]}
    assert parse_sensor_message(good, 1.0).status == (0,) * 25
    lenient = parse_sensor_message({"Position": [0.1] * 25}, 1.0)  # a peer may leave out what it lacks
    assert lenient.position_rad == (0.1,) * 25 and lenient.robot_config == ("unknown",) * 4
    for key, value, match in [("Position", [0.0] * 24, "Position"), ("Temperature", [math.nan] * 25, "Temperature"),
                              ("Status", ["hot"] * 25, "Status"), ("RobotConfig", ["b"], "RobotConfig")]:
        with pytest.raises(ValueError, match=match):
            parse_sensor_message({**good, key: value}, 1.0)
    with pytest.raises(ValueError, match="map"):
        parse_sensor_message([1, 2, 3], 1.0)
    weird = parse_sensor_message({**good, "RobotConfig": ["../../etc\n", "6", "h" * 300, "6"]}, 1.0)
    assert weird.robot_config[0] == "../../etc" and len(weird.robot_config[2]) == 64  # printable, bounded


# ---------------------------------------------------------------------------------------------- every cycle
def test_every_message_gets_one_answer_and_readings_are_stamped_on_receipt(fake, lola_path):
    backend = LolaBackend(lola_path)
    try:
        before = time.monotonic()
        backend.wait_cycles(40)
        reading = backend.read_joints()
        assert before <= reading.t_s <= time.monotonic()
        stamps = []
        for _ in range(10):
            backend.wait_cycles(1)
            stamps.append(backend.read_joints().t_s)
        assert all(b > a for a, b in zip(stamps, stamps[1:]))
        assert np.median(np.diff(stamps)) == pytest.approx(CYCLE_S, abs=0.004)
    finally:
        backend.close()
    assert fake.wait_for(lambda f: not f.connected)
    # One answer per message received, none lost and none extra (the last message may be in flight at close).
    assert backend.messages_received - 1 <= fake.answers_received <= backend.messages_received
    assert fake.messages_sent - 1 <= backend.messages_received <= fake.messages_sent


def test_motion_is_gradual_at_the_requested_speed_and_reaches_the_target(fake, lola_path):
    backend = LolaBackend(lola_path)
    try:
        start = backend.read_joints().angles_rad
        backend.set_stiffness(list(JOINTS), 1.0)
        backend.wait_cycles(50)  # stiffened (0.5 s)
        targets = {"HeadYaw": 0.5, "LKneePitch": start["LKneePitch"] + 0.4, "RHipPitch": start["RHipPitch"] - 0.2}
        t_command = time.monotonic()
        backend.command(targets, 0.3)
        expected_s = max(abs(targets[j] - start[j]) / (0.3 * SPEEDS[j]) for j in targets)
        backend.sleep(expected_s + 0.2)
        reached = backend.read_joints().angles_rad
        t_end = time.monotonic()
    finally:
        backend.close()  # ramps stiffness down
    t, position, stiffness = answers(fake, t_command)
    position, stiffness = position[t < t_end], stiffness[t < t_end]
    steps = np.abs(np.diff(position, axis=0))
    for name in targets:
        i = LOLA_INDEX[name]
        assert steps[:, i].max() <= 0.3 * SPEEDS[name] * CYCLE_S * (1 + 1e-5), name  # one 12 ms step per cycle
        assert reached[name] == pytest.approx(targets[name], abs=1e-5), name
        # All joints of one command arrive together: a straight line in joint space.
        moving = np.flatnonzero(steps[:, i] > 1e-7)
        assert len(moving) == pytest.approx(expected_s / CYCLE_S, abs=2), name
    arms = [LOLA_INDEX[n] for n in LOLA_JOINTS if LOLA_INDEX[n] not in CALIBRATED_MOTORS]
    assert np.all(stiffness[:, arms] == 0.0)  # only the calibrated joints are ever stiffened
    assert np.all(stiffness[:, LOLA_INDEX["LHipYawPitch"]] > 0.9)  # both HipYawPitch names drive the one motor


def test_stiffening_a_joint_never_makes_it_jump(lola_path):
    servos = SimpleServos({"LKneePitch": 0.8})
    with FakeLola(lola_path, servos) as fake:
        backend = LolaBackend(lola_path, stiffen_s=0.2)
        try:
            backend.wait_cycles(10)
            limp = answers(fake)[1][-1]
            assert limp[LOLA_INDEX["LKneePitch"]] == pytest.approx(0.8, abs=1e-6)  # a limp joint: its own angle
            t0 = time.monotonic()
            backend.set_stiffness(["LKneePitch"], 1.0)
            backend.wait_cycles(30)
        finally:
            backend.close()
    _, position, stiffness = answers(fake, t0)
    i = LOLA_INDEX["LKneePitch"]
    assert np.all(np.abs(position[:, i] - 0.8) < 1e-6)
    rises = np.diff(stiffness[:, i])
    assert rises.max() <= CYCLE_S / 0.2 + 1e-6 and stiffness[:, i].max() == pytest.approx(1.0)


# ---------------------------------------------------------------------------------------------- refusals
@pytest.mark.parametrize("targets, match", [
    ({"LKneePitch": 3.0}, "LKneePitch target 3.0000 rad outside its limits"),
    ({"LKneePitch": math.nan}, "not a finite angle"),
    ({"LShoulderPitch": 0.0}, "unknown joint 'LShoulderPitch'"),
    ({"HeadYaw": 1.5, "HeadPitch": 0.4}, "HeadPitch 0.4000 rad outside"),
])
def test_unsafe_targets_are_refused_as_by_every_driver_and_nothing_moves(fake, lola_path, targets, match):
    from naocal.backends.mock import MockBackend

    backend = LolaBackend(lola_path)
    mock = MockBackend(0)
    try:
        backend.set_stiffness(list(JOINTS), 1.0)
        backend.wait_cycles(5)
        before = answers(fake)[1][-1]
        with pytest.raises(SafetyError, match=match) as lola_error:
            backend.command(targets, 0.5)
        with pytest.raises(SafetyError) as mock_error:
            mock.command(targets, 0.5)
        assert str(lola_error.value) == str(mock_error.value)  # one implementation: solver.limits.check_targets
        backend.wait_cycles(5)
        after = answers(fake)[1][-1]
    finally:
        backend.close()
        mock.close()
    assert np.array_equal(before, after)


def test_the_head_path_is_checked_not_only_its_ends(lola_path):
    # Yaw 0.903 -> 2.0 at pitch 0.30: both ends are inside the table (<= 0.33, <= 0.31), yaw 1.527 (<= 0.20) is not.
    with FakeLola(lola_path, SimpleServos({"HeadYaw": 0.903, "HeadPitch": 0.30})):
        backend = LolaBackend(lola_path)
        try:
            backend.set_stiffness(["HeadYaw", "HeadPitch"], 1.0)
            with pytest.raises(SafetyError, match="way to its target leaves the table"):
                backend.command({"HeadYaw": 2.0}, 0.2)
            backend.command({"HeadYaw": 0.5}, 0.2)  # the other way is clear
        finally:
            backend.close()


def test_a_joint_at_stiffness_zero_is_not_commanded(fake, lola_path):
    backend = LolaBackend(lola_path)
    try:
        with pytest.raises(SafetyError, match="stiffness 0"):
            backend.command({"HeadYaw": 0.1}, 0.5)
        for bad in (-0.1, 1.5, math.nan):
            with pytest.raises(SafetyError):
                backend.set_stiffness(["HeadYaw"], bad)
        with pytest.raises(SafetyError, match="unknown joint"):
            backend.set_stiffness(["LShoulderPitch"], 1.0)
    finally:
        backend.close()


# ---------------------------------------------------------------------------------------------- end of control
def test_release_holds_then_ramps_stiffness_down_and_never_jumps(fake, lola_path):
    backend = LolaBackend(lola_path, hold_s=0.5, ramp_s=0.6)
    try:
        backend.set_stiffness(list(JOINTS), 1.0)
        backend.wait_cycles(60)
        start = backend.read_joints().angles_rad
        backend.command({"LKneePitch": start["LKneePitch"] + 0.6}, 0.2)  # takes 0.47 s
        backend.sleep(0.15)
        t_release = time.monotonic()
        backend.release_control()  # mid-motion
        backend.sleep(1.6)
        assert backend.status()["robot"]["control"] == "limp"
    finally:
        backend.close()
    t, position, stiffness = answers(fake, t_release)
    t = t - t_release
    i = LOLA_INDEX["LKneePitch"]
    stiff = t < 0.5 - 2 * CYCLE_S
    assert np.ptp(position[stiff, i]) < 1e-6, "the joint holds where it was commanded when control ended"
    assert 0.0 < position[0, i] - start["LKneePitch"] < 0.6  # stopped mid-way, not sent on to the target
    assert np.all(stiffness[stiff][:, i] == pytest.approx(1.0))
    drops = -np.diff(stiffness[:, i])
    assert drops.max() <= CYCLE_S / 0.6 + 1e-6  # never faster than the ramp
    zero_at = t[np.flatnonzero(stiffness[:, i] == 0.0)[0]]
    assert zero_at == pytest.approx(0.5 + 0.6, abs=0.1)  # hold_s, then ramp_s
    assert np.abs(np.diff(position[t < zero_at, i])).max() < 1e-6  # no position jump while any stiffness is left


def test_the_bridge_releases_control_when_the_lease_of_a_silent_client_expires(fake, lola_path):
    backend = LolaBackend(lola_path, hold_s=0.3, ramp_s=0.3)
    server = BridgeServer(backend, "tcp://127.0.0.1:0", driver="lola", lease_timeout_s=1.5).start_thread()
    try:
        agent = BridgeBackend(server.endpoint, timeout_s=2.0)
        agent.set_stiffness(list(JOINTS), 1.0)
        agent.command({"HeadYaw": 0.05}, 0.5)
        assert agent.status()["robot"]["control"] == "active"
        t_silent = time.monotonic()  # the agent's last request
        assert fake.wait_for(lambda f: last_stiffness(f)[LOLA_INDEX["HeadYaw"]] > 0.1), "never stiffened"
        agent._drop_socket()  # the agent dies: no release, just silence
        assert fake.wait_for(lambda f: last_stiffness(f).max() == 0.0, timeout_s=8.0), "never limp"
        t_limp = time.monotonic() - t_silent
        assert 1.5 + 0.3 - 0.1 <= t_limp <= 5.5, t_limp  # lease, hold, ramp (of what stiffness there was)
        assert backend.status()["robot"]["control"] == "limp"
    finally:
        server.stop()
        backend.close()


def test_close_ramps_stiffness_down_before_disconnecting(fake, lola_path):
    backend = LolaBackend(lola_path, ramp_s=0.4)
    backend.set_stiffness(["HeadYaw"], 1.0)
    backend.wait_cycles(60)
    t_close = time.monotonic()
    backend.close()
    assert time.monotonic() - t_close >= 0.4 - 0.05
    _, _, stiffness = answers(fake, t_close)
    assert stiffness[-1].max() == 0.0 and -np.diff(stiffness[:, 0]).max() <= CYCLE_S / 0.4 + 1e-6
    assert fake.wait_for(lambda f: not f.connected)


# ---------------------------------------------------------------------------------------------- temperature
def test_a_hot_joint_pauses_motion_until_it_cools(fake, lola_path):
    backend = LolaBackend(lola_path)
    try:
        backend.set_stiffness(list(JOINTS), 1.0)
        backend.wait_cycles(60)
        start = backend.read_joints().angles_rad["LKneePitch"]
        backend.command({"LKneePitch": start + 0.5}, 0.1)  # 0.78 s
        backend.wait_cycles(15)
        with fake.lock:
            fake.status[LOLA_INDEX["LKneePitch"]] = 2
        backend.wait_cycles(3)
        with pytest.raises(NaocalError, match="LKneePitch is hot .*status 2"):
            backend.sleep(0.1)
        with pytest.raises(NaocalError, match="LKneePitch is hot"):
            backend.command({"HeadYaw": 0.0}, 0.1)
        paused_at = answers(fake)[1][-1][LOLA_INDEX["LKneePitch"]]
        backend.wait_cycles(20)
        assert answers(fake)[1][-1][LOLA_INDEX["LKneePitch"]] == paused_at  # no motion while hot
        assert "LKneePitch is hot" in backend.status()["robot"]["paused"]
        with fake.lock:
            fake.status[LOLA_INDEX["LKneePitch"]] = 1  # warm: a warning, motion goes on
        backend.wait_cycles(3)
        backend.sleep(1.0)
        assert backend.read_joints().angles_rad["LKneePitch"] == pytest.approx(start + 0.5, abs=1e-5)
    finally:
        backend.close()


# ---------------------------------------------------------------------------------------------- start-up
def test_no_socket_and_refused_connections_are_named(tmp_path, lola_path):
    with pytest.raises(NaocalError, match="no LoLA socket at .*robocup"):
        LolaBackend(lola_path)
    dead = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    dead.bind(lola_path)  # a socket file nobody listens on
    dead.close()
    with pytest.raises(NaocalError, match="connection refused"):
        LolaBackend(lola_path)


@pytest.mark.parametrize("second_client, match", [("silent", "sent nothing within 0.5 s.*serves one client"),
                                                  ("refuse", "connection refused")])
def test_a_second_client_is_refused_while_lola_serves_another(lola_path, second_client, match):
    with FakeLola(lola_path, second_client=second_client) as fake:
        first = LolaBackend(lola_path)
        try:
            t0 = time.monotonic()
            with pytest.raises(NaocalError, match=match):
                LolaBackend(lola_path, first_message_timeout_s=0.5)
            assert time.monotonic() - t0 < 2.0  # a deadline, not a hang
            first.wait_cycles(5)  # the first client is unaffected
        finally:
            first.close()
        assert fake.answers_received > 0


def test_a_peer_that_does_not_speak_lola_is_refused(lola_path):
    """HuLA's /tmp/hula sends raw C structs, not msgpack maps."""
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(lola_path)
    listener.listen(1)

    def serve():
        conn, _ = listener.accept()
        for _ in range(20):
            try:
                conn.sendall(np.arange(200, dtype=np.float32).tobytes())
            except OSError:
                break
            time.sleep(CYCLE_S)
        conn.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        with pytest.raises(NaocalError, match="does not speak LoLA"):
            LolaBackend(lola_path)
    finally:
        thread.join(2.0)
        listener.close()


def test_lola_falling_silent_is_a_fault(lola_path):
    with FakeLola(lola_path) as fake:
        backend = LolaBackend(lola_path, silence_timeout_s=0.2)
        backend.set_stiffness(["HeadYaw"], 1.0)
        backend.wait_cycles(5)
    # the fake stopped and closed the connection
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        try:
            backend.read_joints()
        except RobotTimeout as err:
            assert "LoLA" in str(err)
            break
        time.sleep(0.02)
    else:
        pytest.fail("a closed LoLA connection was not noticed")
    with pytest.raises(RobotTimeout):
        backend.command({"HeadYaw": 0.1}, 0.5)
    backend.close()
    assert fake.answers_received > 0


# ---------------------------------------------------------------------------------------------- hostile peer
def _set(key, joint, value):
    """A hostile LoLA: every message from now on carries `value` at `joint` in `key`."""
    def corrupt(message):
        message[key] = list(message[key])
        message[key][LOLA_INDEX[joint]] = value
        return message
    return corrupt


HOSTILE = {  # (what LoLA sends from now on, the error the driver then raises)
    "nan": (_set("Position", "LKneePitch", math.nan), RobotFault),
    "inf": (_set("Position", "LKneePitch", math.inf), RobotFault),
    "temperature-nan": (_set("Temperature", "LKneePitch", math.nan), RobotFault),
    "string": (_set("Position", "LKneePitch", "0.5"), RobotFault),  # msgpack decodes it as a str
    "bool": (_set("Position", "LKneePitch", True), RobotFault),
    "out-of-limit": (_set("Position", "LKneePitch", 2.5), RobotFault),  # its limit is 2.11 rad
    "huge": (_set("Position", "LKneePitch", 1e30), RobotFault),
    "frozen": (lambda message: None, RobotTimeout),
    "closing": (lambda message: "close", RobotTimeout),
}


@pytest.mark.parametrize("kind", list(HOSTILE))
def test_a_hostile_lola_is_a_fault_at_once_never_a_stale_or_impossible_reading_nor_a_command_outside_limits(
        fake, lola_path, kind):
    hostile, error = HOSTILE[kind]
    timeout_s = 0.25
    backend = LolaBackend(lola_path, silence_timeout_s=timeout_s, hold_s=0.1, ramp_s=0.2)
    served, stop = [], threading.Event()

    def poll():  # an agent reading all the time: what it is served, and how old it was when served
        while not stop.is_set():
            asked_s = time.monotonic()
            for call in (backend.read_joints, backend.status):
                try:
                    got = call()
                except NaocalError:
                    continue
                if isinstance(got, dict):
                    if got["robot"]["fault"] is None:
                        served.append((asked_s - got["t_s"], {j: e["raw_rad"] for j, e in got["joints"].items()}))
                else:
                    served.append((asked_s - got.t_s, got.angles_rad))
            time.sleep(0.001)

    poller = threading.Thread(target=poll, daemon=True)
    try:
        backend.set_stiffness(["HeadYaw"], 1.0)  # LKneePitch stays limp: LoLA echoes what it reads
        backend.wait_cycles(10)
        backend.command({"HeadYaw": 0.3}, 0.2)
        poller.start()
        backend.wait_cycles(5)
        t_hostile = time.monotonic()
        with fake.lock:
            fake.hostile = hostile
        deadline = t_hostile + timeout_s + 0.1
        while backend.status()["robot"]["fault"] is None:
            assert time.monotonic() < deadline, f"{kind}: no fault within {timeout_s} s"
            time.sleep(0.005)
        at_once_s = timeout_s + 0.1 if kind == "frozen" else 0.2  # a bad message: within a few cycles
        assert time.monotonic() - t_hostile <= at_once_s, backend.status()["robot"]["fault"]
        for motion in (lambda: backend.command({"HeadYaw": 0.0}, 0.2), lambda: backend.sleep(0.01),
                       lambda: backend.set_stiffness(["LKneePitch"], 1.0), backend.read_joints):
            with pytest.raises(error):
                motion()
        if kind not in ("frozen", "closing"):  # LoLA still talks: it is answered, held, then limp
            assert fake.wait_for(lambda f: last_stiffness(f).max() == 0.0, timeout_s=2.0), "not limp"
    finally:
        stop.set()
        if poller.is_alive():
            poller.join(2.0)
        backend.close()
    box = limits.joint_limits()
    assert served, "the poller was served nothing before the fault"
    for age_s, angles in served:
        assert age_s <= timeout_s, f"{kind}: a reading {age_s:.3f} s old was served (deadline {timeout_s} s)"
        assert limits.readings_problem(angles, box) is None
    _, position, stiffness = answers(fake)
    assert np.all(np.isfinite(position)) and np.all(np.isfinite(stiffness))
    lower, upper = np.array([LOLA_LIMITS[n] for n in LOLA_JOINTS]).T
    assert np.all((position >= lower - 1e-6) & (position <= upper + 1e-6)), \
        f"{kind}: LoLA was sent a position outside the limits: " + str(position[(position < lower - 1e-6) |
                                                                               (position > upper + 1e-6)][:5])


def test_a_reading_fault_reaches_the_agent_through_the_bridge(fake, lola_path):
    """`bridge status` names the fault; `command` and `sleep` no longer reply ok; a restarted bridge serves again."""
    backend = LolaBackend(lola_path, hold_s=0.1, ramp_s=0.1)
    server = BridgeServer(backend, "tcp://127.0.0.1:0", driver="lola").start_thread()
    agent = BridgeBackend(server.endpoint, timeout_s=2.0, retries=0)
    try:
        agent.set_stiffness(["HeadYaw"], 1.0)
        with fake.lock:
            fake.hostile = HOSTILE["nan"][0]
        assert fake.wait_for(lambda f: f.hostile_sent > 3)
        assert "cannot be trusted" in agent.status()["robot"]["fault"]
        with pytest.raises(RobotFault, match="LKneePitch reads nan"):
            agent.command({"HeadYaw": 0.1}, 0.5)
        with pytest.raises(RobotFault):
            agent.sleep(0.05)
        with pytest.raises(RobotFault):
            agent.read_joints()
    finally:
        agent.close()
        server.stop()
        backend.close()
    with fake.lock:
        fake.hostile = None
    assert fake.wait_for(lambda f: not f.connected)
    again = LolaBackend(lola_path)  # what "restart the bridge" does: a fresh driver, no fault
    try:
        assert again.status()["robot"]["fault"] is None and again.read_joints().t_s > 0
    finally:
        again.close()


def test_a_first_message_that_cannot_be_trusted_refuses_to_start(fake, lola_path):
    with fake.lock:
        fake.hostile = HOSTILE["out-of-limit"][0]
    with pytest.raises(RobotFault, match="first message cannot be trusted.*LKneePitch reads 2.5"):
        LolaBackend(lola_path)


def test_parse_sensor_message_refuses_what_is_not_a_plausible_number():
    good = {"Position": [0.0] * 25, "Stiffness": [0.0] * 25, "Temperature": [30.0] * 25, "Status": [0] * 25}
    knee = LOLA_INDEX["LKneePitch"]
    for key, value, match in [("Position", "0.5", "not a number"), ("Position", True, "not a number"),
                              ("Position", 2.5, "impossible"), ("Position", 1e30, "impossible"),
                              ("Position", -math.inf, "not a finite"), ("Temperature", "30", "not a number"),
                              ("Stiffness", 1.5, r"Stiffness outside \[0, 1\]"), ("Status", 7, "Status must be"),
                              ("Status", 1.5, "Status must be"), ("Status", False, "not a number")]:
        message = {k: list(v) for k, v in good.items()}
        message[key][knee] = value
        with pytest.raises(BadReading, match=match):
            parse_sensor_message(message, 1.0)
    inside = {k: list(v) for k, v in good.items()}
    inside["Position"][knee] = LOLA_LIMITS["LKneePitch"][1] + limits.READING_MARGIN_RAD - 1e-3  # at its stop
    assert parse_sensor_message(inside, 1.0).position_rad[knee] == pytest.approx(2.11255 + 0.249)


def test_every_position_sent_to_lola_is_inside_its_limits_whatever_the_controller_holds():
    sent = msgpack.unpackb(pack_answer(np.r_[2.5, 1e30, math.nan, np.zeros(N_LOLA - 3)], np.ones(N_LOLA)))
    lower, upper = np.array([LOLA_LIMITS[n] for n in LOLA_JOINTS]).T
    position, stiffness = np.array(sent["Position"]), np.array(sent["Stiffness"])
    assert np.all((position >= lower - 1e-6) & (position <= upper + 1e-6))
    assert stiffness[2] == 0.0 and stiffness[0] == 1.0  # a non-finite setpoint goes limp, never stiff


# ---------------------------------------------------------------------------------------------- the whole Backend
def test_the_lola_driver_passes_the_backend_contract(fake, lola_path):
    camera = V4L2Camera("bottom", open_capture=lambda device: SyntheticCapture(device))
    check_backend_contract(LolaBackend(lola_path, camera=camera, ramp_s=0.2), settle_s=0.6)


def test_the_lola_driver_refuses_a_camera_it_was_not_started_with_in_one_line(fake, lola_path):
    """The V4L2 camera is opened at start: capture('top') on a bottom-camera bridge is refused, naming both."""
    camera = V4L2Camera("bottom", open_capture=lambda device: SyntheticCapture(device))
    backend = LolaBackend(lola_path, camera=camera, ramp_s=0.2)
    try:
        with pytest.raises(NaocalError) as info:
            backend.capture("top")
        message = str(info.value)
        assert "top" in message and "bottom" in message and "\n" not in message
        assert backend.capture("bottom") is not None
    finally:
        backend.close()


def test_a_lola_bridge_says_it_offers_only_its_camera(fake, lola_path):
    """The agent plans top-camera stances only for a backend that offers the top camera."""
    camera = V4L2Camera("bottom", open_capture=lambda device: SyntheticCapture(device))
    backend = LolaBackend(lola_path, camera=camera, ramp_s=0.2)
    server = BridgeServer(backend, "tcp://127.0.0.1:0", driver="lola", clock="wall").start_thread()
    client = BridgeBackend(server.endpoint, timeout_s=3.0)
    try:
        assert backend.cameras == ("bottom",) and client.cameras == ("bottom",)
    finally:
        client.close()
        server.stop()
        backend.close()


def test_a_lola_bridge_serves_both_v4l2_cameras_each_from_its_own_device(fake, lola_path):
    opened = []

    def open_capture(device):
        opened.append(device)
        return SyntheticCapture(device)

    cameras = [V4L2Camera(name, open_capture=open_capture) for name in ("bottom", "top")]
    backend = LolaBackend(lola_path, cameras=cameras, ramp_s=0.2)
    server = BridgeServer(backend, "tcp://127.0.0.1:0", driver="lola", clock="wall").start_thread()
    client = BridgeBackend(server.endpoint, timeout_s=3.0)
    try:
        assert backend.cameras == ("bottom", "top") and client.cameras == ("bottom", "top")
        assert opened == []  # opened on first use
        assert client.capture("top") is not None or backend.capture("top") is not None
        assert opened == ["/dev/video-top"]
        assert backend.capture("bottom") is not None and opened == ["/dev/video-top", "/dev/video-bottom"]
    finally:
        client.close()
        server.stop()
        backend.close()


def test_a_camera_missing_at_start_is_named_when_asked_for(fake, lola_path):
    camera = V4L2Camera("bottom", open_capture=lambda device: SyntheticCapture(device))
    backend = LolaBackend(lola_path, cameras=[camera], missing_cameras={"top": "/dev/video-top"}, ramp_s=0.2)
    try:
        assert backend.cameras == ("bottom",)
        with pytest.raises(NaocalError, match="/dev/video-top was missing at start"):
            backend.capture("top")
    finally:
        backend.close()


def test_the_lola_driver_over_the_bridge_passes_the_backend_contract(fake, lola_path):
    camera = V4L2Camera("bottom", open_capture=lambda device: SyntheticCapture(device))
    backend = LolaBackend(lola_path, camera=camera, ramp_s=0.2)
    server = BridgeServer(backend, "tcp://127.0.0.1:0", driver="lola", clock="wall").start_thread()
    try:
        check_backend_contract(BridgeBackend(server.endpoint, timeout_s=3.0), settle_s=0.6)
    finally:
        server.stop()
        backend.close()


# ---------------------------------------------------------------------------------------------- the controller
def frame(position, status=None, t_s=0.0):
    return LolaFrame(t_s=t_s, position_rad=tuple(position), stiffness=(0.0,) * N_LOLA,
                     temperature_c=(40.0,) * N_LOLA, current_a=(0.0,) * N_LOLA,
                     status=tuple(status if status is not None else (0,) * N_LOLA), robot_config=("b", "6", "h", "6"))


def test_joint_control_hold_and_ramp_times_are_exact_in_cycles():
    control = JointControl({i: s for i, s in enumerate(lola_speeds())}, hold_s=0.12, ramp_s=0.24, stiffen_s=0.06)
    measured = np.linspace(-0.5, 0.5, N_LOLA)
    control.step(frame(measured))
    control.set_stiffness([MOTOR_OF["LKneePitch"]], 1.0)
    sent = [control.step(frame(measured)) for _ in range(5)]
    assert [round(s[1][MOTOR_OF["LKneePitch"]], 6) for s in sent] == [0.2, 0.4, 0.6, 0.8, 1.0]
    control.release()
    out = [control.step(frame(measured + 0.3)) for _ in range(40)]  # the leg sags: positions are still held
    i = MOTOR_OF["LKneePitch"]
    stiffness = [s[1][i] for s in out]
    assert stiffness[:9] == [1.0] * 9  # 10 cycles = 0.12 s held (the mode changes in the 10th)
    assert stiffness[9:29] == pytest.approx([1.0 - 0.05 * k for k in range(1, 21)])  # 20 cycles = 0.24 s ramp
    assert all(s[0][i] == pytest.approx(measured[i]) for s in out[:28])  # held while stiff ...
    assert out[30][0][i] == pytest.approx(measured[i] + 0.3)  # ... limp: follows the measurement
    assert control.mode == "limp"
