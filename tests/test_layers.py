"""The rooms of the package import only downwards (issues 37 and 61), lowest first:

    common  <-  description  <-  interface  <-  timing, security, config  <-  bus
            <-  linkemu, scene, mavlink  <-  recording  <-  ros2  <-  stations  <-  harness

`common` is what is small and generic (errors, units, geometry, the typed reader, ports);
`description` the robot and the site as data; `interface` what stations say to each other (keys,
messages and their codec, quality of service, the fault table); `timing` the clocks, rates and
lockstep; `security` certificates and access rules; `config` the typed configuration; `bus` the
session every station talks through; `mavlink` the vehicle as a MAVLink system and the ground
stations' endpoints; the harness is launch, validation, cli and console. A room
may import itself and any room below it, never one above it nor a sibling on its own floor
(linkemu, scene and mavlink know nothing of each other, nor timing, security and config); the harness's
rooms may import each other. The system under test sees nothing of the testbed (issue 50):
`stations` never imports the link emulator, the recording or ROS 2; the shell that hosts a station
among them is the harness's (launch.station).

And no circle of files anywhere in the house: no module imports, through others, a module that
imports it (a package's `__init__` counts as a file: one that gathers its modules may not be
imported by them).

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
    ("description",),
    ("interface",),
    ("timing", "security", "config"),
    ("bus",),
    ("linkemu", "scene", "mavlink"),
    ("recording",),
    ("ros2",),
    ("stations",),
    ("launch", "validation", "cli", "console"),
)
HARNESS = FLOORS[-1]
FLOOR_OF = {room: i for i, rooms in enumerate(FLOORS) for room in rooms}
TESTBED = ("linkemu", "recording", "ros2")
# rooms that may import just these below them: the system under test, nothing of the testbed
ONLY = {
    "stations": {room for rooms in FLOORS[: FLOORS.index(("stations",))] for room in rooms} - set(TESTBED)
}


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


def imported_modules(
    path: Path, root: Path = ROOT, modules: frozenset[str] = frozenset()
) -> list[tuple[int, str]]:
    """(line, abyss module) of every import in the file, wherever it stands; `from package import
    name` is the module `package.name` where that is one of `modules`."""
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
            for alias in node.names:  # from abyss import linkemu; from abyss.interface import keys
                named = f"{module}.{alias.name}"
                found.append((node.lineno, named if module == "abyss" or named in modules else module))
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


def module_graph(files: list[Path], root: Path = ROOT) -> dict[str, set[str]]:
    """Each module of `files` and the modules of `files` it imports."""
    names = frozenset(module_name(p, root) for p in files)
    return {
        module_name(p, root): {m for _, m in imported_modules(p, root, names) if m in names}
        - {module_name(p, root)}
        for p in files
    }


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The circles of `graph`: each set of two or more modules that reach one another through their
    imports (its strongly connected components, Tarjan's walk), sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for nxt in sorted(graph[node]):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return sorted(found)


def test_no_circle_of_files() -> None:
    assert circles(module_graph(package_files())) == []


def test_a_circle_of_files_is_found(tmp_path: Path) -> None:
    """The check itself: two files that import each other (one inside a function, through its
    package), three round a ring, and a package's face that its module imports back."""
    files = {
        "common/a.py": "import abyss.common.b\n",
        "common/b.py": "def later() -> None:\n    from abyss.common import a\n",
        "common/c.py": "from abyss.common.d import x\n",
        "common/d.py": "from .e import y\n",
        "common/e.py": "from abyss.common.c import z\n",
        "common/f.py": "from abyss.common import errors\n",  # a package, not a circle: not found
        "common/errors.py": "",
        "bus/__init__.py": "from abyss.bus.session import Session\n",
        "bus/session.py": "from abyss.bus import HOPS\n",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text(text)
    (tmp_path / "common" / "__init__.py").write_text("")
    found = circles(module_graph(sorted(tmp_path.rglob("*.py")), tmp_path))
    assert found == [
        ["abyss.bus", "abyss.bus.session"],
        ["abyss.common.a", "abyss.common.b"],
        ["abyss.common.c", "abyss.common.d", "abyss.common.e"],
    ]


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
