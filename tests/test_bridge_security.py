"""Attacks on the bridge by anyone who reaches its port, and the mistakes that must be loud (issue 11).

Each test is the attack or the mistake as the issue describes it; docs/PROTOCOL.md "Security" says which proves what.
"""

import errno
import logging
import os
import selectors
import signal
import socket
import stat
import subprocess
import sys
import time

import pytest

from naocal.backends import protocol
from naocal.backends.bridge import BridgeBackend
from naocal.backends.bridge_server import BridgeServer, check_bind_address, write_curve_keys
from naocal.backends.protocol import ControlError
from naocal.backends.errors import BridgeError
from naocal.solver.errors import NaocalError
from tests.bridge_fakes import CLI, MOTION_ARGS, ROOT, FakeBackend, RawClient, serving

TARGETS = [{"HeadYaw": 0.01 * k, "LKneePitch": 0.02 * k} for k in range(1, 11)]


def sent_targets(fake):
    return [targets for targets, _ in fake.commands]


def run_cli(*argv, timeout_s=60):
    return subprocess.run([sys.executable, "-c", CLI, *argv], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout_s)


def one_line_error(result, *fragments):
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr, result.stderr
    for fragment in fragments:
        assert fragment in result.stderr, result.stderr


# ---------------------------------------------------------------------------------------------- lease hijack
def test_a_stranger_who_copies_everything_hello_shows_cannot_move_the_robot_or_take_control():
    fake = FakeBackend()
    with serving(fake, lease_timeout_s=60.0) as server:
        agent = BridgeBackend(server.endpoint, timeout_s=1.0, client_id="agent")
        agent.command(TARGETS[0], 0.2)
        stranger = RawClient(server.endpoint)
        hello = stranger.request("stranger:1", "hello")["result"]
        assert "agent" not in repr(hello) and agent._token not in repr(hello)  # neither its id nor its secret
        assert hello["controlled"] is True
        # Whatever hello shows, the agent's client id (a sniffer learns it) and well-formed guesses of the token.
        guesses = [None, hello["server_id"] * 2, (str(hello.get("controller")) + "_" * 22)[:40], "A" * 43]
        seq = 100
        for guess in guesses:
            for cmd, args in MOTION_ARGS.items():
                seq += 1
                reply = stranger.request(f"agent:{seq}", cmd, args, token=guess)
                assert reply["ok"] is False and reply["error"]["type"] == "ControlError", reply
            reply = stranger.request(f"agent:{seq + 1}", "acquire", {"nonce": "N" * 22}, token=guess)
            assert reply["ok"] is False and reply["error"]["type"] == "ControlError", reply
            assert stranger.request(f"agent:{seq + 2}", "release", token=guess)["ok"]  # a no-op for a stranger
        stranger.close()
        assert fake.executed == {"command": 1}  # nothing the stranger sent moved or stopped anything
        agent.command(TARGETS[1], 0.2)  # the agent keeps control: no StaleRequest, no ControlError
        agent.sleep(0.1)
    assert sent_targets(fake) == TARGETS[:2]


def test_any_client_stops_a_nao_without_the_lease_into_its_drivers_safe_state_and_the_agent_is_told_once():
    """The stop is the safe state control ending gives (Backend.release_control: the LoLA driver holds, then ramps
    limp): no motion is invented. The agent holding the lease keeps it and hears of the stop once."""
    from naocal.backends.errors import RobotFault

    class Released(FakeBackend):
        def release_control(self):
            self.executed["release_control"] += 1

    fake = Released()
    with serving(fake, lease_timeout_s=60.0) as server:
        agent = BridgeBackend(server.endpoint, timeout_s=1.0, client_id="agent")
        agent.command(TARGETS[0], 0.2)
        observer = BridgeBackend(server.endpoint, timeout_s=1.0, client_id="observer")
        assert observer.stop() is None and observer._token is None
        assert fake.executed == {"command": 1, "release_control": 1}  # nothing moved: the driver's safe state
        with pytest.raises(ControlError):
            observer.command(TARGETS[5], 0.2)  # the stop gave it no control
        with pytest.raises(RobotFault, match="another client stopped the robot.*command not executed"):
            agent.command(TARGETS[1], 0.2)
        agent.command(TARGETS[1], 0.2)  # told once
        observer.close()
        agent.close()
    assert sent_targets(fake) == TARGETS[:2]


