"""Fault tests: lost replies, a slow server, restarts, retries spent, and a flood of malformed messages.

Whatever happens on the wire, the fake robot must execute each motion command exactly once, in order.
"""

import threading
import time

import msgpack
import pytest
import zmq
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from naocal.backends import protocol
from naocal.backends.bridge import BridgeBackend
from naocal.backends.bridge_server import BridgeServer, FaultInjector
from naocal.backends.errors import BridgeError
from naocal.solver.errors import NaocalError
from tests.bridge_fakes import FakeBackend, serving

TIMEOUT_S = 0.2
TARGETS = [{"HeadYaw": 0.01 * k, "LKneePitch": 0.02 * k} for k in range(1, 11)]


def client(endpoint, **kwargs):
    kwargs.setdefault("timeout_s", TIMEOUT_S)
    kwargs.setdefault("retries", 4)
    return BridgeBackend(endpoint, client_id="tester", **kwargs)


def sent_targets(fake):
    return [targets for targets, _ in fake.commands]


def test_a_dropped_reply_is_retried_and_the_motion_runs_once():
    fake = FakeBackend()
    # Request ids: 'tester:1' is the client's hello, 'tester:2' its acquire, then the commands; after each lost
    # reply the client reconnects and says hello again (to notice a restarted server), which takes one more id.
    faults = FaultInjector(drop_first_reply_of={"tester:3", "tester:5"})
    with serving(fake, faults=faults) as server:
        bridge = client(server.endpoint)
        for targets in TARGETS[:6]:
            bridge.command(targets, 0.2)
    assert sent_targets(fake) == TARGETS[:6]
    assert not faults.drop_first_reply_of  # both faults did fire


def test_a_slow_reply_after_the_client_timeout_is_deduplicated():
    fake = FakeBackend()
    faults = FaultInjector(delay_first_reply_of={"tester:2": 2.5 * TIMEOUT_S, "tester:4": 2.5 * TIMEOUT_S})
    with serving(fake, faults=faults) as server:
        bridge = client(server.endpoint)
        # tester:2, the acquire, is answered late and retried: the retry gets the same token, not a ControlError.
        bridge.command(TARGETS[0], 0.2)  # tester:4 (3 was the hello after reconnecting): late, retried, from cache
        bridge.command(TARGETS[1], 0.2)
        bridge.set_stiffness(["HeadYaw"], 1.0)
        bridge.command(TARGETS[2], 0.2)
    assert sent_targets(fake) == TARGETS[:3]
    assert fake.executed["set_stiffness"] == 1


def test_a_slow_sleep_on_the_simulated_clock_advances_it_once():
    fake = FakeBackend()
    with serving(fake, faults=FaultInjector(delay_first_reply_of={"tester:3": 2.5 * TIMEOUT_S})) as server:
        bridge = client(server.endpoint)
        bridge.server_info()  # tester:1
        bridge.sleep(0.5)  # tester:2 acquires, tester:3 sleeps
        assert bridge.now() == pytest.approx(0.5)
    assert fake.executed["sleep"] == 1


def test_server_restarted_in_the_middle_of_a_sequence_of_commands():
    """A NAO outlives its bridge server: the client carries on, nothing is lost or repeated."""
    fake = FakeBackend()
    first = BridgeServer(fake, "tcp://127.0.0.1:0", driver="fake", state_persists=True).start_thread()
    endpoint = first.endpoint
    bridge = client(endpoint, retries=8)
    for targets in TARGETS[:4]:
        bridge.command(targets, 0.2)
    first.stop()
    servers = []
    restart = threading.Timer(0.5, lambda: servers.append(
        BridgeServer(fake, endpoint, driver="fake", state_persists=True).start_thread()))
    restart.start()
    try:
        for targets in TARGETS[4:]:
            bridge.command(targets, 0.2)
        assert bridge.server_info()["server_id"] != first.server_id
    finally:
        restart.join()
        for server in servers:
            server.stop()
    assert sent_targets(fake) == TARGETS


