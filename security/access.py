"""Authenticated links: Zenoh over TLS with mutual certificates (`security.certs`), and access
control so that a station takes each data key it receives only from the station that owns it
(only onshore may send operator commands down, only the vessel may publish to onboard, ...).

Zenoh refuses a peer without a valid certificate in the TLS handshake, and drops a message the
access control denies; it says so only in its own log on standard output (a warning for the
handshake, a trace line for a denial). `RefusalLog` reads that log back and turns each refusal into a counted
warning of the station's own log, once per peer and key, as for any bad input."""

from __future__ import annotations

import logging
import os
import re
import sys
import threading
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

import zenoh

from abyss.common.errors import ConfigError
from abyss.interface import keys
from abyss.security.certs import HOLDERS, OPERATOR, CertFiles

log = logging.getLogger(__name__)
TLS_DIR_ENV = "ABYSS_TLS_DIR"  # the certificates' directory for tools that connect to tls/ endpoints
ALL_MESSAGES = (
    "put",
    "delete",
    "query",
    "reply",
    "declare_subscriber",
    "declare_queryable",
    "liveliness_token",
    "liveliness_query",
    "declare_liveliness_subscriber",
)


def check_endpoints(endpoints: Sequence[str], tls: CertFiles | None) -> None:
    """With certificates every endpoint is tls/, without them none is: fail at start otherwise."""
    for endpoint in endpoints:
        if tls is not None and not endpoint.startswith("tls/"):
            raise ConfigError("endpoint", f"{endpoint!r}: with --tls every endpoint must be tls/HOST:PORT")
        if tls is None and endpoint.startswith("tls/"):
            raise ConfigError(
                "endpoint",
                f"{endpoint!r} needs certificates: --tls DIR or {TLS_DIR_ENV}=DIR "
                "(make them with `abyss certs make DIR`)",
            )


def tool_certificates(endpoint: str) -> CertFiles | None:
    """The operator's certificate for a tool connecting to a tls/ endpoint (from $ABYSS_TLS_DIR)."""
    if not endpoint.startswith("tls/"):
        return None
    directory = os.environ.get(TLS_DIR_ENV)
    if not directory:
        raise ConfigError(
            TLS_DIR_ENV,
            f"is not set; {endpoint} needs the directory of "
            "`abyss certs make DIR` (the operator's certificate)",
        )
    return CertFiles(Path(directory), OPERATOR)


def tls_settings(files: CertFiles) -> dict[str, Any]:
    """`transport/link/tls`: mutual TLS, both ends' certificates signed by the abyss CA. The peer
    is named by its certificate's common name, not by its address (stations on a vessel's
    network move between addresses), so the name check on connect is off."""
    return {
        "root_ca_certificate": str(files.ca),
        "listen_certificate": str(files.certificate),
        "listen_private_key": str(files.private_key),
        "connect_certificate": str(files.certificate),
        "connect_private_key": str(files.private_key),
        "enable_mtls": True,
        "verify_name_on_connect": False,
    }


def access_control(station: str) -> dict[str, Any]:
    """Zenoh access control for `station`: every certificate holder may do anything on abyss
    keys, except put a data key that `station` receives (`keys.KEYS`) unless it is the key's
    publisher. A holder not in `certs.HOLDERS` matches no subject and is denied everything."""
    received = [s for s in keys.KEYS if s.to == keys.check_station(station)]
    publishers = sorted({s.station for s in received})
    rules: list[dict[str, Any]] = [
        {
            "id": "testbed",
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": list(ALL_MESSAGES),
            "key_exprs": [f"{keys.PREFIX}/**"],
        }
    ]
    for publisher in publishers:
        rules.append(
            {
                "id": f"only-{publisher}",
                "permission": "deny",
                "flows": ["ingress"],
                "messages": ["put", "delete"],
                "key_exprs": [
                    f"{keys.PREFIX}/*/{s.station}/{s.topic}" for s in received if s.station == publisher
                ],
            }
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": [{"id": holder, "cert_common_names": [holder]} for holder in HOLDERS],
        "policies": [
            {
                "id": f"as-{holder}",
                "subjects": [holder],
                "rules": ["testbed", *(f"only-{p}" for p in publishers if p != holder)],
            }
            for holder in HOLDERS
        ],
    }