# ---------------------------------------------------------------------------------------------- exactly once
def test_a_retried_motion_runs_once_whatever_300_other_clients_sent_meanwhile(monkeypatch):
    """The Lazy Pirate retry of a command whose reply was lost (the same bytes, from a fresh socket) comes after 300
    other client ids sent reads and motion requests: answered from the controller's replies, not run again."""
    fake = FakeBackend()
    with serving(fake) as server:
        payloads = {}
        handle = server._handle

        def spy(frames, *args):
            message = protocol.unpack(frames[-1], max_bytes=protocol.MAX_REQUEST_BYTES)
            if isinstance(message, dict) and message.get("cmd") == "command":
                payloads[message["id"]] = frames[-1]
            return handle(frames, *args)

        monkeypatch.setattr(server, "_handle", spy)
        agent = BridgeBackend(server.endpoint, timeout_s=1.0, client_id="agent")
        agent.command(TARGETS[0], 0.2)
        agent.command(TARGETS[1], 0.2)  # pretend its reply was lost
        lost_id, lost_payload = list(payloads.items())[-1]
        others = RawClient(server.endpoint)
        for n in range(300):
            assert others.request(f"other{n}:1", "now")["ok"]
            assert others.request(f"other{n}:2", "command", MOTION_ARGS["command"])["ok"] is False
        retry = RawClient(server.endpoint)
        reply = retry.send(lost_payload)
        assert reply == {"v": 1, "id": lost_id, "ok": True, "result": None}
        assert sent_targets(fake) == TARGETS[:2]  # answered from the replies kept, not executed again
        retry.close()
        others.close()
        assert server.exactly_once_entries() == 2  # the agent's two commands; nothing of the 300 others


def test_exactly_once_memory_is_bounded_by_the_lease_not_by_what_strangers_send():
    from naocal.backends import bridge_lease

    with serving(FakeBackend(), replies_kept_per_client=8) as server:
        stranger = RawClient(server.endpoint)
        for n in range(500):
            stranger.request(f"s{n}:1", "command", MOTION_ARGS["command"], token="X" * 43)
        assert server.exactly_once_entries() == 0
        stranger.close()
        token_file = None
        for resumed in range(6):  # the same agent resumed six times: one client id per run, one token
            agent = BridgeBackend(server.endpoint, timeout_s=1.0)
            agent._token = token_file
            for k in range(20):
                agent.command(TARGETS[k % 10], 0.2)
            token_file = agent._token
            agent._drop_socket()  # killed: no release
        assert server.exactly_once_entries() <= bridge_lease.MotionLease.MAX_CLIENTS * 8


# ---------------------------------------------------------------------------------------------- flood
FLOOD_SERVER = f"""
import resource, sys
resource.setrlimit(resource.RLIMIT_NOFILE, (256, 256))  # so a few hundred connections exhaust it
sys.path.insert(0, {ROOT!r})
from tests.bridge_fakes import FakeBackend
from naocal.backends.bridge_server import BridgeServer
server = BridgeServer(FakeBackend(), "tcp://127.0.0.1:0", driver="fake", clock="simulated").start()
print(server.endpoint, flush=True)
server.serve_forever()
"""
FLOOD_CONNECTIONS = 600


