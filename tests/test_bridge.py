"""The bridge client and server over real ZeroMQ sockets on 127.0.0.1 (ephemeral ports), against a fake robot."""

import math
import os
import subprocess
import sys
import time

import msgpack
import numpy as np
import pytest
import zmq

from naocal.backends import protocol
from naocal.backends.base import CameraImage, CameraIntrinsics
from naocal.backends.bridge import BridgeBackend
from naocal.backends.bridge_server import DEFAULT_BIND, BridgeServer, check_bind_address, write_curve_keys
from naocal.backends.protocol import ControlError, ProtocolError
from naocal.backends.errors import BridgeError, RobotFault
from naocal.solver.errors import SafetyError
from naocal.solver.errors import NaocalError
from tests.backend_contract import check_backend_contract
from tests.bridge_fakes import CLI, ROOT, FakeBackend, serving



def raw_request(endpoint, payload_frames, timeout_s=1.0):
    """Send raw frames on a fresh DEALER socket; the decoded reply, or None if none came."""
    socket = zmq.Context.instance().socket(zmq.DEALER)
    socket.setsockopt(zmq.LINGER, 0)
    socket.connect(endpoint)
    try:
        socket.send_multipart(payload_frames)
        if not socket.poll(timeout_s * 1000):
            return None
        return msgpack.unpackb(socket.recv_multipart()[-1], raw=False)
    finally:
        socket.close(linger=0)


# ---------------------------------------------------------------------------------------------- protocol
def test_image_round_trip_is_exact_and_writable():
    pixels = np.random.default_rng(1).integers(0, 256, (480, 640, 3), dtype=np.uint8)
    wire = protocol.unpack(protocol.pack(protocol.image_to_wire(CameraImage(pixels, 12.25))), max_bytes=2 << 20)
    image = protocol.image_from_wire(wire)
    assert np.array_equal(image.pixels, pixels) and image.pixels.dtype == np.uint8
    assert image.t_exposure_s == 12.25 and image.camera == "bottom"
    image.pixels[0, 0, 0] = 7  # consumers may draw on it
    wire["shape"] = [480, 640, 4]
    with pytest.raises(ProtocolError, match="cannot hold"):
        protocol.image_from_wire(wire)
    wire["shape"], wire["dtype"] = [480, 640, 3], "float64"
    with pytest.raises(ProtocolError):
        protocol.image_from_wire(wire)


@pytest.mark.parametrize("change, message", [
    (dict(fx_px=float("nan")), "the intrinsics reply, field 'fx_px': expected a finite number, got nan"),
    (dict(width_px=True), "the intrinsics reply, field 'width_px': expected a finite number, got True"),
    (dict(height_px=480.5), "field 'height_px': expected a whole number, got 480.5"),
    (dict(cy_px=-1.0), "the intrinsics reply, field 'cy_px': principal point outside the 640 x 480 image, got -1.0"),
    (dict(distortion=[0.1, "x", 0, 0, 0]), "field 'distortion[1]': expected a finite number, got 'x'"),
    (dict(skew=0.0), "the intrinsics reply, field 'skew': unknown field"),
])
def test_the_servers_intrinsics_are_checked_field_by_field_before_use(change, message):
    wire = protocol.unpack(protocol.pack(CameraIntrinsics(640, 480, 600.0, 600.0, 319.5, 239.5).to_dict()),
                           max_bytes=1 << 16)
    assert protocol.intrinsics_from_wire(wire) == CameraIntrinsics(640, 480, 600.0, 600.0, 319.5, 239.5)
    with pytest.raises(ProtocolError) as refused:
        protocol.intrinsics_from_wire({**wire, **change})
    assert message in str(refused.value), str(refused.value)


@pytest.mark.parametrize("change, message", [
    (dict(t_exposure_s=float("inf")), "the image reply, field 't_exposure_s': expected a finite number, got inf"),
    (dict(camera="side"), "the image reply, field 'camera': expected one of bottom, top, got 'side'"),
    (dict(shape=[480, 640, 3.0]), "field 'shape[2]': expected a whole number from 1 to 65536, got 3.0"),
])
def test_the_servers_images_are_checked_field_by_field_before_use(change, message):
    wire = protocol.unpack(protocol.pack(protocol.image_to_wire(CameraImage(np.zeros((480, 640, 3), np.uint8), 1.0))),
                           max_bytes=2 << 20)
    with pytest.raises(ProtocolError) as refused:
        protocol.image_from_wire({**wire, **change})
    assert message in str(refused.value), str(refused.value)


