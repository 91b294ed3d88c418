"""Who may move the robot (the motion lease) and the exactly-once record of its motion commands.

Control is bound to a secret, not to a name a stranger can copy: `acquire` hands the controller a token of 256
random bits (`secrets`), known only to it and the server, and every motion request must carry it (compared with
`hmac.compare_digest` on SHA-256 digests; the journal on disk holds only the digest). Request ids stay what they
were, "<client_id>:<seq>", but only name a request: knowing a client id gives nothing.

Exactly-once: the lease keeps, per client id that used its token, the highest sequence number seen and the replies
of the last `replies_kept` motion requests. A retried motion is answered from there, an older one refused
(StaleRequest), never run twice. Memory is bounded without evicting anything a stranger can push out: only a
token holder adds entries, at most MAX_CLIENTS client ids per lease (a resumed agent is a new client id with the
same token; the least recently used id goes), and a new lease replaces the old one whole.
"""

from __future__ import annotations

import collections
import errno
import hashlib
import hmac
import logging
import os
import shutil
import stat
import time

import msgpack

from naocal.solver.errors import NaocalError
from naocal.solver.fileio import atomic_write_bytes

log = logging.getLogger("naocal.bridge.server")

TOKEN_BYTES = 32  # 256 bits; secrets.token_urlsafe(32) is 43 characters


def digest(secret: str) -> bytes:
    return hashlib.sha256(secret.encode("utf-8")).digest()


class MotionLease:
    """The current controller: its token's digest, when it was last heard of, its motion replies."""

    MAX_CLIENTS = 4

    def __init__(self, token_digest: bytes, *, token: str | None = None, nonce_digest: bytes | None = None,
                 replies_kept: int = 32):
        self.token_digest = token_digest
        self.token = token  # None when restored from the journal (only the digest is on disk)
        self.nonce_digest = nonce_digest  # the acquire that created it: a retry of it gets the same token
        self.replies_kept = int(replies_kept)
        self.seen_s = time.monotonic()
        self.control_released = False  # the server told the robot its controller let go (silent past the lease)
        self._clients: collections.OrderedDict[str, tuple[int, collections.OrderedDict[int, bytes]]] = (
            collections.OrderedDict())

    def held_by(self, token: str | None) -> bool:
        return token is not None and hmac.compare_digest(digest(token), self.token_digest)

    def created_by(self, nonce: str) -> bool:
        return self.nonce_digest is not None and hmac.compare_digest(digest(nonce), self.nonce_digest)

    def touch(self) -> None:
        """Its holder was heard from: the lease is alive again."""
        self.seen_s = time.monotonic()
        self.control_released = False

    def idle_s(self) -> float:
        return time.monotonic() - self.seen_s

    def lookup(self, client: str, seq: int):
        """('hit', reply) | ('new', None) | ('stale', None) for a motion request of the token holder."""
        entry = self._clients.get(client)
        if entry is None:
            return "new", None
        high_water, replies = entry
        if seq in replies:
            return "hit", replies[seq]
        return ("new", None) if seq > high_water else ("stale", None)

    def store(self, client: str, seq: int, reply: bytes) -> None:
        high_water, replies = self._clients.pop(client, (-1, collections.OrderedDict()))
        replies[seq] = reply
        while len(replies) > self.replies_kept:
            replies.popitem(last=False)
        self._clients[client] = (max(high_water, seq), replies)
        while len(self._clients) > self.MAX_CLIENTS:
            self._clients.popitem(last=False)

    def entries(self) -> int:
        """How many replies it keeps (for tests and the docs' memory bound)."""
        return sum(len(replies) for _, replies in self._clients.values())

    def records(self):
        for client, (_, replies) in self._clients.items():
            for seq, reply in replies.items():
                yield client, seq, reply


