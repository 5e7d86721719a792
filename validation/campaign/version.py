"""Which abyss this is, exactly: the package's version and a digest of its sources and models.
A campaign's run ids contain it (results of different code never mix) and every Ray node must
report the driver's (a node running other code is refused, naming both)."""

from __future__ import annotations

import functools
import hashlib
from importlib import metadata
from pathlib import Path

import abyss

SOURCES = (".py", ".toml", ".xml")  # code, configuration and the models: what a run depends on


@functools.cache
def abyss_version() -> str:
    """`<package version>+<12 hex digits of the sources' SHA-256>`: the same for an editable
    checkout and a wheel built from it."""
    root = Path(abyss.__file__).resolve().parent
    packages = [root, *(d for d in sorted(root.iterdir()) if (d / "__init__.py").is_file())]
    digest = hashlib.sha256()
    for package in packages:
        files = package.glob("*.py") if package == root else package.rglob("*")  # not pyproject.toml
        for path in sorted(files):
            if path.suffix in SOURCES and path.is_file() and "__pycache__" not in path.parts:
                digest.update(path.relative_to(root).as_posix().encode() + b"\0")
                digest.update(path.read_bytes() + b"\0")
    try:
        release = metadata.version("abyss")
    except metadata.PackageNotFoundError:
        release = "0+unknown"
    return f"{release}+{digest.hexdigest()[:12]}"