@pytest.mark.parametrize("error, message", [
    ({"type": "NaocalError", "message": "two\nlines"}, "field 'error.message': expected a single line of printable"),
    ({"type": "NaocalError", "message": "x" * 501}, "field 'error.message': expected a single line"),
    ({"type": 7, "message": "m"}, "field 'error.type': expected a non-empty single line"),
    ({"type": "NaocalError"}, "field 'error.message': missing required field"),
])
def test_an_error_reply_is_checked_before_the_client_echoes_it(error, message):
    reply = {"v": 1, "id": "c:1", "ok": False, "error": error}
    with pytest.raises(ProtocolError) as refused:
        protocol.validate_reply(reply, "c:1")
    assert message in str(refused.value), str(refused.value)
    assert protocol.validate_reply({**reply, "error": {"type": "NaocalError", "message": "one line"}}, "c:1")


def test_requests_with_keys_in_the_wrong_unit_or_type_are_refused():
    good = protocol.make_request("c1:1", "command", {"targets_rad": {"HeadYaw": 0.1}, "speed_fraction": 0.2})
    assert protocol.validate_request(good)[1] == "command"
    wrong_unit = protocol.make_request("c1:1", "command", {"targets_deg": {"HeadYaw": 5.0}, "speed_fraction": 0.2})
    with pytest.raises(ProtocolError, match="targets_deg"):
        protocol.validate_request(wrong_unit)
    for version in (True, 1.0, "1", 2):
        with pytest.raises(ProtocolError) as err:
            protocol.validate_request({**good, "v": version})
        assert err.value.error_type == "UnsupportedVersion"
    with pytest.raises(ProtocolError):
        protocol.validate_request({**good, "args": {"targets_rad": {"HeadYaw": "0.1"}, "speed_fraction": 0.2}})
    with pytest.raises(ProtocolError) as err:
        protocol.validate_request({**good, "cmd": "reboot"})
    assert err.value.error_type == "UnknownCommand"


def test_request_ids_are_client_and_sequence():
    assert protocol.parse_request_id("a1-b.c_d:42") == ("a1-b.c_d", 42)
    for bad in ("42", "a:", ":1", "a:b", "a b:1", "x" * 65 + ":1", 7, None):
        with pytest.raises(ProtocolError):
            protocol.parse_request_id(bad)


# ---------------------------------------------------------------------------------------------- client + server
def test_bridge_client_passes_the_backend_contract():
    fake = FakeBackend()
    with serving(fake) as server:
        check_backend_contract(BridgeBackend(server.endpoint, timeout_s=1.0))
    assert fake.executed["command"] == 2  # the contract's two valid moves, each executed once
    assert not fake.closed  # the server owns the robot; a client's close does not close it


def test_the_bridge_returns_exactly_what_the_backend_returns():
    direct, remote = FakeBackend(seed=3), FakeBackend(seed=3)

    def run(backend):
        out = [backend.robot_identity(), backend.joint_limits(), backend.max_speeds(), backend.intrinsics()]
        backend.sleep(0.1)
        backend.command({"LKneePitch": 1.2, "HeadYaw": -0.3}, 0.25)
        for step_s in (0.013, 0.2, 0.31):
            backend.sleep(step_s)
            reading = backend.read_joints()
            image = backend.capture()
            out += [reading.angles_rad, reading.t_s, backend.now(), image.t_exposure_s, image.pixels.tobytes()]
        out.append(list(backend.gravity_torso_mps2()))
        return out

    expected = run(direct)
    with serving(remote) as server:
        assert run(BridgeBackend(server.endpoint, timeout_s=1.0)) == expected


