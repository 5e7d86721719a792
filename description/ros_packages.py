"""ROS packages without ROS, for robot packages written as ROS users write them (description/urdf.py):
a package found by its name (its package.xml's, or its directory's) as `$(find pkg)` and
`package://pkg/` find it: the robot package itself where `pkg` is its name, else `pkg` under a
directory of ABYSS_PACKAGE_PATH (`:`-separated, each holding packages as subdirectories, as
ROS_PACKAGE_PATH would); and xacro run with that `$(find)` (the xacro package's own resolves
through ROS 2's ament index, which is not there)."""

from __future__ import annotations

import os
import threading
import xml.etree.ElementTree as ET
from pathlib import Path

from abyss.common.errors import ConfigError

PACKAGE_PATH_ENV = "ABYSS_PACKAGE_PATH"  # directories of ROS packages, `:`-separated


def package_name(directory: Path) -> str:
    """A ROS package's name: its package.xml's <name>, else its directory's."""
    manifest = directory / "package.xml"
    if manifest.is_file():
        try:
            name = ET.parse(manifest).findtext("name")
        except ET.ParseError:
            name = None
        if name and name.strip():
            return name.strip()
    return directory.name


def search_path() -> tuple[Path, ...]:
    """The directories of ROS packages that ABYSS_PACKAGE_PATH names, in order."""
    return tuple(Path(p).expanduser() for p in os.environ.get(PACKAGE_PATH_ENV, "").split(":") if p)


def find_package(name: str, own: Path) -> Path | None:
    """The directory of ROS package `name`: the robot package `own` where it is its name, else
    the first `<dir>/<name>` (or a subdirectory whose package.xml says `name`) of the search path."""
    if name == package_name(own):
        return own
    for directory in search_path():
        if (directory / name).is_dir():
            return (directory / name).resolve()
        found = [d for d in sorted(directory.glob("*/package.xml")) if package_name(d.parent) == name]
        if found:
            return found[0].parent.resolve()
    return None


def missing_package(name: str, own: Path) -> str:
    where = ", ".join(map(str, search_path())) or f"nothing: {PACKAGE_PATH_ENV} is unset"
    return (
        f"no ROS package {name!r}: not the robot package's own ({package_name(own)!r}), nor under "
        f"{PACKAGE_PATH_ENV} ({where})"
    )


class _NoPackage(Exception):
    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.name = name


_XACRO_LOCK = threading.Lock()  # xacro keeps its state (args, file stack, `find`) in globals


def xacro_text(model_file: Path, args: dict[str, str], own: Path, path: Path) -> str:
    """The URDF that xacro makes of `model_file` with `args`, `$(find pkg)` resolved by
    find_package; ConfigError naming robot.toml's model.file (or model.xacro_args) for one it
    cannot make."""
    import xacro
    from xacro import substitution_args

    def find(name: str) -> str:
        found = find_package(name, own)
        if found is None:
            raise _NoPackage(name)
        return str(found)

    with _XACRO_LOCK:
        saved = substitution_args._eval_find, substitution_args._eval_dict["find"]
        substitution_args._eval_find = substitution_args._eval_dict["find"] = find
        try:
            return str(xacro.process_file(str(model_file), mappings=dict(args)).toxml())
        except Exception as exc:  # xacro's errors are of many kinds, its own wrapping others
            raise _xacro_error(exc, model_file, own, path) from None
        finally:
            substitution_args._eval_find, substitution_args._eval_dict["find"] = saved


def _xacro_error(exc: Exception, model_file: Path, own: Path, path: Path) -> ConfigError:
    from xacro.substitution_args import ArgException

    chain: list[BaseException] = []
    cause: BaseException | None = exc
    while cause is not None and cause not in chain:
        chain.append(cause)
        cause = getattr(cause, "exc", None) or cause.__cause__ or cause.__context__
    for e in chain:
        if isinstance(e, _NoPackage):
            return ConfigError(
                "model.file", f"{model_file}: $(find {e.name}): {missing_package(e.name, own)}", str(path)
            )
        if isinstance(e, ArgException):
            return ConfigError(
                "model.xacro_args", f"{model_file} needs xacro argument {e}: give it in xacro_args", str(path)
            )
    return ConfigError("model.file", f"xacro cannot expand {model_file}: {exc}", str(path))
