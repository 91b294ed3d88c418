"""`BridgeBackend`: the Backend interface over the network, as a client of `naocal bridge serve`.

Lazy Pirate (ZeroMQ guide, ch. 4): one request at a time on a DEALER socket; wait for the reply with a deadline;
on timeout close the socket, open a fresh one and resend the SAME request (same id), at most `retries` times,
then raise BridgeError naming the endpoint and the command. The server deduplicates request ids, so a command
whose reply was lost is answered from its reply cache and never executed twice.

A retry that succeeds may have reached a restarted server. The client then asks the server who it is: if the
robot behind it keeps its state across restarts (a NAO) it carries on; if not (a mock the server created), the
robot's state and clock are gone, and it raises BridgeError rather than go on with a different robot.

Not thread-safe: one BridgeBackend per thread.
"""

from __future__ import annotations

import logging
import math
import os
import secrets
import time

import numpy as np
import zmq

from backends import protocol
from backends.base import Backend, CameraImage, CameraIntrinsics, JointReading
from backends.protocol import ControlError, ProtocolError
from solver.errors import BridgeError, RobotTimeout, SafetyError

log = logging.getLogger("naocal.bridge.client")

WALL_CLOCK_SLEEP_CHUNK_S = 1.0  # a wall-clock server blocks while it sleeps: keep each sleep short