@pytest.mark.parametrize("with_journal", [True, False])
def test_a_server_that_dies_after_executing_answers_the_retry_from_its_journal(tmp_path, with_journal):
    fake = FakeBackend()
    journal = tmp_path / "replies.journal" if with_journal else None
    faults = FaultInjector(crash_after_executing={"tester:5"})
    first = BridgeServer(fake, "tcp://127.0.0.1:0", journal_path=journal, faults=faults).start_thread()
    endpoint = first.endpoint
    bridge = client(endpoint, retries=8)
    servers = []
    restart = threading.Timer(0.3, lambda: servers.append(
        BridgeServer(fake, endpoint, journal_path=journal).start_thread()))
    try:
        bridge.command(TARGETS[0], 0.2)
        bridge.command(TARGETS[1], 0.2)
        restart.start()
        bridge.command(TARGETS[2], 0.2)  # tester:5 (1 hello, 2 acquire): executed by the first server, which died
        bridge.command(TARGETS[3], 0.2)
    finally:
        restart.join()
        first.stop()
        for server in servers:
            server.stop()
    if with_journal:
        assert sent_targets(fake) == TARGETS[:4]
    else:  # the lease and its replies died with the server (the client acquired anew): what the journal is for
        assert sent_targets(fake) == TARGETS[:3] + [TARGETS[2], TARGETS[3]]


def test_a_restarted_mock_server_is_not_silently_taken_for_the_same_robot():
    first = BridgeServer(FakeBackend(), "tcp://127.0.0.1:0", clock="simulated", state_persists=False).start_thread()
    endpoint = first.endpoint
    bridge = client(endpoint)
    bridge.sleep(0.3)
    bridge.command(TARGETS[0], 0.2)
    first.stop()
    deadline = time.monotonic() + 5.0
    while True:  # libzmq releases the first server's port in its I/O thread, a moment after stop() returns
        try:
            second = BridgeServer(FakeBackend(), endpoint, clock="simulated", state_persists=False).start_thread()
            break
        except NaocalError as err:
            if "Address already in use" not in str(err) or time.monotonic() > deadline:
                raise
            time.sleep(0.05)
    try:
        with pytest.raises(BridgeError, match="restarted.*--resume"):
            bridge.now()
    finally:
        second.stop()


def test_when_the_retries_are_spent_the_error_names_endpoint_and_command():
    # A peer that is bound and never answers (a closed port could be taken by another test's CURVE server).
    placeholder = zmq.Context.instance().socket(zmq.ROUTER)
    port = placeholder.bind_to_random_port("tcp://127.0.0.1")
    endpoint = f"tcp://127.0.0.1:{port}"
    bridge = client(endpoint, timeout_s=0.05, retries=2)
    start = time.monotonic()
    try:
        with pytest.raises(BridgeError) as err:
            bridge.command(TARGETS[0], 0.2)
    finally:
        placeholder.close(linger=0)
    assert time.monotonic() - start < 2.0  # bounded: 3 attempts of 0.05 s, not forever
    assert endpoint in str(err.value) and "'command'" in str(err.value) and "3 attempt(s)" in str(err.value)

    fake = FakeBackend()
    server = BridgeServer(fake, "tcp://127.0.0.1:0").start_thread()
    bridge = client(server.endpoint, timeout_s=0.05, retries=2)
    bridge.command(TARGETS[0], 0.2)
    server.stop()
    with pytest.raises(BridgeError, match=rf"no reply from {server.endpoint} to 'command' .*3 attempt"):
        bridge.command(TARGETS[1], 0.2)
    assert sent_targets(fake) == TARGETS[:1]


def test_after_a_call_went_unanswered_the_next_calls_try_once_until_the_server_answers():
    """A server that died mid-run: its first unanswered call spends the retries, every later call one timeout (the
    shutdown's stop and release would otherwise take (1 + retries) timeouts each); a server back resets it."""
    fake = FakeBackend()
    server = BridgeServer(fake, "tcp://127.0.0.1:0").start_thread()
    endpoint = server.endpoint
    bridge = client(endpoint, timeout_s=0.1, retries=4)
    bridge.command(TARGETS[0], 0.2)
    server.stop()
    with pytest.raises(BridgeError, match="5 attempt"):
        bridge.command(TARGETS[1], 0.2)
    start = time.monotonic()
    with pytest.raises(BridgeError, match="1 attempt"):
        bridge.set_stiffness(["HeadYaw"], 0.0)
    assert time.monotonic() - start < 0.45  # one attempt of 0.1 s (+ reconnect), not five
    again = BridgeServer(fake, endpoint).start_thread()
    try:
        bridge.command(TARGETS[2], 0.2)  # answered: retries are back
    finally:
        again.stop()


