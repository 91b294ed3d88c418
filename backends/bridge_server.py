"""Robot-side bridge server: serves one robot over ZeroMQ: a NAO's `Backend` (the PyBullet mock, NAOqi, LoLA) or
another kind's served robot (kinds.duckiebot.bridge.ServedDuckiebot), each answering its kind's commands.

Socket: ROUTER, not REP. A REP socket must answer every request before it may receive the next one, so it cannot
drop or delay a reply (the fault injector does both), and a client that vanishes mid-request leaves it in a state
that needs care. ROUTER hands us each peer's routing id with the message: we answer whom we like, when we like,
malformed multipart messages included, and replies to peers that have gone away are discarded by libzmq.
Both REQ clients (with their empty delimiter frame) and DEALER clients (the naocal client) are served.

Guarantees (docs/PROTOCOL.md):
- every request gets a reply: a bad one an error reply, never a crash (up to ZMQ_MAX_INBOUND_BYTES; beyond it
  libzmq drops the connection before we see the message);
- one client at a time controls motion (`command`, `set_stiffness`, `sleep`): the one `acquire` gave the lease
  token to, until it sends `release` or stays silent for `lease_timeout_s`; the others may still read. Control is
  bound to that secret, not to a client id anyone can copy (backends/bridge_lease.py);
- any client may `stop` the robot, lease or not (CURVE, when on, still admits only its keys): the kind's safe state,
  which moves nothing (a Duckiebot's wheels at 0; a NAO's `release_control`). A stop the controller did not send is
  told to it at its next motion request (RobotFault, once, nothing executed): what it planned no longer holds;
- a motion is executed once: the replies of the controller's last `replies_kept_per_client` motion requests are
  kept under its lease, a retried one is answered from them and NOT executed again, whatever other clients send;
  with `journal_path` they (and the lease) also survive a restart of the server;
- a flood of idle connections neither exhausts the file descriptors nor spins the CPU (backends/bridge_guard.py).
"""

from __future__ import annotations

import ctypes
import logging
import os
import secrets
import threading
import time

import numpy as np
import zmq

from naocal.backends import protocol
from naocal.backends.base import Backend
from naocal.backends.bridge_endpoint import (check_bind_address, check_bound_endpoint, is_local_endpoint, split_endpoint,
                                      tcp_listen_hosts)
from naocal.backends.bridge_guard import HANDSHAKE_TIMEOUT_S, ConnectionGuard
from naocal.backends.bridge_keys import is_curve_key, load_client_keys, load_key_file, warn_if_others_can_read
from naocal.backends.bridge_lease import TOKEN_BYTES, LeaseJournal, MotionLease, digest
from naocal.backends.protocol import ControlError, ProtocolError, is_motion_command
from naocal.backends.errors import BridgeError, RobotFault, RobotTimeout
from naocal.solver.errors import NaocalError, SafetyError
from naocal.solver.fileio import atomic_write_bytes

log = logging.getLogger("naocal.bridge.server")

DEFAULT_BIND = "tcp://127.0.0.1:7790"
POLL_INTERVAL_S = 0.1  # how often the loop looks at its stop flag


MAX_LEASE_TIMEOUT_S = 86400.0  # a day: a silent controller loses the robot within a deadline, however long


def check_lease_timeout(lease_timeout_s) -> float:
    """A number of seconds in (0, MAX_LEASE_TIMEOUT_S] (NaN would make every lease look expired: anyone could take
    the robot; 1e308 would let a dead controller hold it for ever)."""
    value = float(lease_timeout_s)
    if not 0 < value <= MAX_LEASE_TIMEOUT_S:
        raise NaocalError(f"lease timeout (--lease-timeout-s) must be a number of seconds in "
                          f"(0, {MAX_LEASE_TIMEOUT_S:g}], got {lease_timeout_s}")
    return value


