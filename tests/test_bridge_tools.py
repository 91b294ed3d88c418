"""`naocal bridge ping/status/move` against a served mock, and the bridge's bad-input and key-file checks."""

import logging
import math
import shutil
import time

import pytest

mock = pytest.importorskip("naocal.backends.mock")

from naocal.backends.bridge_keys import load_client_keys  # noqa: E402
from naocal.backends.bridge_server import BridgeServer, write_curve_keys  # noqa: E402
from naocal.tools import cli  # noqa: E402

LEG = ("LHipYawPitch", "LHipRoll", "LHipPitch", "LKneePitch", "LAnklePitch", "LAnkleRoll", "RHipYawPitch", "RHipRoll",
       "RHipPitch", "RKneePitch", "RAnklePitch", "RAnkleRoll", "HeadYaw", "HeadPitch")


@pytest.fixture(scope="module")
def served_mock():
    """`naocal bridge serve --driver mock` as it runs it: the realistic mock on a simulated clock."""
    backend = mock.MockBackend(seed=0, realism="realistic")
    server = BridgeServer(backend, "tcp://127.0.0.1:0", driver="mock", clock="simulated",
                          state_persists=False).start_thread()
    try:
        yield server.endpoint
    finally:
        server.stop()
        backend.close()


def naocal(argv, capsys):
    code = cli.main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def offsets_of(tmp_path, body_id, head_id, c_rad=0.0):
    from naocal.solver.offsets import offsets_from_alpha, write_offsets

    offsets = offsets_from_alpha({j: -c_rad for j in LEG}, (0.0, 0.0, 0.0), {leg: (0.0, 0.0, 0.0) for leg in "LR"},
                                 robot={"body_id": body_id, "head_id": head_id},
                                 fit={"rms_px": [0.1, 0.1], "n_vertices": 1152, "n_images": 48})
    path = tmp_path / f"offsets-{body_id}.json"
    write_offsets(offsets, path)
    return str(path)


def test_move_works_against_the_mock_whose_clock_moves_only_when_asked(served_mock, capsys):
    """It waited on the wall clock, while the mock's clock stood still: 'not there within 5.3 s' every time."""
    code, out, err = naocal(["bridge", "move", "--endpoint", served_mock, "LKneePitch=40"], capsys)
    assert code == 0, err
    reads_deg = float(out.split("reads ")[1].split(" deg")[0])
    assert abs(reads_deg - 40.0) <= 1.0, out


def test_status_and_move_warn_about_another_bodys_offsets_as_verify_refuses_them(served_mock, tmp_path, capsys):
    other = offsets_of(tmp_path, "mock-body-3", "mock-head-3")
    for argv in (["bridge", "status", "--endpoint", served_mock, "--offsets", other],
                 ["bridge", "move", "--endpoint", served_mock, "--offsets", other, "HeadYaw=2"]):
        code, out, err = naocal(argv, capsys)
        assert code == 0, err
        assert "WARNING" in err and "'mock-body-3'" in err and "'mock-body-0'" in err, (argv, err)
    own = offsets_of(tmp_path, "mock-body-0", "mock-head-0")
    code, out, err = naocal(["bridge", "status", "--endpoint", served_mock, "--offsets", own], capsys)
    assert code == 0 and "WARNING" not in err


def test_status_says_why_a_driver_shows_no_versions(served_mock, capsys):
    code, out, err = naocal(["bridge", "status", "--endpoint", served_mock], capsys)
    first = out.splitlines()[0]
    assert code == 0 and "?" not in first, first
    assert first == ("robot: body mock-body-0, head mock-head-0 (the mock driver reports no versions), driver mock")


@pytest.mark.parametrize("argv, match", [
    (["bridge", "ping", "--timeout-s", "1e308"], "--timeout-s"),  # was an OverflowError traceback
    (["bridge", "ping", "--timeout-s", "inf"], "--timeout-s"),
    (["bridge", "ping", "--timeout-s", "nan"], "--timeout-s"),
    (["bridge", "ping", "--timeout-s", "0"], "--timeout-s"),
    (["bridge", "status", "--timeout-s", "1e308"], "--timeout-s"),
    (["bridge", "move", "--timeout-s", "inf", "HeadYaw=1"], "--timeout-s"),  # was a wait without a deadline
    (["bridge", "move", "--timeout-s", "1e308", "HeadYaw=1"], "--timeout-s"),
    (["bridge", "move", "--tolerance-deg", "inf", "HeadYaw=1"], "--tolerance-deg"),  # any reading 'arrived'
    (["bridge", "ping", "--count", "0"], "--count"),  # was timed as 1 round trip
    (["bridge", "ping", "--count", "-3"], "--count"),
])
def test_bad_times_and_counts_are_one_line_errors(served_mock, argv, match, capsys):
    argv = argv[:2] + ["--endpoint", served_mock] + argv[2:]
    t0 = time.monotonic()
    code, out, err = naocal(argv, capsys)
    assert code == 2 and match in err and len(err.strip().splitlines()) == 1, err
    assert time.monotonic() - t0 < 10.0