def test_server_side_safety_errors_come_back_as_safety_errors_and_the_server_lives_on():
    fake = FakeBackend()
    with serving(fake) as server:
        bridge = BridgeBackend(server.endpoint, timeout_s=1.0)
        with pytest.raises(SafetyError, match="LKneePitch"):
            bridge.command({"LKneePitch": 3.0}, 0.1)
        with pytest.raises(SafetyError):
            bridge.command({"LKneePitch": math.nan}, 0.1)
        with pytest.raises(SafetyError, match="NoSuchJoint"):
            bridge.command({"NoSuchJoint": 0.0}, 0.1)
        bridge.command({"LKneePitch": 0.5}, 0.1)
        assert fake.executed["command"] == 1
        with pytest.raises(ValueError):
            bridge.sleep(-1.0)


def test_one_client_controls_motion_others_may_read():
    fake = FakeBackend()
    with serving(fake, lease_timeout_s=60.0) as server:
        first = BridgeBackend(server.endpoint, timeout_s=1.0, client_id="first")
        second = BridgeBackend(server.endpoint, timeout_s=1.0, client_id="second")
        first.command({"HeadYaw": 0.2}, 0.5)
        with pytest.raises(ControlError, match="another client controls the robot"):
            second.command({"HeadYaw": -0.2}, 0.5)
        with pytest.raises(ControlError):
            second.sleep(0.1)
        assert second.read_joints().angles_rad.keys() == first.read_joints().angles_rad.keys()
        assert second.server_info()["controlled"] is True  # but not by whom
        first.close()  # releases
        second.command({"HeadYaw": -0.2}, 0.5)
        assert [targets for targets, _ in fake.commands] == [{"HeadYaw": 0.2}, {"HeadYaw": -0.2}]


def test_an_idle_controller_loses_the_lease_after_the_timeout():
    fake = FakeBackend()
    with serving(fake, lease_timeout_s=0.15) as server:
        first = BridgeBackend(server.endpoint, timeout_s=1.0, client_id="first")
        second = BridgeBackend(server.endpoint, timeout_s=1.0, client_id="second")
        first.command({"HeadYaw": 0.2}, 0.5)
        with pytest.raises(ControlError):
            second.command({"HeadYaw": -0.2}, 0.5)
        time.sleep(0.2)
        second.command({"HeadYaw": -0.2}, 0.5)
        with pytest.raises(ControlError, match="another client controls the robot"):
            first.command({"HeadYaw": 0.2}, 0.5)
    assert [targets for targets, _ in fake.commands] == [{"HeadYaw": 0.2}, {"HeadYaw": -0.2}]


def test_binding_beyond_loopback_needs_an_explicit_flag():
    for local in ("tcp://127.0.0.1:7790", "tcp://localhost:7790", "tcp://[::1]:7790", "ipc:///tmp/naocal"):
        check_bind_address(local, allow_remote=False)
    for remote in ("tcp://0.0.0.0:7790", "tcp://*:7790", "tcp://192.168.1.10:7790", "tcp://eth0:7790"):
        with pytest.raises(NaocalError, match="--allow-remote"):
            check_bind_address(remote, allow_remote=False)
        check_bind_address(remote, allow_remote=True)
    with pytest.raises(NaocalError, match="--allow-remote"):
        BridgeServer(FakeBackend(), "tcp://0.0.0.0:0")
    with serving(FakeBackend(), "tcp://0.0.0.0:0", allow_remote=True) as server:
        port = server.endpoint.rsplit(":", 1)[1]
        assert BridgeBackend(f"tcp://127.0.0.1:{port}", timeout_s=1.0).now() == 0.0


def test_requests_over_the_size_limit_get_an_error_reply_and_huge_ones_do_not_hurt(monkeypatch):
    fake = FakeBackend()
    with serving(fake) as server:
        big = protocol.pack(protocol.make_request("c:1", "now", {"pad": "x" * (protocol.MAX_REQUEST_BYTES + 10)}))
        reply = raw_request(server.endpoint, [b"", big])
        assert reply["ok"] is False and reply["error"]["type"] == "TooLarge"
        huge = b"\x00" * (protocol.ZMQ_MAX_INBOUND_BYTES + 1)  # libzmq drops this peer: no reply at all
        assert raw_request(server.endpoint, [b"", huge], timeout_s=0.3) is None
        assert BridgeBackend(server.endpoint, timeout_s=1.0).now() == 0.0
        # The client refuses to send an oversized request in the first place.
        monkeypatch.setattr(protocol, "MAX_REQUEST_BYTES", 100)
        with pytest.raises(BridgeError, match="too large"):
            BridgeBackend(server.endpoint, timeout_s=1.0).command({f"J{i}": 0.0 for i in range(20)}, 0.1)


