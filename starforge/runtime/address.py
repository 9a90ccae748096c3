"""The dask scheduler's address: parsed and checked before anything connects, and probed for
dask's handshake with bounded waits, so that an endpoint that is not a dask scheduler (nothing
listening, an unreachable host, an HTTP server, a silent listener, another protocol) is named in
one line within seconds, before dask's client (which retries for its whole timeout) starts.
"""

from __future__ import annotations

import os
import re

from starforge.errors import StarforgeError

ENV_SCHEDULER = "STARFORGE_SCHEDULER"
#: seconds to wait for a connection to be accepted
CONNECT_S = 5.0
#: seconds a scheduler has to send dask's handshake once connected (it sends it at once)
HANDSHAKE_S = 4.0
#: dask's default scheduler port
DEFAULT_PORT = 8786
#: the address forms :func:`parse_address` accepts, for its one-line refusals
ADDRESS_FORMS = f"tcp://HOST:PORT, HOST:PORT or HOST (port {DEFAULT_PORT}); HOST a name, an IPv4 or [IPv6] address"

def scheduler_address(scheduler: str | None = None) -> str | None:
    """The scheduler to use, as ``tcp://host:port`` (:func:`parse_address`): ``scheduler`` if
    given, else ``STARFORGE_SCHEDULER``, else None."""
    if scheduler:
        return parse_address(scheduler)
    env = os.environ.get(ENV_SCHEDULER, "").strip()
    return parse_address(env, ENV_SCHEDULER) if env else None


_HOST = re.compile(r"(?=.{1,253}$)[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?(?:\.[A-Za-z0-9](?:[A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*\.?")


def parse_address(text: str, option: str = "--scheduler") -> str:
    """``text`` as ``tcp://host:port``, or StarforgeError in one line naming the accepted forms
    (:data:`ADDRESS_FORMS`).  Only dask's TCP transport is used: ``tls://`` needs certificates
    and ``ucx://`` a UCX installation, neither of which starforge's client is set up for.

    >>> parse_address("10.0.0.1")
    'tcp://10.0.0.1:8786'
    >>> parse_address("tcp://[::1]:9000")
    'tcp://[::1]:9000'
    """
    import ipaddress

    raw = str(text).strip()
    shown = raw if len(raw) <= 60 else raw[:57] + "..."

    def bad(why: str) -> StarforgeError:
        return StarforgeError(f"{option} {shown!r}: {why}; expected {ADDRESS_FORMS}")

    rest = raw
    if "://" in rest:
        scheme, _, rest = rest.partition("://")
        if scheme.lower() != "tcp":
            raise bad(f"{scheme}:// is not supported (starforge connects over plain tcp://)")
    if not rest or any(c in rest for c in "/?#@ \t"):
        raise bad("not a scheduler address")
    if rest.startswith("["):
        host, sep, tail = rest[1:].partition("]")
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            raise bad(f"[{host}] is not an IPv6 address") from None
        if tail and not tail.startswith(":"):
            raise bad("text after the ]")
        port_text = tail[1:] if tail else None
        shown_host = f"[{host}]"
    else:
        if rest.count(":") > 1:
            raise bad("an IPv6 address goes in brackets, [::1]:8786")
        host, _, port_text = rest.partition(":") if ":" in rest else (rest, "", None)
        if not _HOST.fullmatch(host):
            raise bad(f"{host!r} is not a host name or address")
        shown_host = host
    if port_text is None:
        port = DEFAULT_PORT
    elif not (port_text.isascii() and port_text.isdigit()) or len(port_text) > 5 or not 1 <= int(port_text) <= 65535:
        raise bad(f"the port must be a number from 1 to 65535, got {port_text[:12]!r}")
    else:
        port = int(port_text)
    return f"tcp://{shown_host}:{port}"


def _host_port(addr: str) -> tuple[str, int]:
    hostport = addr.split("://", 1)[1]
    host, _, port = hostport.rpartition(":")
    return host.strip("[]"), int(port)


