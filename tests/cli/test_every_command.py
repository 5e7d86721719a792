"""Every `abyss` command as a user first meets it: in a clean environment (no MUJOCO_GL, no
DISPLAY, none of the tests' settings), from a directory of its own; its help, and a wrong
argument, each ending with a clear line and no traceback. (`abyss stress satellite` crashed in
such an environment: the parser compiled the robot's model for `abyss fault`'s help, which
imported MuJoCo before the command chose its OpenGL backend; the tests had set MUJOCO_GL.)"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from abyss.cli import parser

# a wrong argument of each kind a command takes, and what its one line says
WRONG = {
    ("up",): (["--duration", "-5"], "--duration: -5 s"),
    ("station",): (["nowhere"], "invalid choice: 'nowhere'"),
    ("health",): ([], "required: station"),
    ("certs", "make"): ([], "required: DIR"),
    ("keys",): (["--bad"], "unrecognized arguments: --bad"),
    ("link", "show"): (["--connect", "tcp/127.0.0.1:1"], "no system is running"),
    ("link", "set"): (["nolink"], "invalid choice: 'nolink'"),
    ("link", "netem"): (["tether"], "required: --dev"),
    ("link", "shape"): (["tether"], "required: --peer"),
    ("link", "profiles"): (["--bogus"], "unrecognized arguments: --bogus"),
    ("lab", "up"): (["--bogus"], "unrecognized arguments: --bogus"),
    ("lab", "exec"): ([], "required: station"),
    ("lab", "down"): (["--bogus"], "unrecognized arguments: --bogus"),
    ("teleop",): (["--bogus"], "unrecognized arguments: --bogus"),
    ("console",): (["--connect", "tcp/127.0.0.1:1"], "no system is running"),
    ("op",): (["valve", "valve_1", "--connect", "tcp/127.0.0.1:1"], "no system is running"),
    ("fault",): (["thruster", "nope", "2", "--connect", "tcp/127.0.0.1:1"], "no system is running"),
    ("view",): (["no-such-run"], "no such run directory"),
    ("replay",): (["no-such-run"], "no such run directory"),
    ("export", "mcap"): (["no-such-run"], "no recording"),
    ("scenario", "run"): (["no-such.toml"], "cannot read"),
    ("check",): (["nowhere"], "invalid choice: 'nowhere'"),
    ("plot",): (["no-such-run"], "has no control.csv"),
    ("stress", "satellite"): (["--duration", "1"], "--duration: 1.0 s: allowed 2 to 3600 s"),
    ("campaign", "run"): (["no-such.toml"], "cannot read"),
    ("campaign", "merge"): (["x"], "required: --out"),
    ("campaign", "replay"): (["x"], "required: RUN_ID"),
    ("scene", "export"): (["no-such-run"], "holds no scene.msgpack"),
    ("terrain", "build"): (["no-such.ply", "--out", "terrain"], "no such file"),
    ("terrain", "cloud"): (["no-such-dir/seabed.ply"], "could not be written"),
    ("robot", "check"): (["no-such-robot"], "cannot read"),
    ("sitl",): (["--robot", "no-such-robot"], "not a robot package"),
}


def commands(p: argparse.ArgumentParser, prefix: tuple[str, ...] = ()) -> Iterator[tuple[str, ...]]:
    """Every leaf command of the parser, as the words that name it."""
    for action in p._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from commands(sub, (*prefix, name))
            return
    yield prefix


def run(words: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    """`abyss WORDS` in a clean environment: the PATH and HOME alone."""
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": os.environ.get("HOME", "/root")}
    return subprocess.run(
        [sys.executable, "-P", "-m", "abyss.cli", *words],
        capture_output=True,
        text=True,
        cwd=cwd,
        env=env,
        timeout=120,
    )


def test_every_command_has_a_wrong_argument_here() -> None:
    assert set(commands(parser())) == set(WRONG)


def test_every_command_shows_its_help_and_refuses_a_wrong_argument_in_one_line(tmp_path: Path) -> None:
    names = sorted(WRONG)
    with ThreadPoolExecutor(4) as pool:
        helps = list(pool.map(lambda c: run([*c, "--help"], tmp_path), names))
        wrongs = list(pool.map(lambda c: run([*c, *WRONG[c][0]], tmp_path), names))
    for command, shown, wrong in zip(names, helps, wrongs, strict=True):
        words = " ".join(command)
        assert shown.returncode == 0 and "usage: abyss" in shown.stdout, (words, shown.stderr)
        out = wrong.stdout + wrong.stderr
        assert "Traceback" not in out, (words, out)
        last = wrong.stderr.strip().splitlines()[-1] if wrong.stderr.strip() else ""
        assert wrong.returncode == 2 and last.startswith("abyss") and WRONG[command][1] in last, (words, out)
    assert not any(tmp_path.iterdir())  # nothing written where it was run


@pytest.mark.timeout(300)
def test_stress_satellite_renders_in_a_clean_environment(tmp_path: Path) -> None:
    """It renders in its own process: with no MUJOCO_GL set, it chooses the backend itself."""
    done = run(["stress", "satellite", "--resolutions", "0.2", "--duration", "2", "--out", "out"], tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert (tmp_path / "out" / "stress_satellite.json").is_file()
