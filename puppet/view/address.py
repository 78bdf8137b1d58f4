"""Where the live view listens: ``[HOST:]PORT`` parsing, the listening socket, the URL, the token.

Bound to 127.0.0.1 unless the user names another address; beyond loopback every request needs
a random token (carried in the printed URL), compared in constant time.
"""

from __future__ import annotations

import errno
import hmac
import ipaddress
import secrets
import socket
from dataclasses import dataclass

from puppet.view.errors import ViewError

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
LOOPBACK_NAMES = ("localhost",)


def parse_address(text: str | None) -> tuple[str, int]:
    """(host, port) from '' / None (the default), 'PORT', 'HOST:PORT' or '[IPv6]:PORT'."""
    if text is None or str(text).strip() == "":
        return DEFAULT_HOST, DEFAULT_PORT
    text = str(text).strip()
    host, port_text = DEFAULT_HOST, text
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            raise ViewError(f"--view {text!r}: missing ']' after an IPv6 address")
        host, rest = text[1:end], text[end + 1:]
        port_text = rest[1:] if rest.startswith(":") else (rest or str(DEFAULT_PORT))
    elif ":" in text:
        host, port_text = text.rsplit(":", 1)
        port_text = port_text or str(DEFAULT_PORT)
    elif not text.isdigit():
        host, port_text = text, str(DEFAULT_PORT)
    try:
        port = int(port_text)
    except ValueError:
        raise ViewError(f"--view {text!r}: port {port_text!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise ViewError(f"--view {text!r}: port {port} is not in 0..65535")
    return host or DEFAULT_HOST, port


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and 'localhost'."""
    if host.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on (host, port); ViewError naming the address when it is taken."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as err:
        raise ViewError(f"--view: cannot resolve host {host!r}: {err.strerror}") from None
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
            raise ViewError(f"--view: address {where} is already in use (port {port}); "
                            "stop the other program or pick another port, e.g. --view "
                            f"{port + 1}") from None
        raise ViewError(f"--view: cannot listen on {where}: {err.strerror}") from None
    sock.setblocking(False)
    return sock


@dataclass(frozen=True)
class Access:
    """Who may use the view. token: None on loopback, else the secret every request carries."""

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
