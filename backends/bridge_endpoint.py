"""ZeroMQ addresses as libzmq reads them: the server's loopback check and the client's address check.

A bind address is checked the way libzmq itself resolves it (libzmq src/tcp_address.cpp and src/ip_resolver.cpp,
read for this; zmq_tcp(7)), not as a URL: `tcp://0.0.0.0:7790@127.0.0.1` is not "user 0.0.0.0:7790 at host
127.0.0.1" but host 0.0.0.0, port atoi("7790@127.0.0.1") = 7790, i.e. every interface. libzmq
- takes everything after the LAST ';' as the address to listen on (the part before is a source address);
- splits host and port at the LAST ':' and reads the port with atoi (trailing junk ignored; '*' and '0' = any);
- removes [brackets] and a %zone from the host;
- resolves the host as '*' (every interface), then as a network interface name ('eth0', 'lo'), then as a numeric
  address through getaddrinfo(AI_NUMERICHOST), which also takes '127.1', '0x7f.1' and '2130706433'.
Only an address that is provably loopback passes without --allow-remote; anything else counts as remote.
"""

from __future__ import annotations

import ipaddress
import re
import socket

from naocal.backends.errors import BridgeError
from naocal.solver.errors import NaocalError

LOCAL_TRANSPORTS = ("ipc", "inproc")  # never reachable from another machine
CLIENT_EXAMPLE = "tcp://HOST:PORT (e.g. tcp://nao.local:7790) or ipc://PATH"
_HOSTNAME = re.compile(r"^[A-Za-z0-9]([A-Za-z0-9.-]{0,251}[A-Za-z0-9])?$")


def split_endpoint(endpoint: str) -> tuple[str, str]:
    """'tcp://a:1' -> ('tcp', 'a:1'); libzmq splits at the first '://'."""
    scheme, separator, address = endpoint.partition("://")
    if not separator:
        return "", endpoint
    return scheme, address


def tcp_listen_hosts(address: str) -> list[str]:
    """The hosts of a tcp bind address (the part after 'tcp://'), as libzmq parses them: [source host, host] or
    [host], without brackets and %zone. Raises NaocalError if a part has no ':PORT'."""
    parts = address.rsplit(";", 1)
    hosts = []
    for part in parts:
        host, separator, _port = part.rpartition(":")
        if not separator:
            raise NaocalError(f"bind address 'tcp://{address}': expected tcp://HOST:PORT")
        if len(host) >= 2 and host[0] == "[" and host[-1] == "]":
            host = host[1:-1]
        hosts.append(host.rsplit("%", 1)[0] if "%" in host else host)
    return hosts


def is_loopback_host(host: str) -> bool:
    """True only if libzmq would resolve `host` to a loopback address and nothing else."""
    if host in ("", "*"):
        return False
    try:
        if host in {name for _, name in socket.if_nameindex()}:
            return False  # libzmq tries interface names first; an interface's address is not ours to judge here
    except OSError:
        pass
    addresses = []
    for family in (socket.AF_INET, socket.AF_INET6):
        try:
            infos = socket.getaddrinfo(host, None, family, socket.SOCK_STREAM, 0,
                                       socket.AI_NUMERICHOST | socket.AI_PASSIVE)
        except (socket.gaierror, UnicodeError, ValueError):
            continue
        addresses += [info[4][0].split("%", 1)[0] for info in infos]
    if not addresses and host == "localhost":
        try:
            addresses = [info[4][0] for info in socket.getaddrinfo(host, None, socket.AF_INET, socket.SOCK_STREAM)]
        except (socket.gaierror, UnicodeError):
            return False
    return bool(addresses) and all(_loopback_ip(a) for a in addresses)


def _loopback_ip(text: str) -> bool:
    try:
        address = ipaddress.ip_address(text)
    except ValueError:
        return False
    mapped = getattr(address, "ipv4_mapped", None)
    return (mapped or address).is_loopback


