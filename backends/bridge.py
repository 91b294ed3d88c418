"""`BridgeClient`, the client of `naocal bridge serve`, and `BridgeBackend`: a NAO's Backend interface over it.

Lazy Pirate (ZeroMQ guide, ch. 4): one request at a time on a DEALER socket; wait for the reply with a deadline;
on timeout close the socket, open a fresh one and resend the SAME request (same id), at most `retries` times,
then raise BridgeError naming the endpoint and the command. The server deduplicates request ids, so a command
whose reply was lost is answered from its reply cache and never executed twice.

Motion needs the lease: before its first motion command the client asks for it (`acquire`) and from then on
sends the secret token the server answered with on every request. With `lease_file` the token is also kept on
disk (mode 0600), so the same agent, killed and resumed, takes its lease back at once instead of waiting for it
to time out; a stranger without the file still cannot.

A resumed agent's first motion request takes its lease back and first hears, with zero-length sleeps that move
nothing, the stops the server told the killed process's lease while it was gone (another client's `stop`, a
Duckiebot's watchdog): they were about that process's plans, not the resumed run's (take_back_lease).

A retry that succeeds may have reached a restarted server. The client then asks the server who it is: it carries
on only if the robot kept both its state and what this client commanded (NAOqi keeps its last targets and
stiffness); a mock the server created started afresh, and a server whose end made the robot safe (the LoLA
driver ramps the joints limp, a Duckiebot's wheels stop) left a robot that no longer does what the run believes.
Either way it raises BridgeError (the run ends; `--resume` continues it) rather than go on.

Not thread-safe: one BridgeBackend per thread.
"""

from __future__ import annotations

import logging
import math
import os
import secrets
import stat
import time

import numpy as np
import zmq
from zmq.utils.monitor import recv_monitor_message

from naocal.backends import protocol
from naocal.backends.base import Backend, CameraImage, CameraIntrinsics, JointReading
from naocal.backends.bridge_endpoint import check_client_endpoint
from naocal.backends.protocol import ControlError, ProtocolError
from naocal.backends.errors import BridgeError, RobotFault, RobotTimeout
from naocal.solver.errors import NaocalError, SafetyError

log = logging.getLogger("naocal.bridge.client")

MAX_TIMEOUT_S = 3600.0  # the longest a request may wait for its reply
FIRST_CONTACT_TIMEOUT_S = 5.0  # check_server_answers: longer than a wall-clock server's longest sleep chunk
WALL_CLOCK_SLEEP_CHUNK_S = 1.0  # a wall-clock server blocks while it sleeps: keep each sleep short
# A resumed client hears at most two stops it missed (the server's stop notice, the served robot's own: a Duckiebot's
# watchdog), each once; a third refusal is the robot refusing motion now (a driver's latched fault)
MAX_MISSED_STOPS = 3
HANDSHAKE_FAILURES = (zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL | zmq.EVENT_HANDSHAKE_FAILED_AUTH
                      | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL)