class BridgeBackend(Backend):
    """A robot behind a naocal bridge server.

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
    """

    name = "bridge"

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
        context: zmq.Context | None = None,
    ):
        if not isinstance(endpoint, str) or "://" not in endpoint:
            raise BridgeError(f"bridge endpoint {endpoint!r}: expected a ZeroMQ address such as tcp://nao.local:7790")
        if not (timeout_s > 0 and retries >= 0):
            raise ValueError("timeout_s must be > 0 and retries >= 0")
        self.endpoint = endpoint
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.sim_slowdown = float(sim_slowdown)
        self.client_id = client_id or secrets.token_hex(8)
        protocol.parse_request_id(f"{self.client_id}:0")  # a client id the server accepts
        self._context = context or zmq.Context.instance()
        # The agent's command line need not know about CURVE: the key files may come from the environment.
        curve_server_key = curve_server_key or os.environ.get("NAOCAL_CURVE_SERVER_KEY") or None
        curve_client_key = curve_client_key or os.environ.get("NAOCAL_CURVE_CLIENT_KEY") or None
        self._curve = _load_client_curve(curve_server_key, curve_client_key) if curve_server_key else None
        self._socket = None
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
        socket.connect(self.endpoint)
        return socket

    def _drop_socket(self) -> None:
        if self._socket is not None:
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
        payload = protocol.pack(protocol.make_request(request_id, cmd, args))
        if len(payload) > protocol.MAX_REQUEST_BYTES:
            raise BridgeError(f"{self.endpoint}: {cmd}: request of {len(payload)} bytes is too large")
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        attempts = 1 + (self.retries if retries is None else retries)
        reconnected = False
        for attempt in range(attempts):
            if self._socket is None:
                self._socket = self._connect()
                reconnected = True
            reply = self._attempt(payload, request_id, cmd, timeout_s)
            if reply is not None:
                if reconnected and cmd != "hello":
                    self._check_same_server(cmd)
                return self._result(reply, cmd)
            self._drop_socket()  # the Lazy Pirate reset: a fresh connection for the retry
            if attempt + 1 < attempts:
                log.warning("no reply from %s to %s (%s) within %.2f s; retrying (%d of %d)",
                            self.endpoint, cmd, request_id, timeout_s, attempt + 1, attempts - 1)
        raise BridgeError(
            f"no reply from {self.endpoint} to '{cmd}' (request {request_id}) after {attempts} attempt(s) "
            f"of {timeout_s:.2f} s; is `naocal bridge serve` running there?"
        )

    def _attempt(self, payload: bytes, request_id: str, cmd: str, timeout_s: float):
        """Send once and wait until the deadline for the matching reply; None on timeout."""
        deadline = time.monotonic() + timeout_s
        try:
            self._socket.send_multipart([b"", payload], zmq.NOBLOCK)
        except zmq.Again:
            time.sleep(max(0.0, min(timeout_s, deadline - time.monotonic())))
            return None
        while True:
            remaining_s = deadline - time.monotonic()
            if remaining_s <= 0 or not self._socket.poll(remaining_s * 1000, zmq.POLLIN):
                return None
            frames = self._socket.recv_multipart(zmq.NOBLOCK)
            try:
                message = protocol.unpack(frames[-1], max_bytes=protocol.MAX_REPLY_BYTES)
            except ProtocolError as err:
                raise BridgeError(f"{self.endpoint}: {cmd}: unreadable reply: {err}") from None
            if isinstance(message, dict) and message.get("id") is None and message.get("ok") is False:
                error = message.get("error") or {}
                raise BridgeError(f"{self.endpoint}: {cmd}: server refused the request: "
                                  f"{error.get('type')}: {error.get('message')}")
            if isinstance(message, dict) and message.get("id") != request_id:
                log.debug("discarding a reply to %r while waiting for %s", message.get("id"), request_id)
                continue
            try:
                return protocol.validate_reply(message, request_id)
            except ProtocolError as err:
                raise BridgeError(f"{self.endpoint}: {cmd}: malformed reply: {err}") from None

    def _result(self, reply: dict, cmd: str):
        if reply["ok"]:
            return reply["result"]
        error_type, message = reply["error"]["type"], reply["error"]["message"]
        if error_type == "SafetyError":
            raise SafetyError(message)
        if error_type == "RobotTimeout":
            raise RobotTimeout(message)
        if error_type == "ControlError":
            raise ControlError(f"{self.endpoint}: {cmd}: {message}")
        raise BridgeError(f"{self.endpoint}: {cmd}: {error_type}: {message}")

    def _server_info(self) -> dict:
        if self._server is None:
            info = self._call("hello")
            if not isinstance(info, dict) or info.get("protocol") != protocol.PROTOCOL_VERSION:
                raise BridgeError(f"{self.endpoint}: server does not speak protocol {protocol.PROTOCOL_VERSION}")
            self._server = info
        return self._server

    def _check_same_server(self, cmd: str) -> None:
        """After a reconnection: did the server restart? Fatal if the robot behind it lost its state."""
        if self._server is None:
            return
        before = self._server
        self._server = None
        after = self._server_info()
        if after.get("server_id") == before.get("server_id"):
            return
        if not after.get("state_persists", False):
            raise BridgeError(
                f"{self.endpoint}: the bridge server restarted during '{cmd}' and its {after.get('driver')} robot "
                "started afresh (state and clock lost); rerun the calibration with --resume"
            )
        log.warning("%s: bridge server restarted; the robot kept its state, carrying on", self.endpoint)

    def server_info(self) -> dict:
        """The server's hello: protocol, server_id, driver, robot_id, clock, state_persists, controller."""
        return dict(self._server_info())

    def _static_call(self, cmd: str):
        if cmd not in self._static:
            self._static[cmd] = self._call(cmd)
        return self._static[cmd]

    # ------------------------------------------------------------------------------------------ Backend
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
        self._call("command", {"targets_rad": targets, "speed_fraction": float(speed_fraction)})

    def read_joints(self) -> JointReading:
        return protocol.joint_reading_from_wire(self._call("read_joints"))

    def set_stiffness(self, names, stiffness: float) -> None:
        names = [names] if isinstance(names, str) else [str(name) for name in names]
        self._call("set_stiffness", {"names": names, "stiffness": float(stiffness)})

    def capture(self, camera: str = "bottom") -> CameraImage | None:
        return protocol.image_from_wire(self._call("capture", {"camera": camera}))

    def now(self) -> float:
        return float(self._call("now"))

    def sleep(self, duration_s: float) -> None:
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
            self._call("sleep", {"duration_s": step_s}, timeout_s=self.timeout_s + wall_per_robot_s * step_s)
            remaining_s -= step_s
            if remaining_s < 1e-9:
                break

    def release(self) -> None:
        """Give up control of motion so another client may command."""
        self._call("release")

    def close(self) -> None:
        if self._closed:
            return
        try:
            if self._socket is not None:
                self._call("release", timeout_s=min(self.timeout_s, 0.5), retries=0)
        except BridgeError:
            pass  # best effort: the lease also times out on the server
        finally:
            self._closed = True
            self._drop_socket()


def _load_client_curve(server_key_file, client_key_file):
    """(server public, client public, client secret) from key files written by `naocal bridge keygen`."""
    import zmq.auth

    try:
        server_public, _ = zmq.auth.load_certificate(os.fspath(server_key_file))
    except (OSError, ValueError) as err:
        raise BridgeError(f"{server_key_file}: cannot read the server's CURVE public key: {err}") from None
    if client_key_file is None:
        client_public, client_secret = zmq.curve_keypair()
        return server_public, client_public, client_secret
    try:
        client_public, client_secret = zmq.auth.load_certificate(os.fspath(client_key_file))
    except (OSError, ValueError) as err:
        raise BridgeError(f"{client_key_file}: cannot read the client's CURVE key: {err}") from None
    if client_secret is None:
        raise BridgeError(f"{client_key_file}: holds no secret key (give the *.key_secret file)")
    return server_public, client_public, client_secret
