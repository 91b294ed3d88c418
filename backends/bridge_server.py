"""Robot-side bridge server: serves one `Backend` (the PyBullet mock or the NAOqi driver) over ZeroMQ.

Socket: ROUTER, not REP. A REP socket must answer every request before it may receive the next one, so it cannot
drop or delay a reply (the fault injector does both), and a client that vanishes mid-request leaves it in a state
that needs care. ROUTER hands us each peer's routing id with the message: we answer whom we like, when we like,
malformed multipart messages included, and replies to peers that have gone away are discarded by libzmq.
Both REQ clients (with their empty delimiter frame) and DEALER clients (the naocal client) are served.

Guarantees (docs/PROTOCOL.md):
- every request gets a reply: a bad one an error reply, never a crash (up to ZMQ_MAX_INBOUND_BYTES; beyond it
  libzmq drops the connection before we see the message);
- request ids are deduplicated: the replies of the last `replies_kept_per_client` requests of each client are
  kept, a retried request is answered from them and NOT executed again; with `journal_path` the replies of
  motion commands also survive a restart of the server;
- one client at a time controls motion (`command`, `set_stiffness`, `sleep`): the first one to command holds
  the lease until it sends `release` or stays silent for `lease_timeout_s`; the others may still read.
"""

from __future__ import annotations

import collections
import ctypes
import ipaddress
import logging
import os
import secrets
import threading
import time
import urllib.parse

import msgpack
import numpy as np
import zmq

from backends import protocol
from backends.base import Backend
from backends.protocol import MOTION_COMMANDS, ControlError, ProtocolError
from solver.errors import BridgeError, NaocalError, RobotTimeout, SafetyError
from solver.fileio import atomic_write_bytes

log = logging.getLogger("naocal.bridge.server")

DEFAULT_BIND = "tcp://127.0.0.1:7790"
POLL_INTERVAL_S = 0.1  # how often the loop looks at its stop flag


def check_bind_address(bind: str, allow_remote: bool) -> None:
    """Refuse a non-loopback bind unless `allow_remote`. Raises NaocalError naming the address."""
    scheme, _, rest = bind.partition("://")
    if scheme in ("ipc", "inproc"):
        return
    if scheme != "tcp" or not rest:
        raise NaocalError(f"bind address {bind!r}: expected tcp://HOST:PORT (or ipc://PATH)")
    host = urllib.parse.urlsplit(f"//{rest}").hostname or ""
    try:
        loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False  # '*', interface names, host names: may be reachable from outside
    if not loopback and not allow_remote:
        raise NaocalError(
            f"bind address {bind!r} is reachable from other machines; pass --allow-remote to serve on it "
            "(and consider --curve-secret-key)"
        )


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


class ReplyCache:
    """The last replies per client, keyed by request sequence number.

    A value of None marks a read-only request whose reply was too big to keep: a retry may run it again.
    """

    KEEP_BYTES = 64 << 10  # replies larger than this (images) are not kept; only reads produce them
    MAX_CLIENTS = 256

    def __init__(self, per_client: int):
        self.per_client = int(per_client)
        self._clients: collections.OrderedDict[str, collections.OrderedDict[int, bytes | None]] = (
            collections.OrderedDict()
        )
        self._max_seq: dict[str, int] = {}

    def lookup(self, client: str, seq: int):
        """('hit', reply) | ('rerun', None) | ('new', None) | ('stale', None)."""
        entries = self._clients.get(client)
        if entries is not None and seq in entries:
            reply = entries[seq]
            return ("rerun", None) if reply is None else ("hit", reply)
        if seq > self._max_seq.get(client, -1):
            return "new", None
        return "stale", None

    def store(self, client: str, seq: int, reply: bytes, *, side_effects: bool) -> None:
        entries = self._clients.setdefault(client, collections.OrderedDict())
        self._clients.move_to_end(client)
        keep = side_effects or len(reply) <= self.KEEP_BYTES
        entries[seq] = reply if keep else None
        self._max_seq[client] = max(seq, self._max_seq.get(client, -1))
        while len(entries) > self.per_client:
            entries.popitem(last=False)
        while len(self._clients) > self.MAX_CLIENTS:
            dropped, _ = self._clients.popitem(last=False)
            self._max_seq.pop(dropped, None)