class FaultInjector:
    """Deliberate misbehaviour for fault tests, keyed by request id. Each fault fires once per id."""

    def __init__(self, *, drop_first_reply_of=(), delay_first_reply_of=None, crash_after_executing=()):
        self.drop_first_reply_of = set(drop_first_reply_of)
        self.delay_first_reply_of = dict(delay_first_reply_of or {})  # id -> delay in s
        self.crash_after_executing = set(crash_after_executing)  # stop the server without replying

    def action(self, request_id):
        if request_id in self.crash_after_executing:
            self.crash_after_executing.discard(request_id)
            return "crash"
        if request_id in self.drop_first_reply_of:
            self.drop_first_reply_of.discard(request_id)
            return "drop"
        if request_id in self.delay_first_reply_of:
            return float(self.delay_first_reply_of.pop(request_id))
        return None


class BridgeServer:
    """Serve `backend` on `bind`. Use `start()` then `serve_forever()`, or `start_thread()` / `stop()`.

    Parameters
    ----------
    backend : a NAO's Backend, or another kind's ServedRobot (kinds.duckiebot.bridge.ServedDuckiebot).
    driver : name reported to clients ('mock', 'naoqi', ...).
    clock : 'simulated' (the backend's clock only moves on `sleep`) or 'wall'.
    state_persists : True if the robot keeps its state when this server restarts (a real NAO), False for a mock
        created by this server (clients then treat a restart as fatal).
    """

    def __init__(
        self,
        backend: "Backend | ServedRobot",
        bind: str = DEFAULT_BIND,
        *,
        driver: str = "unknown",
        clock: str = "wall",
        state_persists: bool = True,
        allow_remote: bool = False,
        curve_secret_key_file=None,
        curve_clients_dir=None,
        lease_timeout_s: float = 120.0,
        replies_kept_per_client: int = 32,
        journal_path=None,
        faults: FaultInjector | None = None,
        context: zmq.Context | None = None,
    ):
        if clock not in ("simulated", "wall"):
            raise ValueError(f"clock must be 'simulated' or 'wall', got {clock!r}")
        check_bind_address(bind, allow_remote)
        self.backend = backend
        self._robot = served_robot(backend)
        self.bind = bind
        self.driver = driver
        self.clock = clock
        self.state_persists = bool(state_persists)
        self.lease_timeout_s = check_lease_timeout(lease_timeout_s)
        self.faults = faults
        self.server_id = secrets.token_hex(8)
        self.endpoint = None  # the bound address, with the real port, after start()
        self._curve_secret_key_file = curve_secret_key_file
        self._curve_clients_dir = curve_clients_dir
        self._context = context or zmq.Context.instance()
        self._replies_kept = int(replies_kept_per_client)
        self._journal = LeaseJournal(journal_path) if journal_path else None
        self._lease: MotionLease | None = self._journal.load(self._replies_kept) if self._journal else None
        self._allow_remote = bool(allow_remote)
        self._client_keys = 0  # public keys admitted by --curve-clients
        self._socket = None
        self._guard: ConnectionGuard | None = None
        self._authenticator = None
        self._stop = threading.Event()
        self._thread = None
        self._robot_id = None
        self._stop_notice = None  # (lease, why): a stop its holder did not send, told at its next motion request
        self.requests_served = 0

    # ------------------------------------------------------------------------------------------ lifecycle
    def start(self) -> "BridgeServer":
        """Bind the socket (errors such as 'address in use' are raised here)."""
        self._robot_id = str(self._robot.robot_identity().get("id", "unknown"))
        socket = self._context.socket(zmq.ROUTER)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.MAXMSGSIZE, protocol.ZMQ_MAX_INBOUND_BYTES)
        socket.setsockopt(zmq.HANDSHAKE_IVL, int(HANDSHAKE_TIMEOUT_S * 1000))
        scheme, address = split_endpoint(self.bind)
        if scheme == "tcp" and any(":" in host for host in tcp_listen_hosts(address)):
            socket.setsockopt(zmq.IPV6, 1)
        try:
            if self._curve_secret_key_file:
                self._configure_curve(socket)
            self._guard = ConnectionGuard(socket)
            socket.bind(self.bind)
            self.endpoint = socket.getsockopt_string(zmq.LAST_ENDPOINT)
            check_bound_endpoint(self.endpoint, self._allow_remote)  # whatever the parser above missed
            self._guard.listening_on(self.endpoint)
        except BaseException as err:
            if self.endpoint:
                try:
                    socket.unbind(self.endpoint)
                except zmq.ZMQError:
                    pass  # closing it below unbinds too
                self.endpoint = None
            self._close_socket(socket)
            if self._journal is not None:
                self._journal.close()
            if isinstance(err, zmq.ZMQError):
                raise NaocalError(f"cannot bind {self.bind}: {err}") from None
            raise
        self._socket = socket
        log.info("serving %s (%s, robot %s) on %s, %s", self.driver, self.clock, self._robot_id, self.endpoint,
                 self.security_summary())
        if not self._client_keys and not is_local_endpoint(self.endpoint):
            log.warning("listening beyond loopback without --curve-clients: anyone who reaches %s can read the "
                        "robot and take control of motion whenever no client holds it", self.endpoint)
        return self

    def security_summary(self) -> str:
        """One phrase for the start lines: is CURVE on, and whom does it admit."""
        if not self._curve_secret_key_file:
            return "CURVE off: unencrypted, any client"
        if self._client_keys:
            return f"CURVE on: encrypted, {self._client_keys} admitted client key(s)"
        return "CURVE on: encrypted, any client key"

    def _configure_curve(self, socket) -> None:
        key_file = os.fspath(self._curve_secret_key_file)
        public, secret = load_key_file(key_file, "the server's CURVE key")
        if secret is None:
            raise NaocalError(f"{key_file}: holds no secret key (give the *.key_secret file)")
        if not (is_curve_key(public) and is_curve_key(secret)):
            raise NaocalError(f"{key_file}: not a CURVE key pair (expected a file written by naocal bridge keygen)")
        warn_if_others_can_read(key_file)
        if self._curve_clients_dir:
            from zmq.auth.thread import ThreadAuthenticator

            self._client_keys = len(load_client_keys(self._curve_clients_dir))
            self._authenticator = ThreadAuthenticator(self._context)
            self._authenticator.start()
            self._authenticator.configure_curve(domain="*", location=os.fspath(self._curve_clients_dir))
        socket.curve_secretkey = secret
        socket.curve_publickey = public
        socket.curve_server = True

    def serve_forever(self) -> None:
        """Answer requests until `stop()` (or a fault-injected crash). Closes the socket on the way out."""
        if self._socket is None:
            self.start()
        try:
            while not self._stop.is_set():
                self._expire_idle_lease()
                if not self._socket.poll(POLL_INTERVAL_S * 1000, zmq.POLLIN):
                    continue
                frames = self._socket.recv_multipart(zmq.NOBLOCK, copy=False)
                try:
                    self._handle([frame.bytes for frame in frames], _source_fd(frames[0]))
                except Exception:  # a bug in handling one message must not take the robot's server down
                    log.exception("could not handle a message of %d frame(s)", len(frames))
        finally:
            self._close_socket(self._socket)
            self._socket = None
            if self._journal is not None:
                self._journal.close()

    def _close_socket(self, socket) -> None:
        if self._guard is not None:
            self._guard.stop()  # before the socket closes: it switches the socket's monitor off
            self._guard = None
        socket.close(linger=0)
        self._stop_authenticator()

    def start_thread(self) -> "BridgeServer":
        self.start()
        self._thread = threading.Thread(target=self.serve_forever, name="naocal-bridge-server", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                raise BridgeError(f"bridge server on {self.endpoint} did not stop within {timeout_s} s")
            self._thread = None

    def _stop_authenticator(self) -> None:
        if self._authenticator is not None:
            self._authenticator.stop()
            self._authenticator = None

    def exactly_once_entries(self) -> int:
        """Motion replies kept for deduplication (bounded: see backends/bridge_lease.py)."""
        return self._lease.entries() if self._lease is not None else 0

    # ------------------------------------------------------------------------------------------ requests
    def _handle(self, frames: list[bytes], source_fd: int | None = None) -> None:
        routing_id, body = frames[0], frames[1:]
        envelope = [b""] if body and body[0] == b"" else []
        payload_frames = body[len(envelope):]
        if len(payload_frames) != 1:
            self._send(routing_id, envelope, protocol.error_reply(
                None, "ProtocolError", f"expected one payload frame after the envelope, got {len(payload_frames)}"))
            return
        payload = payload_frames[0]
        request_id = None
        try:
            message = protocol.unpack(payload, max_bytes=protocol.MAX_REQUEST_BYTES)
            request_id = _request_id_if_valid(message)
            request_id, cmd, args = protocol.validate_request(message, self._robot.kind)
            token = protocol.request_token(message)
        except ProtocolError as err:
            self._send(routing_id, envelope, protocol.error_reply(request_id, err.error_type, str(err)))
            return

        client, seq = protocol.parse_request_id(request_id)
        lease = self._lease
        controller = lease is not None and lease.held_by(token)
        if controller:
            lease.touch()
        if self._guard is not None:
            self._guard.note_request(source_fd, controller=controller)

        if is_motion_command(cmd):
            reply = self._motion(request_id, client, seq, cmd, args, lease if controller else None)
            if reply is None:
                return  # answered from the lease's replies
        else:
            reply = self._execute(request_id, cmd, args, token)
        self.requests_served += 1

        action = self.faults.action(request_id) if self.faults else None
        if action == "crash":
            log.warning("fault injector: stopping after executing %s, reply not sent", request_id)
            self._stop.set()
            return
        if action == "drop":
            log.warning("fault injector: dropping the reply to %s", request_id)
            return
        if action is not None:
            time.sleep(action)
        self._send(routing_id, envelope, reply)

    def _motion(self, request_id: str, client: str, seq: int, cmd: str, args: dict, lease: MotionLease | None):
        """Run a motion request of the lease holder exactly once; the encoded reply, or None if it was sent."""
        if lease is None:
            return protocol.pack(protocol.error_reply(request_id, "ControlError", self._not_controller()))
        status, cached = lease.lookup(client, seq)
        if status == "hit":
            log.info("request %s (%s) answered from the lease's replies, not executed again", request_id, cmd)
            return cached
        if status == "stale":
            return protocol.pack(protocol.error_reply(
                request_id, "StaleRequest", f"request {request_id} is older than the replies this server keeps; "
                                            "not executed"))
        notice = self._stop_notice
        if notice is not None and notice[0] is lease:
            self._stop_notice = None
            reply = protocol.pack(protocol.error_reply(request_id, "RobotFault", f"{notice[1]}; {cmd} not executed"))
            lease.store(client, seq, reply)  # a retry of this request hears the same
            return reply
        journaled = self._journal is not None and cmd not in protocol.NOT_JOURNALED
        if journaled:
            try:
                self._journal.ensure_room()
            except (NaocalError, OSError) as err:  # nothing executed, nothing kept: a retry may run it later
                return protocol.pack(protocol.error_reply(request_id, "NaocalError", str(err)))
        reply = self._execute(request_id, cmd, args, None)
        if journaled:
            try:
                self._journal.reply(lease, client, seq, reply)
            except NaocalError as err:
                log.error("%s", err)
                reply = protocol.pack(protocol.error_reply(
                    request_id, "NaocalError", f"{err}; the {cmd} WAS executed, but a restarted server would not "
                                               "know it: stop, free some space and resume"))
        lease.store(client, seq, reply)
        return reply

    def _not_controller(self) -> str:
        """Why a motion request without a valid token is refused; names nobody."""
        lease = self._lease
        if lease is None:
            return "motion needs the lease: send 'acquire' first"
        idle_s = lease.idle_s()
        if idle_s >= self.lease_timeout_s:
            return f"the lease is free (its holder has been idle {idle_s:.0f} s): send 'acquire'"
        return (f"another client controls the robot (idle {idle_s:.1f} s of {self.lease_timeout_s:g} s); reads are "
                "allowed, motion is not")

    def _send(self, routing_id: bytes, envelope: list[bytes], reply) -> None:
        data = reply if isinstance(reply, bytes) else protocol.pack(reply)
        try:
            self._socket.send_multipart([routing_id, *envelope, data], zmq.NOBLOCK)
        except zmq.Again:
            log.warning("reply dropped: the client's queue is full")

    def _execute(self, request_id: str, cmd: str, args: dict, token: str | None) -> bytes:
        """Run one validated request and encode its reply; every failure becomes an error reply."""
        try:
            return protocol.pack(protocol.ok_reply(request_id, self._dispatch(cmd, args, token)))
        except ProtocolError as err:
            reply = protocol.error_reply(request_id, err.error_type, str(err))
        except ControlError as err:
            reply = protocol.error_reply(request_id, "ControlError", str(err))
        except SafetyError as err:
            reply = protocol.error_reply(request_id, "SafetyError", str(err))
        except (RobotTimeout, RobotFault) as err:
            reply = protocol.error_reply(request_id, type(err).__name__, str(err))
        except NaocalError as err:
            reply = protocol.error_reply(request_id, "NaocalError", f"{type(err).__name__}: {err}")
        except Exception as err:  # a bug or a robot failure behind the backend: report it, keep serving
            log.exception("request %s (%s) failed", request_id, cmd)
            reply = protocol.error_reply(request_id, "InternalError", f"{type(err).__name__}: {err}")
        return protocol.pack(reply)

    def _acquire(self, token: str | None, nonce: str) -> dict:
        """Grant the lease, or give it back to its holder (a resumed agent shows its token; a retried acquire
        whose reply was lost shows its nonce). ControlError while another client holds it."""
        lease = self._lease
        if lease is not None:
            if lease.held_by(token) or lease.created_by(nonce):
                lease.touch()
                if lease.token is None:
                    lease.token = token
                    log.info("the controller reclaimed its motion lease")
                return {"token": lease.token, "lease_timeout_s": self.lease_timeout_s}
            if lease.idle_s() < self.lease_timeout_s:
                raise ControlError(self._not_controller())
            log.warning("the controlling client was idle %.1f s: its motion lease passes on", lease.idle_s())
        token = secrets.token_urlsafe(TOKEN_BYTES)
        self._lease = MotionLease(digest(token), token=token, nonce_digest=digest(nonce),
                                  replies_kept=self._replies_kept)
        self._journal_event("granted", self._lease)
        self._robot.control_granted()
        log.info("a client now controls motion")
        return {"token": token, "lease_timeout_s": self.lease_timeout_s}

    def _expire_idle_lease(self) -> None:
        """A controller silent past its lease has let go: the backend makes the robot safe (the LoLA driver holds,
        then ramps stiffness down) without waiting for another client to take over. The lease object stays until
        another client acquires: its holder may still come back with its token, and its replies are kept."""
        lease = self._lease
        if lease is None or lease.control_released or lease.idle_s() < self.lease_timeout_s:
            return
        log.warning("the controlling client has been silent for %.1f s: its motion lease expired", lease.idle_s())
        lease.control_released = True
        self._release_control()

    def _release_control(self) -> None:
        try:
            self._robot.release_control()
        except Exception:  # the server must keep serving whatever the driver does
            log.exception("the driver failed to make the robot safe after control ended")

    def _journal_event(self, event: str, lease: MotionLease) -> None:
        if self._journal is None:
            return
        try:
            getattr(self._journal, event)(lease)
        except NaocalError as err:  # the lease still works; only a restart would forget it
            log.error("%s", err)

    def _dispatch(self, cmd: str, args: dict, token: str | None):
        """The session's commands here; the robot's (its kind's) in the served robot."""
        if cmd == "hello":
            lease = self._lease
            return {
                "protocol": protocol.PROTOCOL_VERSION,
                "revision": protocol.PROTOCOL_REVISION,
                "kind": self._robot.kind,
                "server_id": self.server_id,
                "driver": self.driver,
                "robot_id": self._robot_id,
                "clock": self.clock,
                "state_persists": self.state_persists,
                "keeps_commands_on_close": self._robot.keeps_commands_on_close,
                "controlled": lease is not None and lease.idle_s() < self.lease_timeout_s,  # by whom is not said
                "lease_timeout_s": self.lease_timeout_s,
                "max_request_bytes": protocol.MAX_REQUEST_BYTES,
                "max_sleep_s": protocol.MAX_SLEEP_S,
                **self._robot.hello(),
            }
        if cmd == "acquire":
            return self._acquire(token, args["nonce"])
        if cmd == "stop":
            return self._stop_robot(token)
        if cmd == "release":
            lease = self._lease
            if lease is not None and lease.held_by(token):
                log.info("the controller released motion")
                self._lease = None
                self._journal_event("released", lease)
                self._release_control()
            return None
        return self._robot.dispatch(cmd, args)

    def _stop_robot(self, token: str | None):
        """`stop`, from any client: the served robot's safe state (its kind's `stop` command, which moves nothing).
        Sent by anyone but the controller, it is told to the controller at its next motion request."""
        lease = self._lease
        result = self._robot.dispatch("stop", {})
        if lease is not None and not lease.held_by(token):
            log.warning("a client without the lease stopped the robot")
            self._stop_notice = (lease, "another client stopped the robot (stop without the lease)")
        return result


def check_sleep(duration_s: float) -> float:
    """A `sleep` request's duration: within [0, MAX_SLEEP_S] (NaN refused), else ProtocolError."""
    if not 0.0 <= duration_s <= protocol.MAX_SLEEP_S:
        raise ProtocolError(f"sleep: duration_s must be in [0, {protocol.MAX_SLEEP_S:g}] s, got {duration_s}")
    return duration_s


class ServedRobot:
    """A robot as the bridge serves it, one per kind (ServedNao; kinds.duckiebot.bridge.ServedDuckiebot)."""

    kind: str  # its protocol.KIND_COMMANDS key: the commands the server answers
    # Does what the controller commanded stay in force when this server ends and another starts? Not where the end
    # makes the robot safe (close, below): a client that finds the server restarted then ends its run
    # (BridgeClient._check_same_server)
    keeps_commands_on_close = False

    def robot_identity(self) -> dict:
        """{"id": ..., ...}: the robot the hello names."""
        raise NotImplementedError

    def hello(self) -> dict:
        """This kind's own keys of the hello reply."""
        return {}

    def dispatch(self, cmd: str, args: dict):
        """Run one of this kind's commands (validated arguments; motion ones from the lease holder only): its result,
        plain msgpack types. Raises SafetyError, RobotFault, RobotTimeout, NaocalError as a driver does. `stop` comes
        from any client: the robot's safe state, moving nothing."""
        raise NotImplementedError

    def control_granted(self) -> None:
        """A new controller (not one taking its own lease back) starts: what was kept for the last one is not its."""

    def release_control(self) -> None:
        """Nobody controls the robot any more (released, or the lease lapsed): its safe state."""

    def close(self) -> None:
        """The server is done: the safe state, the driver closed."""


class ServedNao(ServedRobot):
    """A NAO's `Backend` (the mock, NAOqi, LoLA) as the bridge serves it: the NAO's commands (protocol.COMMANDS)."""

    kind = "nao"

    def __init__(self, backend: Backend):
        self.backend = backend
        self.keeps_commands_on_close = getattr(backend, "keeps_commands_on_close", False) is True  # the driver's word

    def robot_identity(self) -> dict:
        return self.backend.robot_identity()

    def hello(self) -> dict:
        return {"cameras": [str(c) for c in getattr(self.backend, "cameras", ("bottom",))]}

    def release_control(self) -> None:
        self.backend.release_control()

    def close(self) -> None:
        self.backend.close()

    def dispatch(self, cmd: str, args: dict):
        backend = self.backend
        if cmd == "robot_identity":
            return {str(k): str(v) for k, v in backend.robot_identity().items()}
        if cmd == "joint_names":
            return [str(name) for name in backend.joint_names()]
        if cmd == "joint_limits":
            return {str(name): [float(lo), float(hi)] for name, (lo, hi) in backend.joint_limits().items()}
        if cmd == "max_speeds":
            return {str(name): float(speed) for name, speed in backend.max_speeds().items()}
        if cmd == "intrinsics":
            return backend.intrinsics().to_dict()
        if cmd == "gravity_torso":
            return [float(g) for g in np.asarray(backend.gravity_torso_mps2(), dtype=float).reshape(3)]
        if cmd == "read_joints":
            return protocol.joint_reading_to_wire(backend.read_joints())
        if cmd == "capture":
            camera = args["camera"]  # a backend that has only the bottom camera takes no argument
            return protocol.image_to_wire(backend.capture() if camera == "bottom" else backend.capture(camera))
        if cmd == "now":
            return float(backend.now())
        if cmd == "status":
            return backend.status()
        if cmd == "command":
            backend.command(args["targets_rad"], args["speed_fraction"])
            return None
        if cmd == "set_stiffness":
            backend.set_stiffness(args["names"], args["stiffness"])
            return None
        if cmd == "sleep":
            backend.sleep(check_sleep(args["duration_s"]))
            return None
        if cmd == "stop":  # the NAO's safe state is the one control ending gives: the driver's, no motion invented
            backend.release_control()
            return None
        raise ProtocolError(f"unknown command {cmd!r}", "UnknownCommand")  # COMMANDS and this table disagree


def served_robot(backend) -> ServedRobot:
    """What the server serves: a kind's ServedRobot as it is, a NAO's Backend (the bridge's first) as a ServedNao."""
    return backend if isinstance(backend, ServedRobot) else ServedNao(backend)


def keep_large_buffers_in_heap() -> bool:
    """Ask glibc to serve buffers of up to 32 MiB from the heap rather than from fresh memory mappings.

    Each image reply allocates and frees several buffers of about 1 MiB. As fresh mappings each one costs page
    faults and, when unmapped, a TLB shootdown across cores: on a 2-core VM that made an image round trip 4 ms
    instead of under 1 ms (benchmarks/bench_bridge.py). Process-wide, so only `naocal bridge serve` calls it.
    Returns False where there is no glibc.
    """
    m_trim_threshold, m_mmap_threshold = -1, -3  # from glibc's malloc.h
    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(m_mmap_threshold, 32 << 20)) and bool(libc.mallopt(m_trim_threshold, 128 << 20))
    except (OSError, AttributeError):
        return False


