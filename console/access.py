"""Who may use the pilot's console. On 127.0.0.1 (the default) only this machine's users reach
it, and it asks nothing. Bound to an address others can reach, every request for data or a
command must carry the operator's token: with the operator's certificate (`ABYSS_TLS_DIR`, as
`abyss op` takes it for a tls/ endpoint), a token derived from its private key, the same each
time, so the operator can work it out again with `abyss console --token`; without one, a random
token made at start. The address `abyss console` prints carries it (`?token=`), the page sends it
on each request (the `X-Abyss-Token` header, or `token=` for an image), and a request without it
is refused (401) before anything is read or sent. With the operator's certificate it is also
served over HTTPS, with that certificate (signed by the system's CA, naming the hosts given to
`abyss certs make --host operator=...`): the token never crosses the network in the clear, and the
page is a secure context, which a browser asks of the Gamepad API off localhost. Without one the
page is plain HTTP, and the console says so at start."""

from __future__ import annotations

import getpass
import hashlib
import hmac
import ipaddress
import secrets
import socket
import ssl
from dataclasses import dataclass
from email.message import Message as Headers
from urllib.parse import parse_qs, urlsplit

from abyss.security.certs import CertFiles

HEADER = "X-Abyss-Token"
OPEN_PATHS = ("/", "/console.js")  # the page itself: it holds nothing, and says when it needs the token


def local(host: str) -> bool:
    """Whether `host` is an address only this machine reaches (a loopback address)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def token_of(certificates: CertFiles, system: str) -> str:
    """The console's token for `system`, derived from the operator's private key."""
    key = certificates.private_key.read_bytes()
    return hmac.new(key, f"abyss console {system}".encode(), hashlib.sha256).hexdigest()[:32]


def operator_name(what: str) -> str:
    """Who sends from this tool, as other consoles show it: `what user@host`."""
    return f"{what} {getpass.getuser()}@{socket.gethostname()}"


@dataclass(frozen=True)
class Access:
    """The console's rule: `token` None asks for nothing (a loopback bind); `certificates` the
    operator's, which a non-local bind serves HTTPS with (None: plain HTTP)."""

    host: str
    token: str | None
    certificates: CertFiles | None = None

    @classmethod
    def at(cls, host: str, system: str, certificates: CertFiles | None) -> Access:
        if local(host):
            return cls(host, None)
        if certificates is None:
            return cls(host, secrets.token_urlsafe(18))
        return cls(host, token_of(certificates.check(), system), certificates)

    @property
    def scheme(self) -> str:
        return "https" if self.certificates is not None else "http"

    def tls_context(self) -> ssl.SSLContext | None:
        """The server's TLS context with the operator's certificate (None: plain HTTP)."""
        if self.certificates is None:
            return None
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        context.minimum_version = ssl.TLSVersion.TLSv1_2
        context.load_cert_chain(self.certificates.certificate, self.certificates.private_key)
        return context

    def allows(self, path: str, headers: Headers) -> bool:
        """Whether a request for `path` (with its query) and `headers` may be served."""
        if self.token is None or urlsplit(path).path in OPEN_PATHS:
            return True
        given = headers.get(HEADER) or parse_qs(urlsplit(path).query).get("token", [""])[0]
        return hmac.compare_digest(given.encode(), self.token.encode())

    def url(self, port: int) -> str:
        """Where the page is, with the token when one is asked."""
        host = socket.gethostname() if self.host in ("0.0.0.0", "::") else self.host
        host = f"[{host}]" if ":" in host else host
        return f"{self.scheme}://{host}:{port}/" + (f"?token={self.token}" if self.token else "")