class BridgeClient:
    """The client side of a naocal bridge, for any robot kind: transport (Lazy Pirate), CURVE, the motion lease,
    the server's hello and its clock. BridgeBackend (a NAO) and kinds.duckiebot.bridge.DuckiebotBridge add their
    kind's commands; `kind` None (ping, first contact) talks to a server of any kind.

    Parameters
    ----------
    endpoint : the server's address, e.g. 'tcp://nao.local:7790'.
    timeout_s : how long one attempt waits for its reply (a `sleep` waits its duration on top, see
        `sim_slowdown`).
    retries : further attempts after a timeout, each on a fresh connection with the same request id.
    curve_server_key : the server's public CURVE key file; enables encryption and authenticates the server.
        Default: the file named by the environment variable NAOCAL_CURVE_SERVER_KEY, if set.
    curve_client_key : this client's secret key file (needed if the server only admits known clients);
        without it an ephemeral key pair is used. Default: $NAOCAL_CURVE_CLIENT_KEY, if set.
    sim_slowdown : for a server with a simulated clock, wall-clock seconds allowed per simulated second of `sleep`.
    lease_file : where to keep the motion lease's token (an agent's run directory), so that a resumed run takes
        its own lease back; None keeps it in memory only.
    """

    name = "bridge"
    kind: str | None = None  # the robot kind this client speaks to (hello's `kind`); None: any

    def __init__(
        self,
        endpoint: str,
        *,
        timeout_s: float = 3.0,
        retries: int = 3,
        curve_server_key=None,
        curve_client_key=None,
        client_id: str | None = None,
        sim_slowdown: float = 20.0,
        lease_file=None,
        context: zmq.Context | None = None,
    ):
        check_client_endpoint(endpoint)
        # Every wait has a deadline, and one libzmq can take (a poll in ms: 1e308 s overflowed).
        if not (isinstance(timeout_s, (int, float)) and 0 < timeout_s <= MAX_TIMEOUT_S):
            raise BridgeError(f"bridge timeout (--timeout-s) must be a number of seconds in (0, {MAX_TIMEOUT_S:g}], "
                              f"got {timeout_s}")
        if not retries >= 0:
            raise ValueError("retries must be >= 0")
        self.endpoint = endpoint
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.sim_slowdown = float(sim_slowdown)
        self._unanswered = False  # the last call's every attempt went unanswered
        self.client_id = client_id or secrets.token_hex(8)
        protocol.parse_request_id(f"{self.client_id}:0")  # a client id the server accepts
        self._context = context or zmq.Context.instance()
        # The agent's command line need not know about CURVE: the key files may come from the environment.
        curve_server_key = curve_server_key or os.environ.get("NAOCAL_CURVE_SERVER_KEY") or None
        curve_client_key = curve_client_key or os.environ.get("NAOCAL_CURVE_CLIENT_KEY") or None
        self._curve = _load_client_curve(curve_server_key, curve_client_key) if curve_server_key else None
        self._curve_server_key = curve_server_key
        self.lease_file = os.fspath(lease_file) if lease_file else None
        self._token: str | None = None  # the motion lease's secret, once acquired
        self._socket = None
        self._monitor = None
        self._seq = 0
        self._server: dict | None = None
        self._static: dict = {}
        self._closed = False

    # ------------------------------------------------------------------------------------------ transport
    def _connect(self):
        socket = self._context.socket(zmq.DEALER)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.MAXMSGSIZE, protocol.MAX_REPLY_BYTES)
        # No silent reconnection: a dropped connection shows up as a timeout, and the retry after it checks
        # whether the server restarted (see _check_same_server).
        socket.setsockopt(zmq.RECONNECT_IVL, -1)
        if self._curve is not None:
            server_public, client_public, client_secret = self._curve
            socket.curve_serverkey = server_public
            socket.curve_publickey = client_public
            socket.curve_secretkey = client_secret
        # Handshake failures (a CURVE key missing, wrong or not admitted) are otherwise silence until the timeout.
        # A fresh inproc name per socket: pyzmq's default names the socket's fd, which a socket closed a moment ago
        # may still own, and its old monitor would take the events.
        address = f"inproc://naocal-client-monitor-{secrets.token_hex(8)}"
        socket.monitor(address, HANDSHAKE_FAILURES)
        self._monitor = self._context.socket(zmq.PAIR)
        self._monitor.setsockopt(zmq.LINGER, 0)
        self._monitor.setsockopt(zmq.RCVHWM, 0)  # libzmq's sends to it block; disable_monitor() holds the GIL
        self._monitor.connect(address)
        socket.connect(self.endpoint)
        return socket

    def _drop_socket(self) -> None:
        if self._socket is not None:
            try:
                self._socket.disable_monitor()
            except zmq.ZMQError:
                pass
            self._monitor.close(linger=0)
            self._monitor = None
            self._socket.close(linger=0)
            self._socket = None

    def _call(self, cmd: str, args: dict | None = None, *, timeout_s: float | None = None, retries: int | None = None):
        """Send one request and return its result; retry on timeout with the same id (Lazy Pirate)."""
        if self._closed:
            raise BridgeError(f"bridge to {self.endpoint} is closed ({cmd})")
        if self._server is None and cmd != "hello":
            try:
                self._server_info()  # first contact: check the protocol, learn the server's id and clock
            except BridgeError as err:
                raise BridgeError(f"'{cmd}' needs the server first: {err}") from None
        self._seq += 1
        request_id = f"{self.client_id}:{self._seq}"
        payload = protocol.pack(protocol.make_request(request_id, cmd, args, token=self._token))
        if len(payload) > protocol.MAX_REQUEST_BYTES:
            raise BridgeError(f"{self.endpoint}: {cmd}: request of {len(payload)} bytes is too large")
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        # A server that left a whole call unanswered is presumed gone: one attempt per call until it answers again,
        # so that the calls of a shutdown (stop, release) fail in one timeout each, not (1 + retries).
        attempts = 1 if self._unanswered else 1 + (self.retries if retries is None else retries)
        reconnected = False
        for attempt in range(attempts):
            if self._socket is None:
                self._socket = self._connect()
                reconnected = True
            try:
                reply = self._attempt(payload, request_id, cmd, timeout_s)
            except BridgeError:
                self._drop_socket()
                raise
            if reply is not None:
                self._unanswered = False
                if reconnected and cmd != "hello":
                    self._check_same_server(cmd)
                return self._result(reply, cmd)
            self._drop_socket()  # the Lazy Pirate reset: a fresh connection for the retry
            if attempt + 1 < attempts:
                log.warning("no reply from %s to %s (%s) within %.2f s; retrying (%d of %d)",
                            self.endpoint, cmd, request_id, timeout_s, attempt + 1, attempts - 1)
        self._unanswered = True
        raise BridgeError(
            f"no reply from {self.endpoint} to '{cmd}' (request {request_id}) after {attempts} attempt(s) "
            f"of {timeout_s:.2f} s; is `naocal bridge serve` running there?"
        )

    def _attempt(self, payload: bytes, request_id: str, cmd: str, timeout_s: float):
        """Send once and wait until the deadline for the matching reply; None on timeout."""
        deadline = time.monotonic() + timeout_s
        poller = zmq.Poller()
        poller.register(self._monitor, zmq.POLLIN)
        try:
            self._socket.send_multipart([b"", payload], zmq.NOBLOCK)
            poller.register(self._socket, zmq.POLLIN)
        except zmq.Again:  # no connection to queue on (it may have failed its handshake already): wait and see
            pass
        while True:
            remaining_s = deadline - time.monotonic()
            ready = dict(poller.poll(remaining_s * 1000)) if remaining_s > 0 else {}
            if self._monitor in ready:
                self._raise_handshake_failure()
            if self._socket not in ready:
                return None
            frames = self._socket.recv_multipart(zmq.NOBLOCK)
            try:
                message = protocol.unpack(frames[-1], max_bytes=protocol.MAX_REPLY_BYTES)
            except ProtocolError as err:
                raise BridgeError(f"{self.endpoint}: {cmd}: unreadable reply: {err}") from None
            if isinstance(message, dict) and message.get("id") is None and message.get("ok") is False:
                try:
                    error = protocol.checked_error(message.get("error"))  # checked before it is echoed
                except ProtocolError as err:
                    raise BridgeError(f"{self.endpoint}: {cmd}: malformed reply: {err}") from None
                raise BridgeError(f"{self.endpoint}: {cmd}: server refused the request: "
                                  f"{error['type']}: {error['message']}")
            if isinstance(message, dict) and message.get("id") != request_id:
                log.debug("discarding a reply to %r while waiting for %s", message.get("id"), request_id)
                continue
            try:
                return protocol.validate_reply(message, request_id)
            except ProtocolError as err:
                raise BridgeError(f"{self.endpoint}: {cmd}: malformed reply: {err}") from None

    def _raise_handshake_failure(self) -> None:
        """The connection failed its ZeroMQ handshake: say why in words (it will not heal by retrying)."""
        event = recv_monitor_message(self._monitor, zmq.NOBLOCK)
        kind, value = event["event"], event["value"]
        mismatch = kind == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL and value == zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH
        if self._curve is None:
            # A plain client's handshake with a naocal server fails only on a security mechanism mismatch; the
            # server may hang up before the client has read why (EPIPE, "no detail"), so this is the likely cause.
            raise BridgeError(f"{self.endpoint}: the server requires CURVE keys (the handshake failed): give its "
                              "public key with --curve-server-key FILE or $NAOCAL_CURVE_SERVER_KEY")
        if mismatch:
            raise BridgeError(f"{self.endpoint}: the server does not use CURVE, but this client was given its key "
                              f"{self._curve_server_key}; start the server with --curve-secret-key, or drop the key")
        if kind == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
            raise BridgeError(f"{self.endpoint}: the server does not admit this client's CURVE key (status {value}): "
                              "put the client's public .key in the server's --curve-clients DIR and give its "
                              "secret with --curve-client-key FILE or $NAOCAL_CURVE_CLIENT_KEY")
        raise BridgeError(f"{self.endpoint}: the CURVE handshake failed: is {self._curve_server_key} the public key of "
                          "this server (and does it use CURVE)?")

    def _result(self, reply: dict, cmd: str):
        if reply["ok"]:
            return reply["result"]
        error_type, message = reply["error"]["type"], reply["error"]["message"]
        if error_type == "SafetyError":
            raise SafetyError(message)
        if error_type == "RobotTimeout":
            raise RobotTimeout(message)
        if error_type == "RobotFault":
            raise RobotFault(message)
        if error_type == "ControlError":
            raise ControlError(f"{self.endpoint}: {cmd}: {message}")
        raise BridgeError(f"{self.endpoint}: {cmd}: {error_type}: {message}")

    def _server_info(self) -> dict:
        if self._server is None:
            info = self._call("hello")
            if not isinstance(info, dict) or info.get("protocol") != protocol.PROTOCOL_VERSION:
                raise BridgeError(f"{self.endpoint}: server does not speak protocol {protocol.PROTOCOL_VERSION}")
            served = info.get("kind", "nao")  # a revision-1 server served NAOs only
            if self.kind is not None and served != self.kind:
                older = "" if "kind" in info else " (an older naocal, protocol revision 1: update naocal there)"
                raise BridgeError(f"{self.endpoint}: the bridge there serves a {served}{older}, not a {self.kind}")
            self._server = info
        return self._server

    def _check_same_server(self, cmd: str) -> None:
        """After a reconnection: did the server restart? Then carry on only if the robot kept its state and what
        this client commanded, by the word of both servers (hello's `keeps_commands_on_close`, True only: an older
        server that does not say is taken not to); else BridgeError: the run's record would no longer follow the
        robot (a fresh mock; a LoLA robot ramped limp; a Duckiebot's wheels stopped)."""
        if self._server is None:
            return
        before = self._server
        self._server = None
        after = self._server_info()
        if after.get("server_id") == before.get("server_id"):
            return
        if after.get("state_persists") is not True:
            why = "its robot started afresh (state and clock lost)"
        elif not all(hello.get("keeps_commands_on_close") is True for hello in (before, after)):
            why = "it made the robot safe as it ended (what this run commanded no longer holds)"
        else:
            log.warning("%s: bridge server restarted; the robot kept its state and commands, carrying on", self.endpoint)
            return
        raise BridgeError(f"{self.endpoint}: the bridge server restarted during '{cmd}' and {why}: this run no longer "
                          "follows the robot; continue it with --resume")

    def server_info(self) -> dict:
        """The server's hello: protocol, server_id, driver, robot_id, clock, state_persists, controlled."""
        return dict(self._server_info())

    # ------------------------------------------------------------------------------------------ motion lease
    def _motion_call(self, cmd: str, args: dict, *, timeout_s: float | None = None):
        """A motion request under the lease: acquire it first; if the server refuses (ControlError: nothing was
        executed), the lease may have lapsed (a restarted server, a timeout nobody used): ask for it once more."""
        if self._token is None:
            if self._server is None:
                try:
                    self._server_info()
                except BridgeError as err:
                    raise BridgeError(f"'{cmd}' needs the server first: {err}") from None
            self._acquire_lease()
        try:
            return self._call(cmd, args, timeout_s=timeout_s)
        except ControlError:
            self._acquire_lease()
        return self._call(cmd, args, timeout_s=timeout_s)

    def _acquire_lease(self) -> None:
        """Ask for the motion lease, showing the token we (or the run we resume) had, if any."""
        from_file = self._token is None
        had = self._token or self._read_lease_file()
        self._token = had
        try:
            result = self._call("acquire", {"nonce": secrets.token_urlsafe(16)})
            token = result.get("token") if isinstance(result, dict) else None
            if not isinstance(token, str) or not protocol.SECRET_PATTERN.match(token):
                raise BridgeError(f"{self.endpoint}: acquire: the server answered without a valid token")
        except BridgeError:
            self._token = None
            raise
        self._token = token
        if token == had and from_file:
            log.info("%s: took back the motion lease of an earlier run (token in %s)", self.endpoint, self.lease_file)
            self.take_back_lease()
        elif token != had and self.lease_file:
            self._write_lease_file(token)

    def take_back_lease(self) -> None:
        """The lease of an earlier process of this run, taken back (a resume): the stops the server made or passed on
        while that process was gone (another client's `stop`; a Duckiebot's watchdog, its lease lapsing) are told to
        the next motion requests, once each (RobotFault). They were about that process's plans; the resumed run
        starts again from its own records. So they are heard here, with zero-length sleeps that move nothing, and
        logged; a refusal that persists (a fault of the robot now) is a BridgeError, nothing moved."""
        refused = None
        for _ in range(MAX_MISSED_STOPS):
            try:
                self._call("sleep", {"duration_s": 0.0})
                return
            except RobotFault as err:
                refused = str(err)
                log.warning("%s: while the run being resumed was away: %s", self.endpoint, refused)
        raise BridgeError(f"{self.endpoint}: the server still refuses motion after telling the run being resumed "
                          f"{MAX_MISSED_STOPS - 1} stops it missed: {refused}")

    def _read_lease_file(self) -> str | None:
        if not self.lease_file:
            return None
        try:
            if not stat.S_ISREG(os.stat(self.lease_file).st_mode):
                raise OSError("not a regular file")
            with open(self.lease_file, encoding="ascii") as file:
                text = file.read(256).strip()
        except FileNotFoundError:
            return None
        except (OSError, UnicodeError) as err:
            log.warning("%s: cannot read the lease token (%s); asking for a new lease", self.lease_file, err)
            return None
        if not protocol.SECRET_PATTERN.match(text):
            log.warning("%s: not a lease token; asking for a new lease", self.lease_file)
            return None
        return text

    def _write_lease_file(self, token: str) -> None:
        from naocal.solver.fileio import atomic_write_bytes

        try:
            atomic_write_bytes(self.lease_file, f"{token}\n".encode("ascii"), mode=0o600)  # a secret
        except (OSError, NaocalError) as err:  # the run goes on; only a resume after a crash would wait
            log.warning("%s: cannot keep the lease token (%s): a resumed run would wait for the lease to time out",
                        self.lease_file, err)

    def _forget_lease_file(self) -> None:
        if self.lease_file:
            try:
                os.unlink(self.lease_file)
            except OSError:
                pass

    def _static_call(self, cmd: str):
        if cmd not in self._static:
            self._static[cmd] = self._call(cmd)
        return self._static[cmd]

    # ------------------------------------------------------------------------------------------ clock
    def now(self) -> float:
        return float(self._call("now"))

    def _sleep_robot(self, duration_s: float) -> None:
        """Let `duration_s` of robot time pass on the server's clock (simulated: the mock steps; wall: it waits)."""
        duration_s = float(duration_s)
        if not (math.isfinite(duration_s) and duration_s >= 0):
            raise ValueError(f"sleep: duration_s must be finite and >= 0, got {duration_s}")
        info = self._server_info()
        simulated = info.get("clock") == "simulated"
        # One call for a simulated clock, so a run over the bridge steps the mock exactly as a direct run does.
        chunk_s = float(info.get("max_sleep_s", protocol.MAX_SLEEP_S)) if simulated else WALL_CLOCK_SLEEP_CHUNK_S
        wall_per_robot_s = self.sim_slowdown if simulated else 1.0
        remaining_s = duration_s
        while remaining_s > 0:
            step_s = min(remaining_s, chunk_s)
            self._motion_call("sleep", {"duration_s": step_s}, timeout_s=self.timeout_s + wall_per_robot_s * step_s)
            remaining_s -= step_s
            if remaining_s < 1e-9:
                break

    def stop(self):
        """Stop the robot: its kind's safe state (a Duckiebot's wheels at 0, a NAO driver's release_control), moving
        nothing. Needs no lease: any client may (the controller is told at its next motion request)."""
        return self._call("stop")

    def release(self) -> None:
        """Give up control of motion so another client may command."""
        if self._token is not None:
            self._call("release")
            self._token = None
            self._forget_lease_file()

    def close(self) -> None:
        if self._closed:
            return
        try:
            if self._socket is not None and self._token is not None:
                self._call("release", timeout_s=min(self.timeout_s, 0.5), retries=0)
                self._forget_lease_file()
        except BridgeError:
            pass  # best effort: the lease also times out on the server (and the token file lets a resume reclaim it)
        finally:
            self._closed = True
            self._token = None
            self._drop_socket()


