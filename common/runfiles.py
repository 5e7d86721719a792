"""Files a station keeps in its run directory and reads back when it is restarted there."""

from __future__ import annotations

import json
import os
from pathlib import Path

COMMANDS_FILE = "commands.json"  # every command shore sent, how often, and onboard's answer
EVENTS_FILE = "events.json"  # the restarts shore saw and what it did about them
CARRIED_OVER = (COMMANDS_FILE, EVENTS_FILE)  # what a restarted shore reads back


def read_json_list(path: Path) -> list[dict[str, object]]:
    """What an earlier run of a station left in `path` (a restart); [] if nothing."""
    try:
        items = json.loads(path.read_text())
    except (OSError, ValueError):
        return []
    return [item for item in items if isinstance(item, dict)] if isinstance(items, list) else []


def write_whole(path: Path, data: bytes | str) -> None:
    """Write `path` so that a reader, or a process killed meanwhile, never leaves half a file:
    to a file of this process's beside it, then renamed over it."""
    partial = path.with_name(f".{path.name}.{os.getpid()}")
    if isinstance(data, str):
        partial.write_text(data)
    else:
        partial.write_bytes(data)
    partial.replace(path)
