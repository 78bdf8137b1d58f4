"""Where a server of puppet listens (the live view's ``--view``, the Blender link's ``--link``):
``[HOST:]PORT`` parsing, the listening socket, the URL, the token.

Bound to 127.0.0.1 unless the user names another address; beyond loopback every request needs
a random token (carried in the printed URL), compared in constant time. Errors name the option
the address came from (``option``).
"""

from __future__ import annotations

import errno
import hmac
import ipaddress
import secrets
import socket
from dataclasses import dataclass

from puppet.errors import PuppetError

DEFAULT_HOST = "127.0.0.1"
LOOPBACK_NAMES = ("localhost",)


class AddressError(PuppetError):
    """A listening address that cannot be parsed, resolved or bound (in use, no permission);
    the message names the option it came from."""


def parse_address(text: str | None, *, option: str, default_port: int) -> tuple[str, int]:
    """(host, port) from '' / None (the default), 'PORT', 'HOST', 'HOST:PORT' or '[IPv6]:PORT';
    a port left out is ``default_port``. AddressError naming ``option`` (e.g. '--view')."""
    if text is None or str(text).strip() == "":
        return DEFAULT_HOST, default_port
    text = str(text).strip()
    host, port_text = DEFAULT_HOST, text
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            raise AddressError(f"{option} {text!r}: missing ']' after an IPv6 address")
        host, rest = text[1:end], text[end + 1:]
        port_text = rest[1:] if rest.startswith(":") else (rest or str(default_port))
    elif ":" in text:
        host, port_text = text.rsplit(":", 1)
        port_text = port_text or str(default_port)
    elif not text.isdigit():
        host, port_text = text, str(default_port)
    try:
        port = int(port_text)
    except ValueError:
        raise AddressError(f"{option} {text!r}: port {port_text!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise AddressError(f"{option} {text!r}: port {port} is not in 0..65535")
    return host or DEFAULT_HOST, port


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and 'localhost'."""
    if host.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def one_place(a: tuple[str, int], b: tuple[str, int]) -> bool:
    """Whether two (host, port) addresses would take one listening place: the same port (not 0:
    each of those gets a free one) on hosts that resolve to a shared address, or either host
    the wildcard (0.0.0.0, ::: every address). A host that does not resolve shares nothing
    (``bind`` names it)."""
    if a[1] != b[1] or a[1] == 0:
        return False
    ips = []
    for host in (a[0], b[0]):
        try:
            infos = socket.getaddrinfo(host, a[1], type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        except socket.gaierror:
            return False
        ips.append({ipaddress.ip_address(info[4][0].split("%", 1)[0]) for info in infos})
    if any(ip.is_unspecified for ip in ips[0] | ips[1]):
        return True
    return bool(ips[0] & ips[1])


def bind(host: str, port: int, *, option: str) -> socket.socket:
    """A listening TCP socket on (host, port); AddressError naming ``option`` and the address
    when it cannot be had (taken, unresolvable, not allowed)."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as err:
        raise AddressError(f"{option}: cannot resolve host {host!r}: {err.strerror}") from None
    family, kind, proto, _, address = infos[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(64)
    except OSError as err:
        sock.close()
        where = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
        if err.errno == errno.EADDRINUSE:
            raise AddressError(f"{option}: address {where} is already in use (port {port}); "
                               f"stop the other program or pick another port, e.g. {option} "
                               f"{port + 1}") from None
        raise AddressError(f"{option}: cannot listen on {where}: {err.strerror}") from None
    sock.setblocking(False)
    return sock


@dataclass(frozen=True)
class Access:
    """Who may use a server. token: None on loopback, else the secret every request carries."""

    host: str
    port: int
    token: str | None

    @classmethod
    def for_host(cls, host: str, port: int) -> "Access":
        return cls(host, port, None if is_loopback(host) else secrets.token_urlsafe(18))

    def url(self) -> str:
        """The URL to open (with the token when one is needed)."""
        shown = self.host
        if shown in ("0.0.0.0", "::"):
            shown = socket.gethostname()
        if ":" in shown:
            shown = f"[{shown}]"
        base = f"http://{shown}:{self.port}/"
        return base if self.token is None else f"{base}?token={self.token}"

    def token_ok(self, given: str | None) -> bool:
        """Constant-time check of a request's token (always True on loopback)."""
        if self.token is None:
            return True
        return given is not None and hmac.compare_digest(given.encode(), self.token.encode())

    def host_ok(self, host_header: str | None) -> bool:
        """On loopback, the Host header must name loopback (no DNS rebinding); beyond loopback
        the token is the guard."""
        if self.token is not None:
            return True
        if not host_header:
            return False
        name = host_header.rsplit(":", 1)[0] if not host_header.endswith("]") else host_header
        name = name.strip("[]")
        return is_loopback(name)