def test_a_req_socket_is_served_too():
    with serving(FakeBackend()) as server:
        socket = zmq.Context.instance().socket(zmq.REQ)
        socket.setsockopt(zmq.LINGER, 0)
        socket.connect(server.endpoint)
        socket.send(protocol.pack(protocol.make_request("req:1", "now")))
        assert socket.poll(1000)
        reply = protocol.unpack(socket.recv(), max_bytes=1 << 20)
        socket.close()
    assert reply == {"v": 1, "id": "req:1", "ok": True, "result": 0.0}


# ---------------------------------------------------------------------------------------------- CURVE
def test_curve_encrypts_and_authenticates(tmp_path):
    server_public, server_secret = write_curve_keys(tmp_path / "server", "server")
    other_public, _ = write_curve_keys(tmp_path / "other", "server")
    with pytest.raises(NaocalError, match="already exists"):
        write_curve_keys(tmp_path / "server", "server")
    assert oct(os.stat(server_secret).st_mode & 0o777) == "0o600"
    with serving(FakeBackend(), curve_secret_key_file=server_secret) as server:
        assert BridgeBackend(server.endpoint, timeout_s=1.0, curve_server_key=server_public).now() == 0.0
        with pytest.raises(BridgeError, match="the server requires CURVE keys"):
            BridgeBackend(server.endpoint, timeout_s=2.0, retries=0).now()  # plain text: refused
        with pytest.raises(BridgeError, match="CURVE handshake failed: is .*server.key the public key"):
            BridgeBackend(server.endpoint, timeout_s=2.0, retries=0, curve_server_key=other_public).now()


def test_curve_can_admit_known_clients_only(tmp_path):
    server_public, server_secret = write_curve_keys(tmp_path / "server", "server")
    client_public, client_secret = write_curve_keys(tmp_path / "clients", "agent")
    _, stranger_secret = write_curve_keys(tmp_path / "strangers", "stranger")
    with serving(FakeBackend(), curve_secret_key_file=server_secret, curve_clients_dir=tmp_path / "clients") as server:
        known = BridgeBackend(server.endpoint, timeout_s=1.0, curve_server_key=server_public,
                              curve_client_key=client_secret)
        assert known.now() == 0.0
        stranger = BridgeBackend(server.endpoint, timeout_s=2.0, retries=0, curve_server_key=server_public,
                                 curve_client_key=stranger_secret)
        with pytest.raises(BridgeError, match="does not admit this client's CURVE key"):
            stranger.now()


# ---------------------------------------------------------------------------------------------- CLI
def run_cli(*argv, timeout_s=30):
    return subprocess.run([sys.executable, "-c", CLI, *argv], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout_s)


def test_ping_of_nothing_fails_with_one_line():
    with zmq.Context.instance().socket(zmq.ROUTER) as placeholder:  # a free port nobody serves on
        port = placeholder.bind_to_random_port("tcp://127.0.0.1")
    result = run_cli("bridge", "ping", "--endpoint", f"tcp://127.0.0.1:{port}", "--timeout-s", "0.3")
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and f"127.0.0.1:{port}" in result.stderr and "Traceback" not in result.stderr


def test_serve_refuses_a_remote_bind_without_the_flag():
    result = run_cli("bridge", "serve", "--driver", "naoqi", "--naoqi", "tcp://127.0.0.1:1", "--bind",
                     "tcp://0.0.0.0:7790")
    assert result.returncode == 2 and "--allow-remote" in result.stderr and "Traceback" not in result.stderr


