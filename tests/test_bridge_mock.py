"""The bridge in front of the PyBullet mock: the same contract, and bit-identical data to a direct run."""

import pytest

mock = pytest.importorskip("naocal.backends.mock")

from naocal.backends.bridge import BridgeBackend  # noqa: E402
from naocal.backends.bridge_server import BridgeServer  # noqa: E402
from tests.backend_contract import check_backend_contract  # noqa: E402


def serve_mock(seed):
    return BridgeServer(mock.MockBackend(seed=seed), "tcp://127.0.0.1:0", driver="mock", clock="simulated",
                        state_persists=False).start_thread()


def test_the_bridge_to_the_mock_passes_the_backend_contract():
    server = serve_mock(seed=0)
    try:
        check_backend_contract(BridgeBackend(server.endpoint, timeout_s=30.0))
    finally:
        server.stop(timeout_s=60.0)
        server.backend.close()


def test_the_bridge_to_the_mock_gives_the_same_data_as_the_mock_itself():
    def scripted_run(backend):
        start = backend.read_joints().angles_rad
        limits = backend.joint_limits()
        target = min(start["HeadYaw"] + 0.15, limits["HeadYaw"][1] - 0.05)
        backend.set_stiffness(["HeadYaw", "HeadPitch"], 1.0)
        out = [backend.intrinsics(), backend.robot_identity()]
        backend.command({"HeadYaw": target}, 0.2)
        for step_s in (0.02, 0.3, 1.0):
            backend.sleep(step_s)
            reading = backend.read_joints()
            image = backend.capture()
            out += [reading.angles_rad, reading.t_s, backend.now()]
            out += [None] if image is None else [image.t_exposure_s, image.pixels.tobytes()]
        return out

    direct = mock.MockBackend(seed=7)
    try:
        expected = scripted_run(direct)
    finally:
        direct.close()
    server = serve_mock(seed=7)
    try:
        assert scripted_run(BridgeBackend(server.endpoint, timeout_s=30.0)) == expected
    finally:
        server.stop(timeout_s=60.0)
        server.backend.close()


def test_bridge_serve_mock_answers_ping_and_stops_on_sigint():
    import selectors
    import signal
    import subprocess
    import sys

    from tests.bridge_fakes import CLI, ROOT

    server = subprocess.Popen([sys.executable, "-c", CLI, "bridge", "serve", "--driver", "mock", "--seed", "5",
                               "--effect", "backlash=0.01", "--bind", "tcp://127.0.0.1:0"],
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        selector = selectors.DefaultSelector()
        selector.register(server.stdout, selectors.EVENT_READ)
        assert selector.select(timeout=60), "the server did not start within 60 s"
        line = server.stdout.readline()
        assert line.startswith("naocal bridge: serving mock on tcp://127.0.0.1:"), line
        endpoint = line.split(" on ")[1].strip()
        # The next line says whether CURVE is on (here: off, traffic in clear).
        assert server.stdout.readline() == "naocal bridge: CURVE off: unencrypted, any client\n"
        ping = subprocess.run([sys.executable, "-c", CLI, "bridge", "ping", "--endpoint", endpoint], cwd=ROOT,
                              capture_output=True, text=True, timeout=60)
        assert ping.returncode == 0, ping.stderr
        assert "driver mock" in ping.stdout and "robot mock-5" in ping.stdout and "clock simulated" in ping.stdout
        server.send_signal(signal.SIGINT)
        out, err = server.communicate(timeout=30)
    finally:
        if server.poll() is None:
            server.kill()
            server.wait()
    assert server.returncode == 0, err
    assert "stopped" in out


def test_bridge_serve_refuses_an_unknown_effect_in_one_line():
    import subprocess
    import sys

    from tests.bridge_fakes import CLI, ROOT

    result = subprocess.run([sys.executable, "-c", CLI, "bridge", "serve", "--driver", "mock", "--effect",
                             "gremlins=1"], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and "gremlins" in result.stderr and "Traceback" not in result.stderr
