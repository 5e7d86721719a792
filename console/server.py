"""The pilot's console served: the page (`console/web/`) and its state over HTTP, on 127.0.0.1 unless
told otherwise, where others reach it only with the operator's token, over HTTPS with the operator's
certificate (`console.access`). GET /,
/console.js (the page), /state (`Pilot.state`, with the embedded viewer's address), /frame.jpg and
/sonar.png (the latest relayed frame and sonar fan); POST /command (`abyss op`'s kind, value,
amount) and /teleop (a step of the vehicle's or the end-effector's goal)."""

from __future__ import annotations

import json
import logging
import os
import signal
import ssl
import sys
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import zenoh

from abyss.bus import description
from abyss.bus.session import client_config, open_session
from abyss.common.errors import AbyssError, BadInput, ConfigError
from abyss.common.leave import leave, watch_the_stop
from abyss.console.access import HEADER, Access, operator_name
from abyss.console.pilot import Pilot
from abyss.description.models.panel import Panel
from abyss.security.access import tool_certificates
from abyss.security.certs import CertFiles

WEB = Path(__file__).parent / "web"
FILES = {"/": ("index.html", "text/html"), "/console.js": ("console.js", "text/javascript")}
IMAGES = ("/frame.jpg", "/sonar.png")
log = logging.getLogger(__name__)


def _handler(pilot: Pilot, access: Access, viewer_url: str) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        def _allowed(self) -> bool:
            if access.allows(self.path, self.headers):
                return True
            why = f"the console needs the operator's token (the address it printed, or {HEADER})"
            self._reply(HTTPStatus.UNAUTHORIZED, json.dumps({"error": why}).encode(), "application/json")
            return False

        def do_GET(self) -> None:
            path = self.path.split("?", 1)[0]
            if not self._allowed():
                return
            if path in FILES:
                name, kind = FILES[path]
                self._reply(HTTPStatus.OK, (WEB / name).read_bytes(), kind)
            elif path == "/state":
                state = pilot.state() | {"viewer_url": viewer_url}
                self._reply(HTTPStatus.OK, json.dumps(state).encode(), "application/json")
            elif path in IMAGES and (data := pilot.image(path)) is not None:
                self._reply(HTTPStatus.OK, data, "image/jpeg" if path.endswith(".jpg") else "image/png")
            else:
                self._reply(HTTPStatus.NOT_FOUND, b"not found", "text/plain")

        def do_POST(self) -> None:
            if not self._allowed():
                return
            if self.path not in ("/command", "/teleop"):
                self._reply(HTTPStatus.NOT_FOUND, b"not found", "text/plain")
                return
            try:
                asked = json.loads(self.rfile.read(int(self.headers.get("Content-Length", 0))))
                if self.path == "/teleop":
                    pilot.nudge(asked["target"], list(asked["translation_m"]), list(asked["rotation_rad"]))
                    command_id = -1
                else:
                    command_id = pilot.send(
                        str(asked["kind"]), str(asked["value"]), str(asked.get("amount", ""))
                    )
            except (AbyssError, BadInput, KeyError, ValueError, TypeError) as exc:
                self._reply(
                    HTTPStatus.BAD_REQUEST, json.dumps({"error": str(exc)}).encode(), "application/json"
                )
                return
            self._reply(HTTPStatus.OK, json.dumps({"id": command_id}).encode(), "application/json")

        def _reply(self, status: HTTPStatus, body: bytes, kind: str) -> None:
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, format: str, *args: Any) -> None:
            log.debug(format, *args)

    return Handler


class _Server(ThreadingHTTPServer):
    daemon_threads = True

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A client that does not speak the console's TLS (plain HTTP, an untrusted certificate)
        or that left mid-request: one line in the log, not a traceback."""
        error = sys.exc_info()[1]
        if isinstance(error, ssl.SSLError | ConnectionError):
            log.info("the console dropped %s: %s", client_address[0], error)
        else:
            super().handle_error(request, client_address)


class Console:
    """The console served on `host`:`port` (0: any free one) over `session`, a session on
    shore's network (`abyss console`'s own, or `abyss up`'s); `url` where (with the token a
    non-local `host` asks, `console.access`); `viewer_url`: rerun's web viewer of the live
    recording, embedded in the page ("" none); `close()` ends it."""

    def __init__(
        self,
        session: zenoh.Session,
        system: str,
        port: int,
        panel: Panel,
        host: str = "127.0.0.1",
        certificates: CertFiles | None = None,
        viewer_url: str = "",
    ) -> None:
        self.pilot = Pilot(session, system, panel)
        self.access = Access.at(host, system, certificates)
        self.subscribers = self.pilot.start()
        try:
            self.server = _Server((host, port), _handler(self.pilot, self.access, viewer_url))
        except OSError as exc:
            self._undeclare()
            raise ConfigError(
                "the console's address",
                f"cannot serve on {host}:{port} (--console, or --bind and --port): {exc}",
            ) from None
        if (context := self.access.tls_context()) is not None:  # each handshake in its request's thread
            self.server.socket = context.wrap_socket(
                self.server.socket, server_side=True, do_handshake_on_connect=False
            )
        elif self.access.token is not None:
            log.warning(
                "the console on %s is plain HTTP: its token crosses the network in the clear, and a "
                "browser allows no gamepad there; with the operator's certificate ($ABYSS_TLS_DIR, a "
                "tls/ endpoint) it serves HTTPS",
                host,
            )
        port = self.server.server_address[1]
        self.pilot.by = f"{operator_name('console')}:{port}"  # as other consoles name this one
        self.url = self.access.url(port)
        self.stop = threading.Event()
        self.threads = [
            threading.Thread(target=self.server.serve_forever, name="console http", daemon=True),
            threading.Thread(target=self._watch, name="console watch", daemon=True),
        ]
        for thread in self.threads:
            thread.start()

    def _watch(self) -> None:
        while not self.stop.wait(0.5):
            self.pilot.watch()

    def _undeclare(self) -> None:
        for subscriber in self.subscribers:
            subscriber.undeclare()

    def close(self) -> None:
        self.stop.set()
        self.server.shutdown()
        self.server.server_close()
        self._undeclare()


def run_console(endpoint: str, system: str, port: int, host: str = "127.0.0.1", viewer_url: str = "") -> int:
    """`abyss console`: serve the console until SIGINT or SIGTERM, then close within
    STOP_BOUND_S whatever hangs (common.leave). The signals' handler only writes to a pipe that
    the main thread reads: nothing is raised inside a lock's bytecodes, whichever thread the
    signal lands on."""
    certificates = tool_certificates(endpoint)
    asked, ask = os.pipe()
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda number, _frame: os.write(ask, bytes([number])))
    session = open_session(client_config(endpoint), "abyss console")
    try:
        panel = description.fetch(session, system).panel  # the running system's
        console = Console(session, system, port, panel, host, certificates, viewer_url)
    except BaseException:
        session.close()
        raise
    print(f"abyss console: {console.url} (system {system!r} at {endpoint})", flush=True)
    log.info("abyss console: %s received, closing", signal.Signals(os.read(asked, 1)[0]).name)
    closed = threading.Event()
    threading.Thread(
        target=watch_the_stop, args=("abyss console", closed, lambda: 1), name="stop watchdog", daemon=True
    ).start()
    console.close()
    session.close()
    closed.set()
    leave(0)