def cpu_seconds(pid):
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@pytest.mark.skipif(not os.path.exists("/proc/self/stat"), reason="reads the server's CPU time from /proc")
def test_a_flood_of_idle_connections_neither_spins_the_cpu_nor_locks_out_the_controller():
    server = subprocess.Popen([sys.executable, "-c", FLOOD_SERVER], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    flood = []
    try:
        selector = selectors.DefaultSelector()
        selector.register(server.stdout, selectors.EVENT_READ)
        assert selector.select(timeout=30), "the server did not start"
        endpoint = server.stdout.readline().strip()
        port = int(endpoint.rsplit(":", 1)[1])
        agent = BridgeBackend(endpoint, timeout_s=2.0, retries=0, client_id="agent")  # a miss raises
        agent.command(TARGETS[0], 0.2)
        cpu_start_s, wall_start_s = cpu_seconds(server.pid), time.monotonic()
        for _ in range(FLOOD_CONNECTIONS):  # connect and say nothing
            connection = socket.socket()
            connection.setblocking(False)
            connection.connect_ex(("127.0.0.1", port))
            flood.append(connection)
        slowest_s, k = 0.0, 0
        while time.monotonic() < wall_start_s + 3.0:
            start_s = time.monotonic()
            agent.command(TARGETS[k % len(TARGETS)], 0.2)
            agent.now()
            slowest_s, k = max(slowest_s, time.monotonic() - start_s), k + 1
            time.sleep(0.05)
        agent._drop_socket()  # what the client does after a timeout: a new connection must get in as well
        start_s = time.monotonic()
        agent.command(TARGETS[0], 0.2)
        reconnect_s = time.monotonic() - start_s
        cpu_fraction = (cpu_seconds(server.pid) - cpu_start_s) / (time.monotonic() - wall_start_s)
        print(f"flood of {FLOOD_CONNECTIONS}: slowest controller round trip {slowest_s * 1e3:.1f} ms, reconnection "
              f"{reconnect_s * 1e3:.1f} ms, server CPU {cpu_fraction:.1%} of one core")
        assert slowest_s < 2.0 and reconnect_s < 2.0
        assert cpu_fraction < 0.3, f"the server used {cpu_fraction:.0%} of a core under the flood"
    finally:
        for connection in flood:
            connection.close()
        server.kill()
        server.wait(timeout=30)


# ---------------------------------------------------------------------------------------------- bind check
@pytest.mark.parametrize("bind", [
    "tcp://0.0.0.0:7790@127.0.0.1",  # libzmq: host 0.0.0.0, port atoi("7790@127.0.0.1") = 7790
    "tcp://eth0:7790@127.0.0.1",  # an interface name
    "tcp://*:7790@127.0.0.1",
    "tcp://127.0.0.1:7791;0.0.0.0:7790",  # libzmq listens on what follows the last ';'
    "tcp://0.0.0.0:7791;127.0.0.1:7790",
    "tcp://lo:7790", "tcp://[::]:7790", "tcp://[::ffff:192.168.1.2]:7790", "tcp://0:7790", "tcp://nao.local:7790",
    "tcp://127.0.0.1", "tcp://:7790",
])
def test_bind_addresses_are_read_the_way_libzmq_reads_them_and_refused_unless_loopback(bind):
    with pytest.raises(NaocalError, match="--allow-remote|HOST:PORT"):
        check_bind_address(bind, allow_remote=False)


def test_loopback_in_any_spelling_libzmq_accepts_passes():
    from naocal.backends.bridge_endpoint import tcp_listen_hosts

    for bind in ("tcp://127.0.0.1:0", "tcp://127.1:7790", "tcp://0x7f.1:7790", "tcp://2130706433:7790",
                 "tcp://127.0.0.1%lo:7790", "tcp://[::1]:7790", "tcp://[::ffff:127.0.0.1]:7790", "tcp://localhost:*",
                 "ipc:///tmp/naocal.sock", "inproc://naocal"):
        check_bind_address(bind, allow_remote=False)
    assert tcp_listen_hosts("[::1%lo]:1;127.0.0.1:2") == ["::1", "127.0.0.1"]
    with pytest.raises(NaocalError, match="not a number"):  # junk after the port is refused even when allowed
        check_bind_address("tcp://0.0.0.0:7790@127.0.0.1", allow_remote=True)


def test_the_bound_address_is_checked_again_after_binding(monkeypatch):
    import naocal.backends.bridge_server as bridge_server
    monkeypatch.setattr(bridge_server, "check_bind_address", lambda bind, allow_remote: None)  # a parser bug
    server = BridgeServer(FakeBackend(), "tcp://0.0.0.0:0")
    with pytest.raises(NaocalError, match="ended up listening on tcp://0.0.0.0:.*refused"):
        server.start()
    assert server.endpoint is None  # unbound and closed


def test_serve_refuses_the_source_address_forms_in_one_line():
    for bind in ("tcp://0.0.0.0:7790@127.0.0.1", "tcp://eth0:7790@127.0.0.1"):
        result = run_cli("bridge", "serve", "--driver", "naoqi", "--naoqi", "tcp://127.0.0.1:1", "--bind", bind)
        one_line_error(result, "--allow-remote", bind)


# ---------------------------------------------------------------------------------------------- client endpoints
@pytest.mark.parametrize("endpoint", ["http://nao.local:7790", "tcp://nao.local", "tcp://nao.local:port",
                                      "tcp://nao.local:70000", "nao.local:7790", "tcp://::1:7790", "tcp://a b:1"])
def test_a_bad_client_endpoint_is_one_line_and_exit_2(endpoint, capsys):
    import naocal.tools.cli as cli
    from naocal.backends.bridge_endpoint import check_client_endpoint

    with pytest.raises(BridgeError, match="expected tcp://HOST:PORT|IPv6"):
        check_client_endpoint(endpoint)
    cli.VERB_MODULES, saved = ("naocal.tools.cmd_bridge",), cli.VERB_MODULES
    try:
        code = cli.main(["bridge", "ping", "--endpoint", endpoint, "--timeout-s", "0.2"])
    finally:
        cli.VERB_MODULES = saved
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and endpoint in err, err


def test_calibrate_refuses_a_bad_endpoint_before_writing_anything(tmp_path, capsys):
    pytest.importorskip("naocal.tools.cmd_calibrate")
    import naocal.tools.cli as cli
    code = cli.main(["calibrate", "--backend", "bridge", "--endpoint", "tcp://nao.local", "--out",
                     str(tmp_path / "run")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "tcp://nao.local" in err and "port" in err, err
    assert not (tmp_path / "run").exists()


# ---------------------------------------------------------------------------------------------- CURVE mistakes
def test_a_junk_or_missing_client_key_refuses_to_start_naming_the_file(tmp_path):
    _, server_secret = write_curve_keys(tmp_path / "server", "server")
    clients = tmp_path / "clients"
    write_curve_keys(clients, "agent")
    (clients / "laptop.key").write_text("not a key\n")
    with pytest.raises(NaocalError, match=r"laptop\.key: .*CURVE public key"):
        BridgeServer(FakeBackend(), "tcp://127.0.0.1:0", curve_secret_key_file=server_secret,
                     curve_clients_dir=clients).start()
    (clients / "laptop.key").write_text('metadata\ncurve\n    public-key = "tooshort"\n')
    with pytest.raises(NaocalError, match=r"laptop\.key: not a CURVE public key"):
        BridgeServer(FakeBackend(), "tcp://127.0.0.1:0", curve_secret_key_file=server_secret,
                     curve_clients_dir=clients).start()
    (tmp_path / "empty").mkdir()
    with pytest.raises(NaocalError, match="holds no client public keys"):
        BridgeServer(FakeBackend(), "tcp://127.0.0.1:0", curve_secret_key_file=server_secret,
                     curve_clients_dir=tmp_path / "empty").start()


def test_a_secret_key_others_can_read_is_warned_about(tmp_path, caplog):
    server_public, server_secret = write_curve_keys(tmp_path, "server")
    os.chmod(server_secret, 0o644)
    caplog.set_level(logging.WARNING)
    with serving(FakeBackend(), curve_secret_key_file=server_secret) as server:
        assert BridgeBackend(server.endpoint, timeout_s=1.0, curve_server_key=server_public).now() == 0.0
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any(str(server_secret) in w and "readable by other users" in w and "0644" in w for w in warnings), warnings


def test_a_client_without_keys_is_told_the_server_requires_curve_at_once(tmp_path):
    _, server_secret = write_curve_keys(tmp_path, "server")
    with serving(FakeBackend(), curve_secret_key_file=server_secret) as server:
        start_s = time.monotonic()
        with pytest.raises(BridgeError, match="the server requires CURVE keys"):
            BridgeBackend(server.endpoint, timeout_s=5.0, retries=3).now()
        assert time.monotonic() - start_s < 2.0  # not 4 attempts of 5 s
        result = run_cli("bridge", "ping", "--endpoint", server.endpoint)
    one_line_error(result, "the server requires CURVE keys")


def test_the_start_lines_say_whether_curve_is_on(tmp_path):
    _, server_secret = write_curve_keys(tmp_path / "server", "server")
    write_curve_keys(tmp_path / "clients", "agent")
    summaries = []
    for kwargs in ({}, {"curve_secret_key_file": server_secret},
                   {"curve_secret_key_file": server_secret, "curve_clients_dir": tmp_path / "clients"}):
        with serving(FakeBackend(), **kwargs) as server:
            summaries.append(server.security_summary())
    assert summaries == ["CURVE off: unencrypted, any client", "CURVE on: encrypted, any client key",
                         "CURVE on: encrypted, 1 admitted client key(s)"]


def test_keygen_does_not_tell_a_client_to_keep_its_secret_on_the_server(tmp_path, capsys):
    import naocal.tools.cli as cli
    cli.VERB_MODULES, saved = ("naocal.tools.cmd_bridge",), cli.VERB_MODULES
    try:
        assert cli.main(["bridge", "keygen", "--out", str(tmp_path), "--name", "agent"]) == 0
    finally:
        cli.VERB_MODULES = saved
    out = capsys.readouterr().out
    assert "on the server" not in out and "keep it on the machine that uses it" in out
    assert "--curve-clients" in out and "--curve-server-key" in out
    assert stat.S_IMODE(os.stat(tmp_path / "agent.key_secret").st_mode) == 0o600


# ---------------------------------------------------------------------------------------------- disk full
def test_a_full_disk_under_the_journal_is_an_error_reply_naming_the_file_and_the_server_lives_on(tmp_path,
                                                                                                 monkeypatch):
    import shutil

    fake = FakeBackend()
    journal = tmp_path / "replies.journal"

    def disk_full(*args):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    with serving(fake, journal_path=journal) as server:
        agent = BridgeBackend(server.endpoint, timeout_s=1.0, retries=0)
        agent.command(TARGETS[0], 0.2)
        size = journal.stat().st_size
        monkeypatch.setattr(os, "fsync", disk_full)  # the record is written, then cannot be made durable
        with pytest.raises(BridgeError, match=rf"journal {journal}: .*disk full .*free on its file system.*WAS "
                                              "executed"):
            agent.command(TARGETS[1], 0.2)
        monkeypatch.undo()
        assert journal.stat().st_size == size  # the unsynced record was cut off
        assert agent.now() == 0.0  # the server lives on

        real_usage = shutil.disk_usage
        monkeypatch.setattr(shutil, "disk_usage", lambda path: real_usage(path)._replace(free=4096))
        with pytest.raises(BridgeError, match=rf"journal {journal}: only 4.0 KiB free .*not executed"):
            agent.command(TARGETS[2], 0.2)
        monkeypatch.undo()
        agent.command(TARGETS[3], 0.2)
    assert sent_targets(fake) == [TARGETS[0], TARGETS[1], TARGETS[3]]
    from naocal.backends.bridge_lease import LeaseJournal

    restored = LeaseJournal(journal).load(replies_kept=32)  # readable: no torn record inside
    assert restored is not None and restored.entries() == 2


def test_a_journal_that_cannot_be_written_at_start_is_one_line(tmp_path, monkeypatch):
    def disk_full(*args):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(NaocalError, match=rf"journal {tmp_path / 'j'}: cannot write it: .*free"):
        BridgeServer(FakeBackend(), "tcp://127.0.0.1:0", journal_path=tmp_path / "j")


# ---------------------------------------------------------------------------------------------- resume
AGENT = f"""
import sys, time
sys.path.insert(0, {ROOT!r})
from naocal.backends.bridge import BridgeBackend
agent = BridgeBackend(sys.argv[1], timeout_s=2.0, lease_file=sys.argv[2])
agent.command({{"HeadYaw": 0.1}}, 0.2)
print("moved", flush=True)
time.sleep(600)
"""


def test_a_killed_agent_takes_its_own_lease_back_at_once_and_a_stranger_still_cannot(tmp_path):
    fake = FakeBackend()
    lease_file = tmp_path / "run" / "bridge.token"
    with serving(fake, lease_timeout_s=600.0) as server:
        agent = subprocess.Popen([sys.executable, "-c", AGENT, server.endpoint, str(lease_file)], cwd=ROOT,
                                 stdout=subprocess.PIPE, text=True)
        try:
            assert agent.stdout.readline().strip() == "moved"
        finally:
            agent.send_signal(signal.SIGKILL)
            agent.wait(timeout=30)
        assert stat.S_IMODE(lease_file.stat().st_mode) == 0o600
        stranger = BridgeBackend(server.endpoint, timeout_s=1.0)
        with pytest.raises(ControlError, match="another client controls the robot"):
            stranger.command({"HeadYaw": -0.1}, 0.2)
        start_s = time.monotonic()
        resumed = BridgeBackend(server.endpoint, timeout_s=1.0, lease_file=lease_file)
        resumed.command({"HeadYaw": 0.2}, 0.2)
        assert time.monotonic() - start_s < 5.0  # not the 600 s lease timeout
        resumed.close()  # releases: the token is gone with the lease
        assert not lease_file.exists()
        stranger.command({"HeadYaw": -0.1}, 0.2)
    assert sent_targets(fake) == [{"HeadYaw": 0.1}, {"HeadYaw": 0.2}, {"HeadYaw": -0.1}]


def test_a_restarted_server_keeps_the_lease_of_its_journal(tmp_path):
    """A NAO's bridge server restarts with --journal: its controller carries on, a stranger gets nothing."""
    fake = FakeBackend()
    journal = tmp_path / "replies.journal"
    first = BridgeServer(fake, "tcp://127.0.0.1:0", journal_path=journal, state_persists=True).start_thread()
    endpoint = first.endpoint
    agent = BridgeBackend(endpoint, timeout_s=0.3, retries=8)
    agent.command(TARGETS[0], 0.2)
    first.stop()
    second = BridgeServer(fake, endpoint, journal_path=journal, state_persists=True).start_thread()
    try:
        with pytest.raises(ControlError):
            BridgeBackend(endpoint, timeout_s=1.0).command(TARGETS[5], 0.2)
        agent.command(TARGETS[1], 0.2)
    finally:
        second.stop()
    assert sent_targets(fake) == TARGETS[:2]


# ------------------------------------------------------------------------------------------ files that are not files
def returns_within(timeout_s, function, *args, **kwargs):
    """Run `function` in a thread; its result or exception, or fail if it is still running after `timeout_s`."""
    import threading

    outcome = {}

    def run():
        try:
            outcome["value"] = function(*args, **kwargs)
        except BaseException as err:  # handed to the test
            outcome["error"] = err

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(timeout_s)
    return thread.is_alive(), outcome


def unblock_fifo(path):
    """Open a FIFO for writing and close it, so a reader stuck in open() returns (end of file)."""
    try:
        os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
    except OSError:
        pass


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_journal_key_or_token_that_is_not_a_regular_file_is_refused_without_hanging(tmp_path, caplog):
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    try:
        hung, outcome = returns_within(5.0, BridgeServer, FakeBackend(), "tcp://127.0.0.1:0", journal_path=fifo)
        assert not hung, "reading a FIFO as the journal hangs"
        assert isinstance(outcome.get("error"), NaocalError) and "not a regular file" in str(outcome["error"])
        with pytest.raises(NaocalError, match=f"journal {tmp_path}: "):
            BridgeServer(FakeBackend(), "tcp://127.0.0.1:0", journal_path=tmp_path)  # a directory

        _, server_secret = write_curve_keys(tmp_path / "server", "server")
        clients = tmp_path / "clients"
        write_curve_keys(clients, "agent")
        os.mkfifo(clients / "laptop.key")
        server = BridgeServer(FakeBackend(), "tcp://127.0.0.1:0", curve_secret_key_file=server_secret,
                              curve_clients_dir=clients)
        hung, outcome = returns_within(5.0, server.start)
        assert not hung, "reading a FIFO as a client key hangs"
        assert isinstance(outcome.get("error"), NaocalError) and "laptop.key: not a CURVE public key" in str(
            outcome["error"])
        unblock_fifo(clients / "laptop.key")

        caplog.set_level(logging.WARNING)
        with serving(FakeBackend()) as server:
            agent = BridgeBackend(server.endpoint, timeout_s=1.0, lease_file=fifo)
            hung, outcome = returns_within(5.0, agent.command, TARGETS[0], 0.2)
            assert not hung and "error" not in outcome, "reading a FIFO as the lease token hangs"
        assert any(str(fifo) in r.getMessage() and "asking for a new lease" in r.getMessage() for r in caplog.records)
    finally:
        unblock_fifo(fifo)


def test_journal_records_of_the_wrong_types_are_ignored(tmp_path):
    import msgpack

    from naocal.backends.bridge_lease import LeaseJournal, digest

    lease = digest("T" * 43)
    good = protocol.pack(protocol.ok_reply("agent:1", None))
    records = [{"lease": lease}, {"lease": lease, "client": "agent", "seq": 1, "reply": good},
               {"lease": lease, "client": "agent", "seq": 2, "reply": 10 ** 9},  # bytes(10**9) would be 1 GB
               {"lease": lease, "client": "agent", "seq": "3", "reply": good}, ["old", 1, good]]
    path = tmp_path / "j"
    path.write_bytes(b"".join(msgpack.packb(r, use_bin_type=True) for r in records))
    restored = LeaseJournal(path).load(replies_kept=32)
    assert restored.held_by("T" * 43) and list(restored.records()) == [("agent", 1, good)]


# ---------------------------------------------------------------------------------------------- bad numbers
@pytest.mark.parametrize("value", ["nan", "-1", "0", "inf"])
def test_a_lease_timeout_or_client_timeout_that_is_not_a_positive_finite_number_is_one_line(value):
    # NaN as the lease timeout would make every lease look expired, so anyone could take the robot.
    result = run_cli("bridge", "serve", "--driver", "naoqi", "--naoqi", "tcp://127.0.0.1:1", "--lease-timeout-s",
                     value)
    one_line_error(result, "--lease-timeout-s", value)
    result = run_cli("bridge", "ping", "--endpoint", "tcp://127.0.0.1:1", "--timeout-s", value)
    one_line_error(result, "--timeout-s", value)


def test_serve_raises_its_file_descriptor_limit_to_the_hard_limit():
    script = ("import resource, sys; sys.path.insert(0, sys.argv[1]); soft, hard = resource.getrlimit("
              "resource.RLIMIT_NOFILE); resource.setrlimit(resource.RLIMIT_NOFILE, (64, hard)); "
              "from backends.bridge_guard import raise_fd_limit; print(*raise_fd_limit(), hard)")
    soft, hard, original_hard = map(int, subprocess.run([sys.executable, "-c", script, ROOT], capture_output=True,
                                                        text=True, timeout=60, check=True).stdout.split())
    assert soft == hard == original_hard


def test_keygen_into_a_place_it_cannot_write_is_one_line(tmp_path):
    (tmp_path / "file").write_text("")
    result = run_cli("bridge", "keygen", "--out", str(tmp_path / "file" / "keys"))
    one_line_error(result, str(tmp_path / "file"))
