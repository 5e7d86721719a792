"""The physics step's marine terms in C (native_marine.c, which setup.sh compiles into the
environment: .venv/lib/abyss/libabyss_marine.so): the hull's Fossen terms and the arm's added
mass, put into MuJoCo's step by its control callback, so that a whole low-level period of steps
is one `mj_step(nstep=...)` with no Python between them. The same equations in the same order as
the Python path (Fossen._apply_diagonal, Links.add_mass), so the two step bit for bit alike
(tests/stations/simulation/test_native_marine.py holds it). Where the library is not built (an
image without a compiler), `Marine.of` is None and World steps in Python."""

from __future__ import annotations

import ctypes
import functools
import logging
import sys
import weakref
from pathlib import Path

import mujoco
import numpy as np

from abyss.stations.simulation.hydrodynamics import Fossen
from abyss.stations.simulation.links import Links

LIBRARY = Path(sys.prefix) / "lib" / "abyss" / "libabyss_marine.so"  # a build output, not a module
log = logging.getLogger(__name__)
_double6 = ctypes.c_double * 6


class _Terms(ctypes.Structure):
    """native_marine.c's AbyssMarine."""

    _fields_ = (
        ("data", ctypes.c_void_p),
        ("active", ctypes.c_int),
        ("body", ctypes.c_int),
        ("dof", ctypes.c_int),
        ("added_mass", _double6),
        ("linear", _double6),
        ("quadratic", _double6),
        ("buoyancy_n", ctypes.c_double),
        ("centre_of_buoyancy_m_body", ctypes.c_double * 3),
        ("hull_entries", ctypes.c_int * 9),
        ("current_mps_world", ctypes.c_void_p),
        ("links", ctypes.c_int),
        ("link_entries", ctypes.c_void_p),
        ("link_values", ctypes.c_void_p),
    )


@functools.cache
def library() -> ctypes.CDLL | None:
    """native_marine.c's library, its callback installed as MuJoCo's control callback; None if not built."""
    if not LIBRARY.is_file():
        log.info("%s not built (setup.sh builds it): the marine terms step in Python", LIBRARY.name)
        return None
    try:
        lib = ctypes.CDLL(str(LIBRARY))
    except OSError as exc:  # built against another MuJoCo than this environment's
        log.warning("%s does not load (%s): the marine terms step in Python; run setup.sh", LIBRARY.name, exc)
        return None
    lib.abyss_marine_register.argtypes = [ctypes.POINTER(_Terms)]
    lib.abyss_marine_register.restype = ctypes.c_int
    lib.abyss_marine_unregister.argtypes = [ctypes.c_int]
    if mujoco.get_mjcb_control() is not None:
        raise RuntimeError("MuJoCo's control callback is taken: the marine terms need it")
    mujoco.set_mjcb_control(lib.abyss_marine_control)
    return lib


class Marine:
    """One World's marine terms in C: `step` runs `nstep` physics steps with them."""

    @staticmethod
    def of(data: mujoco.MjData, fossen: Fossen | None, links: Links | None) -> Marine | None:
        """For these terms, or None where C does not have them (the library not built; a hull
        with a full added-mass matrix, which steps in Python)."""
        lib = library()
        if lib is None or fossen is None or fossen.diagonal is None:
            return None
        return Marine(lib, data, fossen, links)

    def __init__(self, lib: ctypes.CDLL, data: mujoco.MjData, fossen: Fossen, links: Links | None) -> None:
        assert fossen.diagonal is not None
        self.links = links
        self.current_mps_world = np.zeros(3)  # held here: C reads it through its pointer
        self._link_entries = np.ascontiguousarray(links.entries if links else [], dtype=np.int32)
        self._link_values = np.zeros(len(self._link_entries))
        linear, quadratic = fossen.damping
        terms = self._terms = _Terms(
            data=data._address,
            body=fossen.body,
            dof=fossen.dof,
            added_mass=_double6(*fossen.diagonal),
            linear=_double6(*linear),
            quadratic=_double6(*quadratic),
            buoyancy_n=fossen.buoyancy_n,
            centre_of_buoyancy_m_body=(ctypes.c_double * 3)(*fossen.centre_of_buoyancy_m_body),
            hull_entries=(ctypes.c_int * 9)(*fossen.diagonal_entries),
            current_mps_world=self.current_mps_world.ctypes.data,
            links=len(self._link_entries),
            link_entries=self._link_entries.ctypes.data,
            link_values=self._link_values.ctypes.data,
        )
        slot = lib.abyss_marine_register(ctypes.byref(terms))
        if slot < 0:
            raise RuntimeError("too many worlds with marine terms in one process")
        weakref.finalize(self, lib.abyss_marine_unregister, slot)  # before its terms go
        self._data = data  # kept alive while registered

    def step(self, model: mujoco.MjModel, current_mps_world: np.ndarray, nstep: int) -> None:
        """`nstep` physics steps with the current and the arm's added mass held, as the low level
        last set them."""
        self.current_mps_world[:] = current_mps_world
        if self.links is not None:
            self._link_values[:] = self.links.values
        self._terms.active = 1
        try:
            mujoco.mj_step(model, self._data, nstep=nstep)
        finally:
            self._terms.active = 0
