"""Running one station: the same code path for `abyss station` and `abyss up`."""

from __future__ import annotations

import importlib
import json
import logging
import signal
import socket
import sys
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from common import keys
from common.bus import Bus
from common.config import Config

log = logging.getLogger(__name__)


def station_entry(name: str) -> Callable[[Config, Any], None]:
    """The station's `run(config, bus)`."""
    return importlib.import_module(f"stations.{keys.check_station(name)}").run  # type: ignore[no-any-return]


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def run_station(name: str, config: Config, listen: Sequence[str], connect: Sequence[str],
                status_file: Path | None, link_mode: str = "emulated") -> int:
    """Open the bus, run the station until SIGINT/SIGTERM, close, write the status file."""
    entry = station_entry(name)
    bus = Bus(config.system, name, config.links.profiles(), listen=listen, connect=connect,
              seed=config.seed, link_mode=link_mode)

    def stop(signum: int, _frame: Any) -> None:
        log.info("%s: %s received, stopping", name, signal.Signals(signum).name)
        bus.stop.set()

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, stop)
        signal.signal(signal.SIGTERM, stop)
    log.info("%s up in system %s (listen %s, connect %s)", name, config.system, list(listen), list(connect))
    code = 0
    try:
        entry(config, bus)
    except Exception:
        log.exception("%s failed", name)
        code = 1
    status = bus.status()
    bus.close()
    if status_file is not None:
        status_file.write_text(json.dumps({"exit_code": code, **status}, indent=2))
    log.info("%s stopped (exit %d)", name, code)
    return code


def configure_logging(verbose: bool = False) -> None:
    logging.basicConfig(level=logging.DEBUG if verbose else logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