class BridgeBackend(BridgeClient, Backend):
    """A NAO behind a naocal bridge server: the Backend interface (backends/base.py) over the network. Parameters:
    BridgeClient's."""

    kind = "nao"

    def robot_identity(self) -> dict:
        return dict(self._static_call("robot_identity"))

    def joint_names(self) -> tuple[str, ...]:
        return tuple(self._static_call("joint_names"))

    def joint_limits(self) -> dict[str, tuple[float, float]]:
        return {name: (float(lo), float(hi)) for name, (lo, hi) in self._static_call("joint_limits").items()}

    def max_speeds(self) -> dict[str, float]:
        return {name: float(v) for name, v in self._static_call("max_speeds").items()}

    def intrinsics(self) -> CameraIntrinsics:
        return protocol.intrinsics_from_wire(self._static_call("intrinsics"))

    def gravity_torso_mps2(self) -> np.ndarray:
        return np.array(self._static_call("gravity_torso"), dtype=float)

    def command(self, targets_rad: dict[str, float], speed_fraction: float) -> None:
        targets = {str(name): float(angle) for name, angle in targets_rad.items()}
        self._motion_call("command", {"targets_rad": targets, "speed_fraction": float(speed_fraction)})

    def read_joints(self) -> JointReading:
        return protocol.joint_reading_from_wire(self._call("read_joints"), self.joint_limits())

    def set_stiffness(self, names, stiffness: float) -> None:
        names = [names] if isinstance(names, str) else [str(name) for name in names]
        self._motion_call("set_stiffness", {"names": names, "stiffness": float(stiffness)})

    @property
    def cameras(self) -> tuple:
        """The cameras the server's driver offers (a server from before the top camera: the bottom one)."""
        return tuple(str(c) for c in self._server_info().get("cameras", ("bottom",)))

    def capture(self, camera: str = "bottom") -> CameraImage | None:
        return protocol.image_from_wire(self._call("capture", {"camera": camera}))

    def sleep(self, duration_s: float) -> None:
        self._sleep_robot(duration_s)

    def status(self) -> dict:
        """Everything the robot reports (Backend.status): {"robot": {...}, "joints": {name: {...}}, "t_s"}."""
        return self._call("status")