class LeaseJournal:
    """Append-only file of lease events, fsynced before the reply goes out, so a restarted server neither
    repeats a motion whose reply was lost nor forgets who controls the robot.

    Records (msgpack maps): {"lease": digest} when a lease is granted, {"lease", "client", "seq", "reply"} for a
    motion reply, {"lease", "released": true}. On start the last lease is restored (its controller keeps it for
    the lease timeout from then) with its replies, and the file is rewritten compacted to that. A torn last record
    (power lost while writing) is ignored; records of the format before the lease (3-element arrays) too.
    A file that is not a journal (it starts with neither record) is refused, never compacted to nothing.
    """

    MIN_FREE_BYTES = 1 << 20  # below this, motion commands are refused rather than run without a record

    def __init__(self, path):
        self.path = os.fspath(path)
        self._fd = None

    def load(self, replies_kept: int) -> MotionLease | None:
        lease = self._read(replies_kept)
        compacted = b""
        if lease is not None:
            compacted = msgpack.packb({"lease": lease.token_digest}, use_bin_type=True) + b"".join(
                _pack_reply(lease.token_digest, c, s, r) for c, s, r in lease.records())
        try:
            atomic_write_bytes(self.path, compacted, mode=0o600)  # clients' ids: like the journal it replaces
            self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
        except (OSError, NaocalError) as err:
            raise NaocalError(f"journal {self.path}: cannot write it: {_reason(err)} ({free_space(self.path)})") \
                from None
        return lease

    def _read(self, replies_kept: int) -> MotionLease | None:
        try:
            info = os.stat(self.path)
        except FileNotFoundError:
            return None
        except OSError as err:
            raise NaocalError(f"journal {self.path}: {err.strerror}") from None
        if not stat.S_ISREG(info.st_mode):  # a FIFO would hang the reader, a device never end
            raise NaocalError(f"journal {self.path}: not a regular file")
        lease, skipped = None, 0
        with open(self.path, "rb") as file:
            _check_is_journal(self.path, file.read(len(FIRST_RECORD_START)), info.st_size)
            file.seek(0)
            unpacker = msgpack.Unpacker(file, raw=False, strict_map_key=True, max_buffer_size=64 << 20)
            try:
                for record in unpacker:
                    if not (isinstance(record, dict) and isinstance(record.get("lease"), bytes)):
                        skipped += 1
                        continue
                    token_digest = record["lease"]
                    if record.get("released"):
                        lease = None
                    elif lease is None or lease.token_digest != token_digest:
                        lease = MotionLease(token_digest, replies_kept=replies_kept)
                    if lease is not None and _reply_record(record):
                        lease.store(record["client"], record["seq"], record["reply"])
            except Exception:  # torn or corrupt tail: keep what was read
                log.warning("journal %s: ignoring a damaged tail", self.path)
        if skipped:
            log.warning("journal %s: ignored %d record(s) of an older format", self.path, skipped)
        if lease is not None:
            log.info("journal %s: the motion lease of the last controller is kept for it (%d replies)", self.path,
                     lease.entries())
        return lease

    def ensure_room(self) -> None:
        """Refuse (NaocalError) before a motion runs if its reply might not fit on disk."""
        free = shutil.disk_usage(os.path.dirname(os.path.abspath(self.path))).free
        if free < self.MIN_FREE_BYTES:
            raise NaocalError(f"journal {self.path}: only {_size(free)} free on its file system; motion refused, not "
                              "executed (free some space)")

    def granted(self, lease: MotionLease) -> None:
        self._append(msgpack.packb({"lease": lease.token_digest}, use_bin_type=True))

    def reply(self, lease: MotionLease, client: str, seq: int, reply: bytes) -> None:
        self._append(_pack_reply(lease.token_digest, client, seq, reply))

    def released(self, lease: MotionLease) -> None:
        self._append(msgpack.packb({"lease": lease.token_digest, "released": True}, use_bin_type=True))

    def _append(self, data: bytes) -> None:
        """Write and fsync one record; on failure cut the file back to where it was (no torn record stays) and
        raise NaocalError naming the file and the free space."""
        offset = os.lseek(self._fd, 0, os.SEEK_END)
        try:
            write_all(self._fd, data)
            os.fsync(self._fd)
        except OSError as err:
            try:
                os.ftruncate(self._fd, offset)
            except OSError:
                pass
            raise NaocalError(f"journal {self.path}: cannot record it: {_reason(err)} ({free_space(self.path)})") \
                from None

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


# Every journal starts with a lease record ({"lease": digest}: the first event of a lease, and what compaction
# writes first), msgpack-packed as a map of one key "lease"; a journal of the format before the lease with a
# [client, seq, reply] array; an empty journal is empty. Anything else is someone else's file.
FIRST_RECORD_START = msgpack.packb({"lease": b""}, use_bin_type=True)[:7]  # fixmap(1), "lease"
OLD_FORMAT_START = msgpack.packb(["", 0, b""], use_bin_type=True)[:1]  # fixarray(3)


def _check_is_journal(path: str, head: bytes, size: int) -> None:
    """Refuse (NaocalError) a file that does not start as a journal: load() would compact it to nothing."""
    if size == 0 or head.startswith(OLD_FORMAT_START):
        return
    if head == FIRST_RECORD_START[:len(head)]:  # a whole first record, or one torn as power was lost
        return
    raise NaocalError(f"journal {path}: not a naocal bridge journal (it does not start with a lease record); "
                      "refusing to overwrite it: give a new file name or an existing journal (nothing was changed)")


def _reply_record(record: dict) -> bool:
    return (isinstance(record.get("client"), str) and type(record.get("seq")) is int
            and isinstance(record.get("reply"), bytes))


def write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _pack_reply(token_digest: bytes, client: str, seq: int, reply: bytes) -> bytes:
    return msgpack.packb({"lease": token_digest, "client": client, "seq": seq, "reply": reply}, use_bin_type=True)


def _reason(err) -> str:
    if isinstance(err, OSError) and err.errno is not None:
        return os.strerror(err.errno) if err.errno != errno.ENOSPC else "disk full"
    return str(err)


def free_space(path) -> str:
    try:
        return f"{_size(shutil.disk_usage(os.path.dirname(os.path.abspath(path))).free)} free on its file system"
    except OSError:
        return "free space unknown"


def _size(n_bytes: int) -> str:
    if n_bytes < 1024:
        return f"{n_bytes} B"
    value = float(n_bytes)
    for unit in ("KiB", "MiB", "GiB", "TiB"):
        value /= 1024
        if value < 1024 or unit == "TiB":
            return f"{value:.1f} {unit}"
