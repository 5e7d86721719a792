"""The wheel a user installs: one import package, `abyss`, holding every module, data file and
entry point of the repository's folders, and working from a virtual environment of its own.

pyproject.toml maps `abyss` to the repository root and lists its packages by hand; these tests
build the wheel and hold that list to the folders, so that a new package is not silently left
out of what users install (the editable install used for development never notices)."""

from __future__ import annotations

import configparser
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
WHEEL_NAME = "abyss-0.1.0-py3-none-any.whl"
PACKAGE_FOLDERS = (
    "cli",
    "common",
    "config",
    "console",
    "description",
    "interface",
    "launch",
    "linkemu",
    "stations",
    "timing",
    "validation",
)
# not copied for the build: what the build writes, caches, runs and environments
NOT_SOURCES = {
    ".git",
    ".venv",
    "build",
    "dist",
    "runs",
    "certs",
    "__pycache__",
    ".pytest_cache",
    ".ruff_cache",
    ".hypothesis",
    ".mypy_cache",
}

pytestmark = pytest.mark.timeout(300)


def _ignore(_folder: str, names: list[str]) -> set[str]:
    return {n for n in names if n in NOT_SOURCES or n.endswith((".egg-info", ".pyc"))}


def _repo_packages() -> list[Path]:
    """Every package folder of the repository (relative to it): the top-level folders that hold
    an `__init__.py`, and every folder under them that does."""
    top = [p.parent for p in ROOT.glob("*/__init__.py")]
    found = [Path(".")]
    for folder in top:
        found += [
            p.parent.relative_to(ROOT) for p in folder.rglob("__init__.py") if "__pycache__" not in p.parts
        ]
    return sorted(found)


def _in_wheel(relative: Path) -> str:
    """The name in the wheel of a repository file."""
    return (Path("abyss") / relative).as_posix()


def _clean_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}