def _load_client_curve(server_key_file, client_key_file):
    """(server public, client public, client secret) from key files written by `naocal bridge keygen`."""
    from naocal.backends.bridge_keys import load_key_file, warn_if_others_can_read

    try:
        server_public, _ = load_key_file(server_key_file, "the server's CURVE public key")
        if client_key_file is None:
            client_public, client_secret = zmq.curve_keypair()
            return server_public, client_public, client_secret
        client_public, client_secret = load_key_file(client_key_file, "the client's CURVE key")
    except NaocalError as err:
        raise BridgeError(str(err)) from None
    if client_secret is None:
        raise BridgeError(f"{client_key_file}: holds no secret key (give the *.key_secret file)")
    warn_if_others_can_read(client_key_file)
    return server_public, client_public, client_secret


def check_server_answers(endpoint: str, timeout_s: float = FIRST_CONTACT_TIMEOUT_S) -> dict:
    """The server's hello, asked once with one deadline: BridgeError at once if no naocal bridge answers at
    `endpoint` within `timeout_s`. For a command that should not start (nor make a run directory) without a robot;
    a BridgeBackend's own calls retry, which against a dead endpoint takes (1 + retries) x timeout_s per call."""
    bridge = BridgeClient(endpoint, timeout_s=timeout_s, retries=0)
    try:
        return bridge.server_info()
    finally:
        bridge.close()