# Zenoh's log lines that say it refused a peer or a message.
_DENIED = re.compile(
    r"on (?P<subject>\S+) is unauthorized to (?P<action>[\w ]+?) \((?P<flow>\w+)\) "
    r"on (?P<key>\S+)"
)
_HANDSHAKE = re.compile(r"zenoh_link_tls::unicast: (?P<reason>.*?)(?:\. Hint:.*)?$")
# per message, per declared key, or by design (tls_settings): not worth a line of the station's log
_QUIET = re.compile(r"is authorized to|caching permissions|Skipping name verification")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
_CERT_NAME = re.compile(r"CertCommonName\((?P<name>[^)]*)\)")
_THREAD = re.compile(r"ThreadId\((?P<id>\d+)\)")
_DROPPED = "Msg intercepted!"  # follows a denial that dropped a message (not one computed for a cache)
ZENOH_LOG_FILTER = "warn,zenoh::net::routing::interceptor=trace"


class RefusalLog:
    """Zenoh's log, line by line: refusals become counted warnings of this process's log, the
    per-message 'authorized' trace lines are dropped, everything else goes on to `out`."""

    def __init__(self, out: TextIO) -> None:
        self.refused: Counter[str] = Counter()
        self._out = out
        self._logged: set[str] = set()
        self._lock = threading.Lock()
        self._denied: dict[str, str] = {}  # thread -> the denial it logged last, until it drops the message

    def read(self, fd: int) -> None:
        with os.fdopen(fd, "r", errors="replace") as lines:
            for line in lines:
                self.take(line)

    def take(self, line: str) -> None:
        """One line of Zenoh's log."""
        plain = _ANSI.sub("", line).rstrip()
        thread = _THREAD.search(plain)
        denial = self._denied.pop(thread["id"], None) if thread else None
        if _QUIET.search(plain):
            return
        if denied := _DENIED.search(plain):
            holder = _CERT_NAME.search(denied["subject"])
            who = holder["name"] if holder else "a peer without a known certificate"
            if thread:
                action = denied["action"].lower()
                self._denied[thread["id"]] = f"{who}: {action} on {denied['key']} ({denied['flow']})"
            return
        if plain.endswith(_DROPPED):
            if denial:
                self.refuse(denial, "access control denied")
            return
        if "WARN" in plain and (handshake := _HANDSHAKE.search(plain)):
            self.refuse(f"TLS handshake: {handshake['reason']}", "peer refused")
            return
        self._out.write(line)

    def refuse(self, what: str, verdict: str) -> None:
        with self._lock:
            self.refused[what] += 1
            first = what not in self._logged
            self._logged.add(what)
        if first:
            log.warning("%s: %s", verdict, what)


_refusal_log: RefusalLog | None = None


def refusal_log() -> RefusalLog:
    """The process's one reader of Zenoh's log (a station is one process): Zenoh writes it to
    file descriptor 1, which from here on is a pipe read by a thread; Python's own standard
    output keeps the real one."""
    global _refusal_log
    if _refusal_log is None:
        sys.stdout.flush()
        sys.stdout = os.fdopen(os.dup(1), "w", buffering=1)
        read_fd, write_fd = os.pipe()
        os.dup2(write_fd, 1)
        os.close(write_fd)
        _refusal_log = RefusalLog(sys.stdout)
        threading.Thread(target=_refusal_log.read, args=(read_fd,), name="zenoh-log", daemon=True).start()
        zenoh.init_log_from_env_or(ZENOH_LOG_FILTER)
    return _refusal_log
