"""The rooms of the package import only downwards (issue 37):

    common  <-  linkemu, scene  <-  recording  <-  ros2  <-  stations  <-  harness

where the harness is launch, validation, cli and console. A room may import itself and any room
below it, never one above it nor a sibling on its own floor (linkemu and scene know nothing of
each other); the harness's rooms may import each other. The system under test sees nothing of the
testbed (issue 50): `stations` imports `common` and `scene` alone, never the link emulator, the
recording or ROS 2; the shell that hosts a station among them is the harness's (launch.station).
Read from the source with `ast`, every import counted: at the top of a module, inside
functions, and under `if TYPE_CHECKING:` (a type-only import is still a dependency of the design,
and none of the tree needs one upwards), in the forms `import abyss.x`, `from abyss.x import y`,
`from abyss import x` and relative ones.

And every module of the package imports (the whole walk, a few seconds)."""

from __future__ import annotations

import ast
import pkgutil
import subprocess
import sys
import textwrap
import time
import tomllib
from pathlib import Path

import abyss

ROOT = Path(__file__).resolve().parent.parent
FLOORS: tuple[tuple[str, ...], ...] = (  # lowest first
    ("common",),
    ("linkemu", "scene"),
    ("recording",),
    ("ros2",),
    ("stations",),
    ("launch", "validation", "cli", "console"),
)
HARNESS = FLOORS[-1]
FLOOR_OF = {room: i for i, rooms in enumerate(FLOORS) for room in rooms}
ONLY = {"stations": {"common", "scene"}}  # rooms that may import just these below them


def allowed(room: str, imported: str) -> bool:
    """May `room` import `imported`? Itself, any room on a floor below (of those in ONLY, for a
    room named there), or, in the harness, each other."""
    if room == imported or (room in HARNESS and imported in HARNESS):
        return True
    if room in ONLY:
        return imported in ONLY[room]
    return FLOOR_OF[imported] < FLOOR_OF[room]


def rooms_of_package() -> set[str]:
    """The top-level rooms pyproject.toml's `packages` names (abyss.<room>...)."""
    packages = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    return {name.split(".")[1] for name in packages if name.count(".") >= 1}


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(("abyss", *(parts[:-1] if parts[-1] == "__init__" else parts)))


def imported_modules(path: Path, root: Path = ROOT) -> list[tuple[int, str]]:
    """(line, abyss module) of every import in the file, wherever it stands."""
    tree = ast.parse(path.read_text(), filename=str(path))
    name = module_name(path, root)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the file's package, up level - 1
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                module = ".".join([*base, *([node.module] if node.module else [])])
            else:
                module = node.module or ""
            if module == "abyss":  # from abyss import linkemu
                found += [(node.lineno, f"abyss.{alias.name}") for alias in node.names]
            else:
                found.append((node.lineno, module))
    return [(line, name) for line, name in found if name.startswith("abyss.")]


def package_files() -> list[Path]:
    return sorted(p for room in FLOOR_OF if (ROOT / room).is_dir() for p in (ROOT / room).rglob("*.py"))


def upward_imports(files: list[Path], root: Path = ROOT) -> list[str]:
    """`file:line: room imports module` for each import of a room the file's room may not import."""
    wrong = []
    for path in files:
        room = path.relative_to(root).parts[0]
        for line, name in imported_modules(path, root):
            imported = name.split(".")[1]
            if imported in FLOOR_OF and not allowed(room, imported):
                wrong.append(f"{path.relative_to(root)}:{line}: {room} imports {name}")
    return wrong


def test_every_room_of_the_package_has_a_floor() -> None:
    assert rooms_of_package() <= set(FLOOR_OF), rooms_of_package() - set(FLOOR_OF)
    assert len(package_files()) > 100  # the walk found the package


def test_no_room_imports_upwards() -> None:
    assert upward_imports(package_files()) == []


def test_an_upward_import_is_found(tmp_path: Path) -> None:
    """The check itself: an import of a room above, in each form, inside a function too, is found."""
    (tmp_path / "common").mkdir()
    sample = tmp_path / "common" / "upward.py"
    sample.write_text(
        textwrap.dedent(
            """
            import abyss.stations.runtime
            from abyss.linkemu.link import Link
            from abyss import launch

            def inner() -> None:
                from abyss.validation.tcpcheck import workload
                from ..scene import stream
                from . import keys
            """
        )
    )
    wrong = upward_imports([sample], tmp_path)
    assert [w.split(": ", 1)[1] for w in wrong] == [
        "common imports abyss.stations.runtime",
        "common imports abyss.linkemu.link",
        "common imports abyss.launch",
        "common imports abyss.validation.tcpcheck",
        "common imports abyss.scene",
    ]
    assert not allowed("linkemu", "scene") and not allowed("scene", "linkemu")
    assert allowed("cli", "launch") and allowed("validation", "launch") and allowed("stations", "scene")
    assert not any(allowed("stations", testbed) for testbed in ("linkemu", "recording", "ros2", "launch"))


def test_the_system_under_test_importing_the_testbed_is_found(tmp_path: Path) -> None:
    """A station that imports the link emulator, the recording or ROS 2 is refused, as the shell
    that did (stations/runtime.py) was until it moved to the harness."""
    (tmp_path / "stations").mkdir()
    sample = tmp_path / "stations" / "shell.py"
    sample.write_text(
        "from abyss.linkemu import control\nimport abyss.recording.store\nfrom abyss import ros2\n"
    )
    assert [w.split(": ", 1)[1] for w in upward_imports([sample], tmp_path)] == [
        "stations imports abyss.linkemu",
        "stations imports abyss.recording.store",
        "stations imports abyss.ros2",
    ]


def test_every_module_imports() -> None:
    """Each module of the package (but `__main__`s), imported in a fresh interpreter (nothing cached
    by the tests): a module only some command imports cannot break unseen."""
    walk = pkgutil.walk_packages(abyss.__path__, "abyss.")
    names = [m.name for m in walk if not m.name.endswith(".__main__")]  # those run when imported
    assert len(names) > 100
    script = f"import importlib\nfor name in {names!r}:\n    importlib.import_module(name)\n"
    started_s = time.monotonic()
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr[-3000:]
    print(f"{len(names)} modules imported in {time.monotonic() - started_s:.1f} s")