class ReplyJournal:
    """Append-only file of motion replies [client, seq, reply], fsynced before the reply is sent.

    A restarted server loads it, so a retried motion command whose reply was lost in the restart is answered,
    not executed again. A torn last record (power loss while writing) is ignored.
    """

    def __init__(self, path, cache: ReplyCache):
        self.path = os.fspath(path)
        records = []
        if os.path.exists(self.path):
            with open(self.path, "rb") as file:
                unpacker = msgpack.Unpacker(file, raw=False, strict_map_key=True, max_buffer_size=64 << 20)
                try:
                    for record in unpacker:
                        if isinstance(record, list) and len(record) == 3:
                            records.append(record)
                except Exception:  # torn or corrupt tail: keep what was read
                    log.warning("journal %s: ignoring a damaged tail after %d records", self.path, len(records))
        for client, seq, reply in records:
            cache.store(client, seq, reply, side_effects=True)
        # Rewrite it compacted to what the cache keeps, then append.
        kept = [[c, s, r] for c, entries in cache._clients.items() for s, r in entries.items() if r is not None]
        atomic_write_bytes(self.path, b"".join(msgpack.packb(rec, use_bin_type=True) for rec in kept))
        self._file = open(self.path, "ab")

    def append(self, client: str, seq: int, reply: bytes) -> None:
        self._file.write(msgpack.packb([client, seq, reply], use_bin_type=True))
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        self._file.close()