@pytest.fixture(scope="module")
def build(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The wheel and what its build printed, built by pip from a copy of the working tree (a
    build in the tree itself writes build/ and abyss.egg-info there, and a stale build/lib can
    leak deleted modules into it).
    With build isolation: the development environment's setuptools (65.5, and no `wheel`)
    is older than the >=68 that [build-system] asks for, so --no-build-isolation fails there."""
    tmp = tmp_path_factory.mktemp("wheel")
    source = tmp / "source"
    shutil.copytree(ROOT, source, ignore=_ignore)
    out = tmp / "dist"
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(source)],
        capture_output=True,
        text=True,
        timeout=240,
        env=_clean_env(),
    )
    assert built.returncode == 0, built.stdout + built.stderr
    wheels = list(out.glob("*.whl"))
    assert [w.name for w in wheels] == [WHEEL_NAME], wheels
    return wheels[0], built.stdout + built.stderr


@pytest.fixture(scope="module")
def wheel(build: tuple[Path, str]) -> Path:
    return build[0]


def test_the_build_warns_of_nothing(build: tuple[Path, str]) -> None:
    """A data folder left out of `packages` (config/traces) makes setuptools print a screen of
    warning at every install, setup.sh's included."""
    _, output = build
    assert "warn" not in output.lower(), output


@pytest.fixture(scope="module")
def names(wheel: Path) -> set[str]:
    with zipfile.ZipFile(wheel) as z:
        return set(z.namelist())


def read(wheel: Path, name: str) -> str:
    with zipfile.ZipFile(wheel) as z:
        return z.read(name).decode()


def test_one_import_package_abyss(wheel: Path, names: set[str]) -> None:
    assert read(wheel, "abyss-0.1.0.dist-info/top_level.txt").split() == ["abyss"]
    dist_info = {n for n in names if n.startswith("abyss-0.1.0.dist-info/")}
    outside = sorted(n for n in names - dist_info if not n.startswith("abyss/"))
    assert not outside, f"files outside abyss/ in the wheel: {outside}"
    assert not [n for n in names if n.startswith(("abyss/tests/", "abyss/bench/"))]


def test_entry_points(wheel: Path) -> None:
    entry_points = configparser.ConfigParser()
    entry_points.read_string(read(wheel, "abyss-0.1.0.dist-info/entry_points.txt"))
    assert dict(entry_points["console_scripts"]) == {"abyss": "abyss.cli:main"}
    assert dict(entry_points["pytest11"]) == {"abyss": "abyss.validation.pytest_plugin"}


def test_every_package_and_module_of_the_repository_is_in_the_wheel(names: set[str]) -> None:
    packages = _repo_packages()
    tops = {p.parts[0] for p in packages if p.parts}
    assert tops >= set(PACKAGE_FOLDERS), tops  # the scan below sees the folders it should
    missing = [
        f"abyss.{'.'.join(p.parts)}".rstrip(".")
        for p in packages
        if _in_wheel(p / "__init__.py") not in names
    ]
    assert not missing, f"packages missing from the wheel (add them to pyproject.toml's packages): {missing}"
    # every module, also one in a folder without __init__.py that no package list would name
    modules = {ROOT / "__init__.py"} | {
        p for top in tops for p in (ROOT / top).rglob("*.py") if "__pycache__" not in p.parts
    }
    in_repo = {_in_wheel(p.relative_to(ROOT)) for p in modules}
    in_wheel = {n for n in names if n.endswith(".py")}
    assert in_repo - in_wheel == set(), "modules missing from the wheel"
    assert in_wheel - in_repo == set(), "modules in the wheel that the repository does not hold"


def test_package_data_is_in_the_wheel_byte_for_byte(wheel: Path, names: set[str]) -> None:
    models = [
        p
        for p in (ROOT / "description" / "models").rglob("*")
        if p.is_file() and p.suffix not in (".py", ".pyc")
    ]
    assert {p.name for p in models} >= {"robot.xml", "robot.toml", "site.xml", "site.toml", "terrain.bin"}
    data = [*models, ROOT / "config" / "profiles.toml", ROOT / "py.typed"]
    # nothing else in a package folder that is not Python: a new data file needs package-data
    for top in {p.parts[0] for p in _repo_packages() if p.parts}:
        data += [
            p
            for p in (ROOT / top).rglob("*")
            if p.is_file() and "__pycache__" not in p.parts and p.suffix not in (".py", ".pyc")
        ]
    with zipfile.ZipFile(wheel) as z:
        for path in sorted(set(data)):
            name = _in_wheel(path.relative_to(ROOT))
            assert name in names, f"{name} missing from the wheel (pyproject.toml's package-data)"
            assert z.read(name) == path.read_bytes(), name


def test_the_installed_wheel_runs_from_its_own_environment(wheel: Path, tmp_path: Path) -> None:
    """Installed without its dependencies into a fresh venv; the dependencies come from the
    development venv's site-packages through a plain path line in a .pth file, which adds the
    folder but runs none of its .pth files, so the editable install's finder (abyss ->
    this repository) is not loaded and every import of abyss must come from the wheel."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    installed = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(python),
            "install",
            "-q",
            "--no-deps",
            "--no-index",
            str(wheel),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        env=_clean_env(),
    )
    assert installed.returncode == 0, installed.stdout + installed.stderr
    site = Path(
        subprocess.run(
            [python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    )
    assert (site / "abyss" / "__init__.py").is_file()
    dev_site = [sysconfig.get_path("purelib"), sysconfig.get_path("platlib")]
    # pinocchio's packages live in cmeel's prefix, which cmeel.pth would have added
    dev_site += [
        str(
            Path(p)
            / "cmeel.prefix"
            / "lib"
            / f"python{sys.version_info[0]}.{sys.version_info[1]}"
            / "site-packages"
        )
        for p in dev_site
    ]
    lines = dict.fromkeys(p for p in dev_site if Path(p).is_dir())
    (site / "zz_abyss_dev_dependencies.pth").write_text("".join(f"{p}\n" for p in lines))

    cwd = tmp_path / "elsewhere"
    cwd.mkdir()
    env = _clean_env()
    keys = subprocess.run(
        [venv / "bin" / "abyss", "keys"], capture_output=True, text=True, cwd=cwd, env=env, timeout=120
    )
    assert keys.returncode == 0, keys.stderr
    assert "| `abyss/<system>/simulation/nav` | NavState |" in keys.stdout

    probe = (
        "import sys, abyss, abyss.stations.onboard, abyss.description.models as m, abyss.launch.up; "
        "print(abyss.__file__); print(abyss.stations.onboard.__file__); "
        "import abyss.description.robot as r; print(r.robot_at('').model_file); "
        "print(sorted(n for n in sys.modules if n.startswith('__editable__')))"
    )
    imported = subprocess.run(
        [python, "-c", probe], capture_output=True, text=True, cwd=cwd, env=env, timeout=120
    )
    assert imported.returncode == 0, imported.stderr
    package, onboard, robot, editable = imported.stdout.splitlines()
    assert Path(package) == site / "abyss" / "__init__.py", package
    assert Path(onboard) == site / "abyss" / "stations" / "onboard" / "__init__.py", onboard
    assert Path(robot).is_relative_to(site) and Path(robot).is_file(), robot
    assert editable == "[]", editable