def write_curve_keys(directory, name: str = "server") -> tuple[str, str]:
    """Write a new CURVE key pair as `<name>.key` (public, to give to the other side) and `<name>.key_secret`
    (mode 0600) in ZeroMQ's certificate format. Refuses to overwrite existing keys. Returns both paths.
    """
    if not name or "/" in name or name.startswith("."):
        raise NaocalError(f"key name {name!r}: expected a plain file name such as 'server'")
    public_path = os.path.join(os.fspath(directory), f"{name}.key")
    secret_path = public_path + "_secret"
    for path in (public_path, secret_path):
        if os.path.exists(path):
            raise NaocalError(f"{path}: already exists; not overwriting a key (move it away first)")
    public, secret = (key.decode("ascii") for key in zmq.curve_keypair())
    banner = f"#   ZeroMQ CURVE certificate written by naocal bridge keygen on {time.strftime('%Y-%m-%d %H:%M:%S')}\n"
    public_text = f"{banner}metadata\ncurve\n    public-key = \"{public}\"\n"
    secret_text = (f"{banner}#   SECRET: keep it on the machine that uses it.\nmetadata\ncurve\n"
                   f"    public-key = \"{public}\"\n    secret-key = \"{secret}\"\n")
    try:
        atomic_write_bytes(secret_path, secret_text.encode("ascii"), mode=0o600)
        atomic_write_bytes(public_path, public_text.encode("ascii"), mode=0o644)
    except OSError as err:
        raise NaocalError(f"{err.filename or directory}: cannot write the key files: {err.strerror}") from None
    return public_path, secret_path


def _request_id_if_valid(message):
    """The request's id if it is well-formed (so even an error reply can name it), else None."""
    if isinstance(message, dict):
        try:
            protocol.parse_request_id(message.get("id"))
            return message["id"]
        except ProtocolError:
            return None
    return None


def _source_fd(frame) -> int | None:
    """The file descriptor of the connection a message came from (ZMQ_SRCFD), or None where unknown."""
    try:
        fd = frame.get(zmq.SRCFD)
    except (zmq.ZMQError, AttributeError, TypeError, ValueError):
        return None
    return fd if isinstance(fd, int) and fd >= 0 else None