# ---------------------------------------------------------------------------------------------- malformed input
def _valid_request(cmd):
    args = {
        "command": {"targets_rad": {"HeadYaw": 0.1}, "speed_fraction": 0.2},
        "set_stiffness": {"names": ["HeadYaw"], "stiffness": 1.0},
        "sleep": {"duration_s": 0.1},
    }.get(cmd, {})
    return protocol.make_request("fuzz:1", cmd, args)


SMALL_INT = st.integers(-1000, 1000)
NOT_A_NUMBER = st.one_of(st.none(), st.booleans(), st.text(max_size=5), st.binary(max_size=5),
                         st.lists(SMALL_INT, max_size=2), st.dictionaries(st.text(max_size=3), SMALL_INT, max_size=2))
WRONG_ARG = {  # values of the wrong type for each argument
    "targets_rad": st.one_of(NOT_A_NUMBER.filter(lambda v: not isinstance(v, dict)),
                             NOT_A_NUMBER.map(lambda v: {"HeadYaw": v})),
    "names": st.one_of(NOT_A_NUMBER.filter(lambda v: not isinstance(v, list)),
                       st.lists(NOT_A_NUMBER.filter(lambda v: not isinstance(v, str)), min_size=1, max_size=3)),
    "speed_fraction": NOT_A_NUMBER,
    "stiffness": NOT_A_NUMBER,
    "duration_s": NOT_A_NUMBER,
}
PLAIN = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-(2**63), 2**64 - 1), st.floats(), st.text(max_size=20),
              st.binary(max_size=20)),
    lambda children: st.one_of(st.lists(children, max_size=4), st.dictionaries(st.text(max_size=8), children,
                                                                                 max_size=4)),
    max_leaves=8,
)


@st.composite
def broken_requests(draw):
    """A request for a real command with exactly one thing wrong."""
    cmd = draw(st.sampled_from(sorted(protocol.COMMANDS)))
    message = _valid_request(cmd)
    mutation = draw(st.sampled_from(["drop_key", "version", "id", "cmd", "args_type", "extra_key", "extra_arg",
                                     "arg_type", "drop_arg", "top_level"]))
    if mutation == "drop_key":
        del message[draw(st.sampled_from(sorted(message)))]
    elif mutation == "version":
        message["v"] = draw(st.sampled_from([0, 2, -1, "1", 1.0, True, None, [1]]))
    elif mutation == "id":
        message["id"] = draw(st.one_of(st.sampled_from(["", "nocolon", "a:", ":1", "a:b", "a b:1", "x" * 65 + ":1"]),
                                       NOT_A_NUMBER.filter(lambda v: not isinstance(v, str))))
    elif mutation == "cmd":
        message["cmd"] = draw(st.one_of(st.text(max_size=12).filter(lambda c: c not in protocol.COMMANDS),
                                        NOT_A_NUMBER.filter(lambda v: not isinstance(v, str))))
    elif mutation == "args_type":
        message["args"] = draw(NOT_A_NUMBER.filter(lambda v: not isinstance(v, dict)))
    elif mutation == "extra_key":
        message[draw(st.text(max_size=6).filter(lambda k: k not in message))] = draw(PLAIN)
    elif mutation == "extra_arg":
        message["args"][draw(st.sampled_from(["targets_deg", "duration_ms", "x", "speed"]))] = 1.0
    elif mutation in ("arg_type", "drop_arg") and message["args"]:
        key = draw(st.sampled_from(sorted(message["args"])))
        if mutation == "drop_arg":
            del message["args"][key]
        else:
            message["args"][key] = draw(WRONG_ARG[key])
    else:
        message = draw(st.one_of(PLAIN.filter(lambda m: not isinstance(m, dict)), st.dictionaries(
            st.text(max_size=6), PLAIN, max_size=5)))
    return [b"", msgpack.packb(message, use_bin_type=True)]