def probe(addr: str, timeout_s: float = CONNECT_S, handshake_s: float = HANDSHAKE_S) -> None:
    """Check that a dask scheduler answers at ``addr`` (``tcp://host:port``), within about
    ``timeout_s + handshake_s`` seconds; StarforgeError in one line otherwise, saying what is
    there instead: nothing (connection refused), no answer (an unreachable host or a
    firewall), an HTTP server, a listener that sends nothing, or bytes that are not dask's.

    A dask scheduler sends its handshake as soon as a connection is accepted (a frame of
    distributed's TCP protocol: a little-endian uint64 length, then the number of sub-frames
    and their lengths); that is read here without dask, and sent back as this side's
    handshake (the same settings), so the scheduler sees an ordinary short-lived connection."""
    import socket
    import struct

    host, port = _host_port(addr)
    hint = f"start one with `dask scheduler`, or unset --scheduler / {ENV_SCHEDULER} to run on this machine"
    try:
        sock = socket.create_connection((host, port), timeout=timeout_s)
    except socket.gaierror:
        raise StarforgeError(f"cannot reach the dask scheduler at {addr}: unknown host {host!r}; {hint}") from None
    except ConnectionRefusedError:
        raise StarforgeError(
            f"cannot reach the dask scheduler at {addr}: nothing listens there (connection refused); {hint}"
        ) from None
    except TimeoutError:
        raise StarforgeError(
            f"cannot reach the dask scheduler at {addr}: no answer in {timeout_s:g} s "
            f"(host down, or a firewall); {hint}"
        ) from None
    except OSError as exc:
        raise StarforgeError(f"cannot reach the dask scheduler at {addr}: {exc.strerror or exc}; {hint}") from None
    not_dask = f"{addr} is not a dask scheduler"
    with sock:
        sock.settimeout(handshake_s)
        try:
            head = _recv_exact(sock, 16)
        except TimeoutError:
            if _speaks_http(sock):
                raise StarforgeError(
                    f"{not_dask}: an HTTP server answers there (a dask dashboard is usually on port 8787, "
                    f"the scheduler on {DEFAULT_PORT})"
                ) from None
            raise StarforgeError(
                f"{not_dask}: something accepts connections there but sent no dask handshake in "
                f"{handshake_s:g} s (a scheduler sends one at once, unless it is too busy to answer)"
            ) from None
        except OSError as exc:
            raise StarforgeError(f"{not_dask}: the connection failed ({exc.strerror or exc})") from None
        total, frames = struct.unpack("<QQ", head) if len(head) == 16 else (0, 0)
        if len(head) < 16 or not (16 <= total <= 1 << 20 and 1 <= frames <= 64):
            head += _recv_some(sock, 64)  # enough of its greeting to name it
            said = head.decode("latin-1").splitlines()[0] if head.strip() else "nothing"
            raise StarforgeError(f"{not_dask}: it answered {said[:40]!r}, not dask's handshake")
        try:
            body = _recv_exact(sock, total - 8)
            sock.sendall(head + body)
        except OSError:  # it sent a handshake and went away: the client's connection says more
            pass


def _recv_exact(sock, n: int) -> bytes:
    """Up to ``n`` bytes (fewer only when the peer closed the connection)."""
    buf = b""
    while len(buf) < n:
        part = sock.recv(n - len(buf))
        if not part:
            break
        buf += part
    return buf


def _recv_some(sock, n: int) -> bytes:
    """Whatever of up to ``n`` more bytes arrives within a fifth of a second."""
    try:
        sock.settimeout(0.2)
        return sock.recv(n)
    except OSError:
        return b""


def _speaks_http(sock) -> bool:
    """Whether a listener that sent nothing answers an HTTP request (within one second)."""
    try:
        sock.settimeout(1.0)
        sock.sendall(b"HEAD / HTTP/1.0\r\n\r\n")
        reply = sock.recv(16)
    except OSError:
        reply = b""
    return reply.startswith(b"HTTP/")
