"""Keep serving the controller under a flood of connections.

libzmq accepts every TCP connection on its I/O thread. When accept() fails for want of file descriptors (EMFILE)
it reports the failure and returns with the listening socket still readable, so it fails again at once (libzmq
src/tcp_listener.cpp: "TODO: Handle specific errors like ENFILE/EMFILE"): a core at 100 % and no new connection,
not even the controller's reconnection, gets in. Three layers against it:

1. `raise_fd_limit()`: the soft RLIMIT_NOFILE up to the hard limit (`naocal bridge serve` calls it).
2. ZMQ_HANDSHAKE_IVL = HANDSHAKE_TIMEOUT_S on the server socket: libzmq drops a connection that has not finished
   the ZMTP handshake by then (default 30 s).
3. `ConnectionGuard`: watches the socket's monitor events (ACCEPTED and DISCONNECTED carry the connection's file
   descriptor) and learns from each request which descriptor it came from (ZMQ_SRCFD). When the connections near
   the descriptor budget (or an accept failed), it shuts connections down (shutdown(2); libzmq then closes them):
   first those that never sent a request, oldest first, then the least recently active; never the controller's.

ZMQ_MAX_SOCKETS does not help (it counts ZeroMQ sockets, not connections); ZMQ_TCP_ACCEPT_FILTER is deprecated and
cannot tell a local attacker from the agent.
"""

from __future__ import annotations

import errno
import logging
import os
import secrets
import socket as pysocket
import struct
import threading
import time

import zmq

log = logging.getLogger("naocal.bridge.server")

HANDSHAKE_TIMEOUT_S = 5.0  # a naocal client's handshake takes milliseconds, CURVE included
RESERVED_FDS = 64  # left for the robot driver, the journal, logging ...
LOW_WATER = 0.75  # shedding brings the connections down to this fraction of the budget
EVENTS_PER_ROUND = 2000  # libzmq's accept spin makes ACCEPT_FAILED events without end: act between batches


def raise_fd_limit() -> tuple[int, int]:
    """Raise the soft RLIMIT_NOFILE to the hard limit where the system allows it. Returns (soft, hard) after."""
    try:
        import resource
    except ImportError:  # not POSIX
        return -1, -1
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    target = hard if hard != resource.RLIM_INFINITY else 1 << 20
    if soft != resource.RLIM_INFINITY and soft < target:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
        except (ValueError, OSError) as err:
            log.warning("could not raise the file descriptor limit from %d to %d: %s", soft, target, err)
    return resource.getrlimit(resource.RLIMIT_NOFILE)