MALFORMED = st.one_of(
    st.binary(max_size=300).map(lambda raw: [b"", raw]),  # random bytes
    st.binary(min_size=1, max_size=300).map(lambda raw: [raw]),  # no envelope delimiter
    PLAIN.map(lambda value: [b"", msgpack.packb(value, use_bin_type=True)]),  # wrong types
    broken_requests(),  # wrong types, missing keys, bad ids, unknown commands
    st.lists(st.binary(max_size=20), min_size=2, max_size=4).map(lambda frames: [b"", *frames]),  # extra frames
    st.integers(protocol.MAX_REQUEST_BYTES + 1, protocol.MAX_REQUEST_BYTES + 4096).map(  # huge
        lambda n: [b"", msgpack.packb({"v": 1, "id": "fuzz:1", "cmd": "now", "args": {"pad": b"\0" * n}})]),
    st.sampled_from([[b"", b"\x91" * 1100], [b"", b"\xdd\xff\xff\xff\xff"], [b"", b"\xc7\x05\x01abcde"],
                     [b"", b"\xdf\xff\xff\xff\xff"], [b"", b"\xd4\xff\x00"]]),  # deep nesting, bogus lengths, ext
)


def test_a_thousand_malformed_messages_get_error_replies_and_the_server_stays_up():
    fake = FakeBackend()
    with serving(fake) as server:
        socket = zmq.Context.instance().socket(zmq.DEALER)
        socket.setsockopt(zmq.LINGER, 0)
        socket.connect(server.endpoint)
        replies = []

        @settings(max_examples=1000, deadline=None, derandomize=True, database=None,
                  suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much])
        # One certain example of each error type, whatever the generator draws (its choices vary by version).
        @given(MALFORMED)
        @example([b"", protocol.pack({**protocol.make_request("x:1", "dance", {}), "cmd": "dance"})])
        @example([b"", protocol.pack({**protocol.make_request("x:2", "read_joints", {}), "v": 2})])
        @example([b"", b"\x00" * (protocol.MAX_REQUEST_BYTES + 1)])
        @example([b"", b"\xc1"])
        def send_garbage(frames):
            socket.send_multipart(frames)
            assert socket.poll(2000), f"no reply to {frames!r:.200}"
            reply = msgpack.unpackb(socket.recv_multipart()[-1], raw=False)
            assert reply["ok"] is False and reply["v"] == 1, reply
            assert reply["error"]["type"] in protocol.ERROR_TYPES and reply["error"]["message"]
            replies.append(reply["error"]["type"])

        send_garbage()
        socket.close(linger=0)
        bridge = BridgeBackend(server.endpoint, timeout_s=1.0)
        bridge.command(TARGETS[0], 0.2)
        assert bridge.read_joints().t_s == 0.0
    assert len(replies) >= 1000
    assert {"ProtocolError", "UnknownCommand", "UnsupportedVersion", "TooLarge"} <= set(replies)
    assert fake.executed == {"command": 1}  # none of the garbage moved the robot


def test_a_very_late_duplicate_is_refused_not_executed():
    fake = FakeBackend()
    with serving(fake, replies_kept_per_client=2) as server:
        socket = zmq.Context.instance().socket(zmq.DEALER)
        socket.setsockopt(zmq.LINGER, 0)
        socket.connect(server.endpoint)

        def send(message):
            socket.send_multipart([b"", protocol.pack(message)])
            assert socket.poll(2000)
            return protocol.unpack(socket.recv_multipart()[-1], max_bytes=1 << 20)

        token = send(protocol.make_request("late:0", "acquire", {"nonce": "n" * 22}))["result"]["token"]

        def request(seq, targets):
            return send(protocol.make_request(f"late:{seq}", "command", {"targets_rad": targets, "speed_fraction": 0.2},
                                              token=token))

        for seq in (1, 2, 3):
            assert request(seq, TARGETS[seq])["ok"]
        assert request(3, TARGETS[3]) == {"v": 1, "id": "late:3", "ok": True, "result": None}  # from the cache
        late = request(1, TARGETS[1])  # its reply is no longer kept
        assert late["ok"] is False and late["error"]["type"] == "StaleRequest"
        socket.close(linger=0)
    assert sent_targets(fake) == TARGETS[1:4]