@pytest.mark.parametrize("value", ["1e308", "inf", "nan", "0"])
def test_serve_refuses_a_lease_timeout_that_is_no_deadline(value, capsys):
    code, out, err = naocal(["bridge", "serve", "--driver", "mock", "--bind", "tcp://127.0.0.1:0",
                             "--lease-timeout-s", value], capsys)
    assert code == 2 and "--lease-timeout-s" in err and len(err.strip().splitlines()) == 1, err


def test_a_client_secret_key_renamed_into_the_clients_dir_is_warned_about(tmp_path, caplog):
    clients = tmp_path / "clients"
    clients.mkdir()
    write_curve_keys(tmp_path, "alice")
    shutil.copy(tmp_path / "alice.key_secret", clients / "alice.key")  # the secret, renamed
    write_curve_keys(tmp_path, "bob")
    shutil.copy(tmp_path / "bob.key", clients / "bob.key")  # as it should be
    with caplog.at_level(logging.WARNING, logger="naocal.bridge"):
        assert len(load_client_keys(clients)) == 2  # alice's public key is still in it: admitted
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and "alice.key" in warnings[0] and "SECRET" in warnings[0], warnings


def test_calibrate_against_a_dead_endpoint_fails_fast_and_leaves_no_run_directory(tmp_path, capsys):
    import socket

    with socket.socket() as probe:  # a free port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    out_dir = tmp_path / "run"
    t0 = time.monotonic()
    code, out, err = naocal(["calibrate", "--backend", "bridge", "--endpoint", f"tcp://127.0.0.1:{port}",
                             "--out", str(out_dir)], capsys)
    took_s = time.monotonic() - t0
    assert code == 2 and "no reply" in err and len(err.strip().splitlines()) == 1, err
    assert took_s < 5.0 + 2.0, took_s  # backends.bridge.FIRST_CONTACT_TIMEOUT_S, once (was 42 s)
    assert not out_dir.exists()


def test_move_through_offsets_commands_target_plus_c(served_mock, tmp_path, capsys):
    c = math.radians(2.0)
    own = offsets_of(tmp_path, "mock-body-0", "mock-head-0", c_rad=c)
    code, out, err = naocal(["bridge", "move", "--endpoint", served_mock, "--offsets", own, "LKneePitch=35"], capsys)
    assert code == 0, err
    assert "target 35.00 deg, commanded 37.00 deg raw" in out


class FaultedMock(mock.MockBackend):
    """The mock as a faulted driver reports itself: its status names the fault."""

    def status(self):
        report = super().status()
        report["robot"]["fault"] = "LKneePitch reads nan: a reading that cannot be trusted"
        return report


@pytest.mark.parametrize("json_flag", [[], ["--json"]])
def test_status_of_a_faulted_robot_exits_3_so_that_a_script_stops(json_flag, capsys):
    backend = FaultedMock(seed=0)
    server = BridgeServer(backend, "tcp://127.0.0.1:0", driver="mock", clock="simulated",
                          state_persists=False).start_thread()
    try:
        code, out, err = naocal(["bridge", "status", "--endpoint", server.endpoint, *json_flag], capsys)
    finally:
        server.stop()
        backend.close()
    assert code == 3, (out, err)
    assert "cannot be trusted" in out


def test_ping_and_stop_check_the_hello_they_echo(capsys):
    """A server's hello is read before ping or stop prints it: a robot id holding a terminal escape is refused."""
    from tests.bridge_fakes import FakeBackend, serving

    class Odd(FakeBackend):
        def robot_identity(self):
            return {**super().robot_identity(), "id": "fake\x1b]0;owned\x07"}

    with serving(Odd()) as server:
        for verb in ("ping", "stop"):
            assert cli.main(["bridge", verb, "--endpoint", server.endpoint]) == 2
            err = capsys.readouterr().err
            assert "hello, field 'robot_id': expected a non-empty single line of printable text" in err and "\x1b" not in err
    with serving(FakeBackend()) as server:
        assert cli.main(["bridge", "stop", "--endpoint", server.endpoint]) == 0
        assert capsys.readouterr().out.strip() == f"{server.endpoint}: stopped the nao fake-0 (driver fake)"