def connection_budget() -> int:
    """How many connections the process can hold: the soft descriptor limit less those open and a reserve."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    except ImportError:
        return 1 << 16
    if soft == resource.RLIM_INFINITY:
        return 1 << 16
    open_now = 64
    for directory in ("/proc/self/fd", "/dev/fd"):
        try:
            open_now = len(os.listdir(directory))
            break
        except OSError:
            continue
    return max(8, soft - open_now - RESERVED_FDS)


class ConnectionGuard:
    """Sheds idle connections of `socket` before they exhaust the file descriptors. See the module docstring.

    Create it in the thread that owns `socket`, before `bind`; call `listening_on()` after it, `note_request()` for
    every request and `stop()` (from the owning thread, before closing the socket) at the end.
    """

    EVENTS = zmq.EVENT_ACCEPTED | zmq.EVENT_ACCEPT_FAILED | zmq.EVENT_DISCONNECTED | zmq.EVENT_CLOSED

    def __init__(self, socket: zmq.Socket, budget: int | None = None):
        self.budget = int(budget or connection_budget())
        self.shed = 0  # connections shut down so far
        self._socket = socket
        self._lock = threading.Lock()
        self._accepted: dict[int, float] = {}  # fd -> when accepted; insertion order = accept order
        self._active: dict[int, float] = {}  # fd -> when it last carried a request
        self._protected: int | None = None  # the controller's connection
        self._local_name = None
        self._srcfd_known = True
        self._last_warning_s = -1e9
        self._stop = threading.Event()
        # libzmq sends events on the monitor socket with blocking sends, from its I/O thread: the peer must be
        # connected before the first event, never refuse one (no high-water mark: disable_monitor() holds the GIL,
        # so a full queue at stop() would deadlock with this thread) and be drained until the monitor is off.
        address = f"inproc://naocal-guard-{secrets.token_hex(8)}"
        socket.monitor(address, self.EVENTS)
        self._events = socket.context.socket(zmq.PAIR)
        self._events.setsockopt(zmq.LINGER, 0)
        self._events.setsockopt(zmq.RCVHWM, 0)
        self._events.connect(address)
        self._thread = threading.Thread(target=self._run, name="naocal-bridge-guard", daemon=True)
        self._thread.start()

    def listening_on(self, endpoint: str) -> None:
        """The bound address: only connections accepted on it are ever shut down."""
        scheme, _, address = endpoint.partition("://")
        if scheme == "tcp":
            self._local_name = int(address.rpartition(":")[2])
        elif scheme == "ipc":
            self._local_name = address

    def note_request(self, fd, *, controller: bool) -> None:
        if fd is None:
            if self._srcfd_known and self._local_name is not None:
                log.warning("libzmq does not say which connection a request came from (ZMQ_SRCFD): idle connections "
                            "are left to the handshake timeout, not shed")
            self._srcfd_known = False
            return
        with self._lock:
            self._active[fd] = time.monotonic()
            if controller:
                self._protected = fd

    def stop(self) -> None:
        try:
            self._socket.disable_monitor()  # while the thread still drains, so libzmq never blocks on it
        except zmq.ZMQError:
            pass
        self._stop.set()
        self._thread.join(5.0)

    # ------------------------------------------------------------------------------------------ the thread
    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                try:
                    self._drain_and_shed()
                except Exception:  # this thread must outlive any bug: libzmq would block on its events
                    log.exception("connection guard")
        finally:
            self._events.close(linger=0)

    def _drain_and_shed(self) -> None:
        if not self._events.poll(100):
            return
        must_shed, accept_failed = False, False
        for _ in range(EVENTS_PER_ROUND):  # what is pending first, so the picture of open connections is current
            try:
                frames = self._events.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                break
            event, value = struct.unpack("=Hi", frames[0][:6])
            if event == zmq.EVENT_ACCEPTED:
                self._accepted[value] = time.monotonic()
                must_shed |= len(self._accepted) > self.budget
            elif event in (zmq.EVENT_DISCONNECTED, zmq.EVENT_CLOSED):
                self._forget(value)
            elif event == zmq.EVENT_ACCEPT_FAILED:
                accept_failed = True
        accept_failed = accept_failed and _descriptors_exhausted()  # not an old event from before the last shed
        if must_shed or accept_failed:
            self._shed(accept_failed)

    def _forget(self, fd: int) -> None:
        self._accepted.pop(fd, None)
        with self._lock:
            self._active.pop(fd, None)
            if self._protected == fd:
                self._protected = None

    def _shed(self, accept_failed: bool) -> None:
        if not self._srcfd_known:
            return  # cannot tell the controller's connection from the flood: leave it to HANDSHAKE_IVL
        excess = len(self._accepted) - int(self.budget * LOW_WATER)
        if accept_failed:  # descriptors ran out before the budget: this process holds more than it thought
            excess = max(excess, len(self._accepted) // 4, 1)
        if excess <= 0:
            return
        with self._lock:
            active = dict(self._active)
            protected = self._protected
        silent = [fd for fd in self._accepted if fd not in active and fd != protected]
        idle = [fd for _, fd in sorted((t, fd) for fd, t in active.items() if fd != protected and fd in self._accepted)]
        shed = 0
        for fd in (silent + idle)[:excess]:
            self._forget(fd)
            shed += self._shutdown(fd)
        self.shed += shed
        now = time.monotonic()
        if now - self._last_warning_s > 10.0:
            self._last_warning_s = now
            log.warning("%s connections near the limit of %d: shut down %d idle one(s) (%d so far); the "
                        "controller's connection is kept", "out of file descriptors:" if accept_failed else "flood:",
                        self.budget, shed, self.shed)

    def _shutdown(self, fd: int) -> bool:
        """shutdown(2) the connection on `fd` if it is one accepted on our address; False otherwise."""
        try:
            sock = pysocket.socket(fileno=fd)
        except OSError:  # closed meanwhile, or no longer a socket
            return False
        try:
            name = sock.getsockname()
            port_or_path = name[1] if isinstance(name, tuple) else name
            if isinstance(port_or_path, bytes):
                port_or_path = port_or_path.decode(errors="replace")
            if self._local_name is None or port_or_path != self._local_name:
                return False
            sock.shutdown(pysocket.SHUT_RDWR)
            return True
        except OSError:
            return False
        finally:
            sock.detach()


def _descriptors_exhausted() -> bool:
    """True if this process cannot open another file descriptor right now."""
    try:
        fd = os.open(os.devnull, os.O_RDONLY)
    except OSError as err:
        return err.errno in (errno.EMFILE, errno.ENFILE)
    os.close(fd)
    return False
