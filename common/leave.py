"""Leaving a process that holds Zenoh sessions and native threads (a station, the pilot's
console): its stop is bounded, whatever hangs in it, and it ends without the interpreter's
finalisation."""

from __future__ import annotations

import faulthandler
import logging
import os
import sys
import threading
from collections.abc import Callable
from typing import NoReturn

STOP_BOUND_S = 4.5  # a process stops within 5 s of being asked (this, and exiting)
log = logging.getLogger(__name__)


def watch_the_stop(name: str, stopped: threading.Event, last_words: Callable[[], int]) -> None:
    """Run in a thread of its own once a stop is asked: past STOP_BOUND_S without `stopped`, every
    thread's stack goes to stderr (what hung: a Zenoh teardown, a native call), `last_words` runs
    (it writes what it must and gives the exit code), and the process ends."""
    if stopped.wait(STOP_BOUND_S):
        return
    log.error("%s: not stopped %.1f s after it was asked; the threads' stacks:", name, STOP_BOUND_S)
    faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
    code = last_words()
    sys.stderr.flush()
    os._exit(code)


def leave(code: int) -> NoReturn:
    """End the process, everything closed and written, without the interpreter's finalisation,
    which aborts the process ("exception not rethrown") when a daemon thread is still inside
    native code (an octree insertion, an ICP, a Zenoh callback) as it tears the threads down."""
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