def test_ping_reports_round_trip_driver_and_robot(capsys, monkeypatch):
    import naocal.tools.cli as cli
    monkeypatch.setattr(cli, "VERB_MODULES", ("naocal.tools.cmd_bridge",))
    with serving(FakeBackend(seed=4), driver="fake") as server:
        code = cli.main(["bridge", "ping", "--endpoint", server.endpoint, "--count", "3"])
    out = capsys.readouterr().out
    assert code == 0 and "round trip" in out and "driver fake" in out and "robot fake-4" in out


def test_a_failing_backend_gives_an_error_reply_and_the_server_lives_on():
    class BrokenBackend(FakeBackend):
        def capture(self):
            raise RuntimeError("camera cable unplugged")

        def max_speeds(self):
            return {"HeadYaw": object()}  # cannot be encoded

    with serving(BrokenBackend()) as server:
        bridge = BridgeBackend(server.endpoint, timeout_s=1.0)
        with pytest.raises(BridgeError, match="InternalError.*camera cable unplugged"):
            bridge.capture()
        with pytest.raises(BridgeError, match="InternalError"):
            bridge.max_speeds()
        assert bridge.now() == 0.0


def test_curve_keys_can_come_from_the_environment(tmp_path, monkeypatch):
    server_public, server_secret = write_curve_keys(tmp_path, "server")
    with serving(FakeBackend(), curve_secret_key_file=server_secret) as server:
        monkeypatch.setenv("NAOCAL_CURVE_SERVER_KEY", str(server_public))
        assert BridgeBackend(server.endpoint, timeout_s=1.0).now() == 0.0
        monkeypatch.setenv("NAOCAL_CURVE_SERVER_KEY", str(tmp_path / "missing.key"))
        with pytest.raises(BridgeError, match="missing.key"):
            BridgeBackend(server.endpoint, timeout_s=1.0)


def test_bad_server_settings_are_one_line_errors(tmp_path):
    public, secret = write_curve_keys(tmp_path, "server")
    with pytest.raises(NaocalError, match="no secret key"):
        BridgeServer(FakeBackend(), "tcp://127.0.0.1:0", curve_secret_key_file=public).start()
    with pytest.raises(NaocalError, match="cannot read"):
        BridgeServer(FakeBackend(), "tcp://127.0.0.1:0", curve_secret_key_file=tmp_path / "nope").start()
    with pytest.raises(NaocalError, match="not a directory"):
        BridgeServer(FakeBackend(), "tcp://127.0.0.1:0", curve_secret_key_file=secret,
                     curve_clients_dir=tmp_path / "nope").start()
    with serving(FakeBackend()) as server:
        with pytest.raises(NaocalError, match="cannot bind"):
            BridgeServer(FakeBackend(), server.endpoint).start()


def test_the_cli_default_bind_is_the_servers():
    from naocal.tools import cmd_bridge

    assert cmd_bridge.DEFAULT_BIND == DEFAULT_BIND == "tcp://127.0.0.1:7790"


class _HostileReadings(FakeBackend):
    """A server whose robot reports `value` as LKneePitch (a broken driver, or a server from before the checks)."""

    def __init__(self, value):
        super().__init__()
        self.value = value

    def read_joints(self):
        reading = super().read_joints()
        return protocol.JointReading(angles_rad={**reading.angles_rad, "LKneePitch": self.value}, t_s=reading.t_s)


@pytest.mark.parametrize("value", [math.nan, math.inf, 2.5, 1e30])
def test_the_client_checks_every_reading_it_is_served(value):
    with serving(_HostileReadings(value)) as server:
        client = BridgeBackend(server.endpoint, timeout_s=2.0)
        try:
            with pytest.raises(RobotFault, match="LKneePitch reads"):
                client.read_joints()
        finally:
            client.close()


def test_a_reading_on_the_wire_as_a_string_or_a_bool_is_not_a_number():
    limits_rad = {"LKneePitch": (-0.09, 2.11)}
    for value in ("0.5", True):
        with pytest.raises(RobotFault, match="not a number"):
            protocol.joint_reading_from_wire({"angles_rad": {"LKneePitch": value}, "t_s": 1.0}, limits_rad)
    with pytest.raises(RobotFault, match="time"):
        protocol.joint_reading_from_wire({"angles_rad": {"LKneePitch": 0.5}, "t_s": "1.0"}, limits_rad)