class BridgeServer:
    """Serve `backend` on `bind`. Use `start()` then `serve_forever()`, or `start_thread()` / `stop()`.

    Parameters
    ----------
    driver : name reported to clients ('mock', 'naoqi', ...).
    clock : 'simulated' (the backend's clock only moves on `sleep`) or 'wall'.
    state_persists : True if the robot keeps its state when this server restarts (a real NAO), False for a mock
        created by this server (clients then treat a restart as fatal).
    """

    def __init__(
        self,
        backend: Backend,
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
        self.bind = bind
        self.driver = driver
        self.clock = clock
        self.state_persists = bool(state_persists)
        self.lease_timeout_s = float(lease_timeout_s)
        self.faults = faults
        self.server_id = secrets.token_hex(8)
        self.endpoint = None  # the bound address, with the real port, after start()
        self._curve_secret_key_file = curve_secret_key_file
        self._curve_clients_dir = curve_clients_dir
        self._context = context or zmq.Context.instance()
        self._cache = ReplyCache(replies_kept_per_client)
        self._journal = ReplyJournal(journal_path, self._cache) if journal_path else None
        self._controller: str | None = None
        self._controller_seen_s = 0.0
        self._socket = None
        self._authenticator = None
        self._stop = threading.Event()
        self._thread = None
        self._robot_id = None
        self.requests_served = 0

    # ------------------------------------------------------------------------------------------ lifecycle
    def start(self) -> "BridgeServer":
        """Bind the socket (errors such as 'address in use' are raised here)."""
        self._robot_id = str(self.backend.robot_identity().get("id", "unknown"))
        socket = self._context.socket(zmq.ROUTER)
        socket.setsockopt(zmq.LINGER, 0)
        socket.setsockopt(zmq.MAXMSGSIZE, protocol.ZMQ_MAX_INBOUND_BYTES)
        try:
            if self._curve_secret_key_file:
                self._configure_curve(socket)
            socket.bind(self.bind)
        except zmq.ZMQError as err:
            self._stop_authenticator()
            socket.close(linger=0)
            raise NaocalError(f"cannot bind {self.bind}: {err}") from None
        except BaseException:
            self._stop_authenticator()
            socket.close(linger=0)
            raise
        self._socket = socket
        self.endpoint = socket.getsockopt_string(zmq.LAST_ENDPOINT)
        log.info("serving %s (%s, robot %s) on %s", self.driver, self.clock, self._robot_id, self.endpoint)
        return self

    def _configure_curve(self, socket) -> None:
        import zmq.auth

        try:
            public, secret = zmq.auth.load_certificate(os.fspath(self._curve_secret_key_file))
        except (OSError, ValueError) as err:
            raise NaocalError(f"{self._curve_secret_key_file}: cannot read the CURVE key: {err}") from None
        if secret is None:
            raise NaocalError(f"{self._curve_secret_key_file}: holds no secret key (give the *.key_secret file)")
        if self._curve_clients_dir:
            from zmq.auth.thread import ThreadAuthenticator

            if not os.path.isdir(self._curve_clients_dir):
                raise NaocalError(f"{self._curve_clients_dir}: not a directory of client public keys (*.key)")

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
                if not self._socket.poll(POLL_INTERVAL_S * 1000, zmq.POLLIN):
                    continue
                frames = self._socket.recv_multipart(zmq.NOBLOCK)
                try:
                    self._handle(frames)
                except Exception:  # a bug in handling one message must not take the robot's server down
                    log.exception("could not handle a message of %d frame(s)", len(frames))
        finally:
            self._socket.close(linger=0)
            self._socket = None
            self._stop_authenticator()
            if self._journal is not None:
                self._journal.close()

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

    # ------------------------------------------------------------------------------------------ requests
    def _handle(self, frames: list[bytes]) -> None:
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
            request_id, cmd, args = protocol.validate_request(message)
        except ProtocolError as err:
            self._send(routing_id, envelope, protocol.error_reply(request_id, err.error_type, str(err)))
            return

        client, seq = protocol.parse_request_id(request_id)
        if client == self._controller:
            self._controller_seen_s = time.monotonic()
        status, cached = self._cache.lookup(client, seq)
        if status == "hit":
            log.info("request %s (%s) answered from the reply cache, not executed again", request_id, cmd)
            self._send(routing_id, envelope, cached)
            return
        if status == "stale":
            self._send(routing_id, envelope, protocol.error_reply(
                request_id, "StaleRequest", f"request {request_id} is older than the replies this server keeps; "
                                            "not executed"))
            return

        reply = self._execute(request_id, client, cmd, args)
        side_effects = cmd in MOTION_COMMANDS
        self._cache.store(client, seq, reply, side_effects=side_effects)
        if side_effects and self._journal is not None and cmd != "sleep":
            self._journal.append(client, seq, reply)
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

    def _send(self, routing_id: bytes, envelope: list[bytes], reply) -> None:
        data = reply if isinstance(reply, bytes) else protocol.pack(reply)
        try:
            self._socket.send_multipart([routing_id, *envelope, data], zmq.NOBLOCK)
        except zmq.Again:
            log.warning("reply dropped: the client's queue is full")

    def _execute(self, request_id: str, client: str, cmd: str, args: dict) -> bytes:
        """Run one validated request and encode its reply; every failure becomes an error reply."""
        try:
            if cmd in MOTION_COMMANDS:
                self._take_lease(client)
            return protocol.pack(protocol.ok_reply(request_id, self._dispatch(client, cmd, args)))
        except ProtocolError as err:
            reply = protocol.error_reply(request_id, err.error_type, str(err))
        except ControlError as err:
            reply = protocol.error_reply(request_id, "ControlError", str(err))
        except SafetyError as err:
            reply = protocol.error_reply(request_id, "SafetyError", str(err))
        except RobotTimeout as err:
            reply = protocol.error_reply(request_id, "RobotTimeout", str(err))
        except NaocalError as err:
            reply = protocol.error_reply(request_id, "NaocalError", f"{type(err).__name__}: {err}")
        except Exception as err:  # a bug or a robot failure behind the backend: report it, keep serving
            log.exception("request %s (%s) failed", request_id, cmd)
            reply = protocol.error_reply(request_id, "InternalError", f"{type(err).__name__}: {err}")
        return protocol.pack(reply)

    def _take_lease(self, client: str) -> None:
        now = time.monotonic()
        holder = self._controller
        if holder not in (None, client):
            idle_s = now - self._controller_seen_s
            if idle_s < self.lease_timeout_s:
                raise ControlError(
                    f"the robot is controlled by client {holder} (idle {idle_s:.1f} s of {self.lease_timeout_s:g} s); "
                    "reads are allowed, motion is not"
                )
            log.warning("client %s idle for %.1f s: motion lease passes to %s", holder, idle_s, client)
        if holder != client:
            log.info("client %s now controls motion", client)
        self._controller = client
        self._controller_seen_s = now

    def _dispatch(self, client: str, cmd: str, args: dict):
        backend = self.backend
        if cmd == "hello":
            return {
                "protocol": protocol.PROTOCOL_VERSION,
                "server_id": self.server_id,
                "driver": self.driver,
                "robot_id": self._robot_id,
                "clock": self.clock,
                "state_persists": self.state_persists,
                "controller": self._controller,
                "max_request_bytes": protocol.MAX_REQUEST_BYTES,
                "max_sleep_s": protocol.MAX_SLEEP_S,
            }
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
        if cmd == "command":
            backend.command(args["targets_rad"], args["speed_fraction"])
            return None
        if cmd == "set_stiffness":
            backend.set_stiffness(args["names"], args["stiffness"])
            return None
        if cmd == "sleep":
            duration_s = args["duration_s"]
            if not 0.0 <= duration_s <= protocol.MAX_SLEEP_S:  # also refuses NaN
                raise ProtocolError(f"sleep: duration_s must be in [0, {protocol.MAX_SLEEP_S:g}] s, got {duration_s}")
            backend.sleep(duration_s)
            return None
        if cmd == "release":
            if self._controller == client:
                log.info("client %s released motion", client)
                self._controller = None
            return None
        raise ProtocolError(f"unknown command {cmd!r}", "UnknownCommand")  # COMMANDS and this table disagree


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
    atomic_write_bytes(secret_path, secret_text.encode("ascii"))  # mkstemp: created with mode 0600
    atomic_write_bytes(public_path, public_text.encode("ascii"))
    os.chmod(public_path, 0o644)
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
