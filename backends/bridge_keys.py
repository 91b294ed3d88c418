"""CURVE key files: the checks that make a key mistake loud instead of a silent lock-out."""

from __future__ import annotations

import glob
import logging
import os
import stat

from zmq.utils import z85

from naocal.solver.errors import NaocalError

log = logging.getLogger("naocal.bridge")


MAX_KEY_FILE_BYTES = 64 << 10


def load_key_file(path, what: str) -> tuple[bytes | None, bytes | None]:
    """(public, secret) from a ZeroMQ certificate file; NaocalError naming the file if it is not a regular file of
    sensible size (a FIFO would hang the reader) or holds no key."""
    import zmq.auth

    path = os.fspath(path)
    try:
        info = os.stat(path)
    except OSError as err:
        raise NaocalError(f"{path}: cannot read {what}: {err.strerror}") from None
    if not stat.S_ISREG(info.st_mode) or info.st_size > MAX_KEY_FILE_BYTES:
        raise NaocalError(f"{path}: not {what} (not a regular file of at most {MAX_KEY_FILE_BYTES >> 10} KiB)")
    try:
        return zmq.auth.load_certificate(path)
    except (OSError, ValueError, UnicodeError) as err:
        raise NaocalError(f"{path}: cannot read {what}: {err}") from None


def is_curve_key(key) -> bool:
    """A Z85-encoded 32-byte CURVE key."""
    try:
        return key is not None and len(key) == 40 and len(z85.decode(key)) == 32
    except (ValueError, TypeError, KeyError):
        return False


def warn_if_others_can_read(path) -> bool:
    """Log a warning if a secret key file is readable by its group or by others; True if it is."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        log.warning("%s: this SECRET key is readable by other users (mode %04o): run chmod 600 on it, and make a new "
                    "key pair if others may have read it", path, stat.S_IMODE(mode))
        return True
    return False


def load_client_keys(directory) -> list[bytes]:
    """The public keys of `--curve-clients DIR`: every `*.key` file must hold one, or NaocalError names it.

    libzmq's authenticator would skip or choke on a bad file and admit nobody, silently.
    """
    directory = os.fspath(directory)
    if not os.path.isdir(directory):
        raise NaocalError(f"{directory}: not a directory of client public keys (*.key)")
    keys = []
    for path in sorted(glob.glob(os.path.join(directory, "*.key"))):
        public, secret = load_key_file(path, "a CURVE public key")
        if not is_curve_key(public):
            raise NaocalError(f"{path}: not a CURVE public key (expected a NAME.key written by naocal bridge keygen)")
        if secret is not None:  # a NAME.key_secret renamed: the client's secret has left the client
            log.warning("%s: holds a SECRET key too (a *.key_secret renamed?): a client's secret key belongs on the "
                        "client only; put its public NAME.key here, delete this copy, and make the client a new key "
                        "pair if others may have read it", path)
        keys.append(public)
    if not keys:
        raise NaocalError(f"{directory}: holds no client public keys (*.key): nobody could connect")
    return keys
