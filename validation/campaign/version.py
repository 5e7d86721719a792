"""The abyss a campaign's runs were made with: the package's version and a digest of its
sources, so that results of different code never mix (a run's id hashes it) and a Ray node
running other code is refused."""

from __future__ import annotations

import functools
import hashlib
from importlib import metadata
from pathlib import Path

import abyss

SOURCE_SUFFIXES = (".py", ".toml", ".xml")
NOT_PACKAGED = {"pyproject.toml"}  # at the root of a checkout, not in the wheel


def _package_files(root: Path) -> list[Path]:
    """The package's source files: those in `root` and in every folder under it that is a package
    (holds an `__init__.py`), as the wheel has them; tests, benchmarks and environments are not."""
    files: list[Path] = []
    folders = [root]
    while folders:
        folder = folders.pop()
        for path in sorted(folder.iterdir()):
            if path.is_dir() and (path / "__init__.py").exists():
                folders.append(path)
            elif path.is_file() and path.suffix in SOURCE_SUFFIXES and path.name not in NOT_PACKAGED:
                files.append(path)
    return sorted(files)


@functools.cache
def abyss_version() -> str:
    """`<package version>+<the first 12 hex digits of a SHA-256 of the package's .py, .toml and
    .xml sources (their paths and contents)>`."""
    root = Path(abyss.__file__).resolve().parent
    digest = hashlib.sha256()
    for path in _package_files(root):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    try:
        version = metadata.version("abyss")
    except metadata.PackageNotFoundError:
        version = "0"
    return f"{version}+{digest.hexdigest()[:12]}"