def check_bind_address(bind: str, allow_remote: bool) -> None:
    """Refuse a bind address other machines could reach unless `allow_remote`. Raises NaocalError naming it."""
    if not isinstance(bind, str) or not bind:
        raise NaocalError(f"bind address {bind!r}: expected tcp://HOST:PORT (or ipc://PATH)")
    scheme, address = split_endpoint(bind)
    if scheme in LOCAL_TRANSPORTS and address:
        return
    if scheme != "tcp" or not address:
        raise NaocalError(f"bind address {bind!r}: expected tcp://HOST:PORT (or ipc://PATH)")
    hosts = tcp_listen_hosts(address)
    remote = [host for host in hosts if not is_loopback_host(host)]
    if remote and not allow_remote:
        raise NaocalError(
            f"bind address {bind!r} listens on {remote[-1] or '?'!r} (libzmq's reading), which other machines may "
            "reach; bind tcp://127.0.0.1:PORT, or pass --allow-remote (and use CURVE keys)"
        )
    port = address.rsplit(";", 1)[-1].rpartition(":")[2]
    if not (port == "*" or (port.isdigit() and port.isascii() and int(port) <= 65535)):
        raise NaocalError(f"bind address {bind!r}: port {port!r} is not a number in 0..65535 (libzmq would read "
                          f"it as {_atoi(port)})")


def is_local_endpoint(endpoint: str) -> bool:
    """True if a bound address (ZMQ_LAST_ENDPOINT) is reachable from this machine only."""
    scheme, address = split_endpoint(endpoint)
    if scheme in LOCAL_TRANSPORTS:
        return True
    return scheme == "tcp" and bool(address) and all(is_loopback_host(host) for host in tcp_listen_hosts(address))


def check_bound_endpoint(last_endpoint: str, allow_remote: bool) -> None:
    """Second line of defence, on the address the socket really listens on (ZMQ_LAST_ENDPOINT)."""
    if not allow_remote and not is_local_endpoint(last_endpoint):
        raise NaocalError(f"the server ended up listening on {last_endpoint}, which other machines may reach; "
                          "refused (pass --allow-remote if that is what you want)")


def _atoi(text: str) -> int:
    digits = re.match(r"\s*[+-]?\d*", text).group(0).strip()
    return int(digits) % 65536 if digits not in ("", "+", "-") else 0


def check_client_endpoint(endpoint) -> str:
    """A server address a client may connect to: tcp://HOST:PORT with PORT in 1..65535, ipc://PATH or
    inproc://NAME. Returns it; raises BridgeError (exit 2) with one line naming it otherwise."""
    if not isinstance(endpoint, str):
        raise BridgeError(f"bridge endpoint {endpoint!r}: expected {CLIENT_EXAMPLE}")
    scheme, address = split_endpoint(endpoint)
    if scheme in LOCAL_TRANSPORTS and address:
        return endpoint
    if scheme != "tcp":
        shown = f"'{scheme}://'" if scheme else "no scheme"
        raise BridgeError(f"bridge endpoint {endpoint!r}: {shown} is not a ZeroMQ transport naocal uses; "
                          f"expected {CLIENT_EXAMPLE}")
    host, separator, port = address.rpartition(":")
    if not separator or not host or (host.startswith("[") != host.endswith("]")):
        raise BridgeError(f"bridge endpoint {endpoint!r}: no port; expected {CLIENT_EXAMPLE}")
    if not (port.isascii() and port.isdigit() and 1 <= int(port) <= 65535):
        raise BridgeError(f"bridge endpoint {endpoint!r}: port {port!r} is not a number in 1..65535; "
                          f"expected {CLIENT_EXAMPLE}")
    if host.startswith("["):
        try:
            ipaddress.IPv6Address(host[1:-1].split("%", 1)[0])
        except ValueError:
            raise BridgeError(f"bridge endpoint {endpoint!r}: {host} is not an IPv6 address") from None
    elif not _HOSTNAME.match(host):
        raise BridgeError(f"bridge endpoint {endpoint!r}: {host!r} is not a host name or IP address "
                          f"(IPv6 goes in brackets); expected {CLIENT_EXAMPLE}")
    return endpoint
