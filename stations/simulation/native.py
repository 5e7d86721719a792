"""The physics in C (native_physics.c, which setup.sh, or the image's build stage, compiles into
the environment: .venv/lib/abyss/libabyss_physics.so; `build`):
- `Marine`: the hull's Fossen terms and the arm's added mass, put into MuJoCo's step by its control
  callback, so that a whole low-level period of steps is one `mj_step(nstep=...)` with no Python
  between them. The same equations in the same order as the Python path (Fossen._apply_diagonal,
  ArmStrips.add_mass), so the two step bit for bit alike;
- `LowLevel`: the dynamic low level (the controllers, the thrusters, the arm's strip model) as one
  call per control period, alike to the Python's to rounding.
tests/stations/simulation/test_native_physics.py holds both. Where the library is not built (no
compiler), `Marine.of` and `LowLevel.of` are None and World runs it all in Python."""

from __future__ import annotations

import ctypes
import functools
import logging
import subprocess
import sys
import weakref
from pathlib import Path

import mujoco
import numpy as np

from abyss.description.robot import COMMANDED_AXES
from abyss.interface.messages.schema import MAX_ARM_JOINTS
from abyss.stations.simulation.attitude import ROLL
from abyss.stations.simulation.hydrodynamics import Fossen
from abyss.stations.simulation.lowlevel import Dynamic, References
from abyss.stations.simulation.strips import ArmStrips

ABI = 2  # native_physics.c's abyss_physics_abi: its structs' layout (2: any arm, the attitude hold)
LIBRARY = Path(sys.prefix) / "lib" / "abyss" / "libabyss_physics.so"  # a build output, not a module
log = logging.getLogger(__name__)
_double6 = ctypes.c_double * 6


class _Terms(ctypes.Structure):
    """native_physics.c's AbyssMarine, field for field under C's names (`links`, `link_entries`,
    `link_values`: the arm's strip model's inertia entries, their count and values)."""

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


_double4, _double2, _int2 = ctypes.c_double * 4, ctypes.c_double * 2, ctypes.c_int * 2
_arm_ints, _arm_doubles = ctypes.c_int * MAX_ARM_JOINTS, ctypes.c_double * MAX_ARM_JOINTS  # C's ABYSS_ARM_MAX
_pointer = ctypes.c_void_p


class _LowLevelTerms(ctypes.Structure):
    """native_physics.c's AbyssLowLevel, field for field under C's names (`links`: the strip
    model's bodies, the arm's links; `strips` its strips)."""

    _fields_ = (
        ("qpos", ctypes.c_int),
        ("qvel", ctypes.c_int),
        ("kp", _double4),
        ("ki", _double4),
        ("kd", _double4),
        ("linear", _double4),
        ("quadratic", _double4),
        ("integral", _pointer),
        ("error", _pointer),
        ("thrusters", ctypes.c_int),
        ("rows", ctypes.c_int),
        ("actuators", _pointer),
        ("pinv", _pointer),
        ("allocation", _pointer),
        ("held", _int2),
        ("attitude_kp", _double2),
        ("attitude_kd", _double2),
        ("forward_max_n", ctypes.c_double),
        ("reverse_max_n", ctypes.c_double),
        ("deadband", ctypes.c_double),
        ("time_constant_s", ctypes.c_double),
        ("efficiency", _pointer),
        ("rotor_speed", _pointer),
        ("arm_joints", ctypes.c_int),
        ("arm_dofs", _arm_ints),
        ("arm_motors", _arm_ints),
        ("grippers", ctypes.c_int),
        ("gripper_motors", _int2),
        ("arm_kp", ctypes.c_double),
        ("arm_ki", ctypes.c_double),
        ("arm_force_limit", _arm_doubles),
        ("arm_integral", _pointer),
        ("references", _pointer),
        ("current_mps_world", _pointer),
        ("links", ctypes.c_int),
        ("strips", ctypes.c_int),
        ("dofs", ctypes.c_int),
        ("root", ctypes.c_int),
        ("added_inertia", ctypes.c_int),
        ("entries", ctypes.c_int),
        ("bodies", _pointer),
        ("owner", _pointer),
        ("dof", _pointer),
        ("flat", _pointer),
        ("q", _pointer),
        ("drag", _pointer),
        ("kirchhoff", _pointer),
        ("buoyancy", _pointer),
        ("added_mass", _pointer),
        ("mask", _pointer),
        ("jacobian", _pointer),
        ("mass_q", _pointer),
        ("values", _pointer),
    )


def build(out: Path = LIBRARY, compiler: str = "cc") -> Path:
    """Compile native_physics.c against this environment's MuJoCo (its wheel's headers and library)
    into `out`, floating-point contraction off so that the per-step terms are Python's bit for bit:
    setup.sh and the image's build stage run it (`python -m abyss.stations.simulation.native`)."""
    mujoco_dir = Path(mujoco.__file__).parent
    shared = sorted(mujoco_dir.glob("libmujoco.so.*"))
    if not shared:
        raise FileNotFoundError(f"no libmujoco.so.* in {mujoco_dir}")
    out.parent.mkdir(parents=True, exist_ok=True)
    source = Path(__file__).with_name("native_physics.c")
    flags = ["-O2", "-fPIC", "-shared", "-ffp-contract=off", f"-I{mujoco_dir / 'include'}"]
    link = [f"-L{mujoco_dir}", f"-l:{shared[0].name}", f"-Wl,-rpath,{mujoco_dir}"]
    subprocess.run([compiler, *flags, str(source), *link, "-o", str(out)], check=True)
    return out


@functools.cache
def library() -> ctypes.CDLL | None:
    """native_physics.c's library, its callback installed as MuJoCo's control callback; None if not built."""
    if not LIBRARY.is_file():
        log.info("%s not built (setup.sh builds it): the physics runs in Python", LIBRARY.name)
        return None
    try:
        lib = ctypes.CDLL(str(LIBRARY))
        low_level = lib.abyss_low_level
        abi = lib.abyss_physics_abi()
        if abi != ABI:  # the structs' layout changed: read with the wrong one, a run crashed
            raise AttributeError(f"its structs' layout is {abi}, this source's {ABI}")
    except (OSError, AttributeError) as exc:  # built against another MuJoCo, or from another source
        log.warning("%s does not load (%s): the physics runs in Python; run setup.sh", LIBRARY.name, exc)
        return None
    lib.abyss_marine_register.argtypes = [ctypes.POINTER(_Terms)]
    lib.abyss_marine_register.restype = ctypes.c_int
    lib.abyss_marine_unregister.argtypes = [ctypes.c_int]
    low_level.argtypes = [ctypes.POINTER(_LowLevelTerms), ctypes.c_void_p]
    low_level.restype = None
    if mujoco.get_mjcb_control() is not None:
        raise RuntimeError("MuJoCo's control callback is taken: the marine terms need it")
    mujoco.set_mjcb_control(lib.abyss_marine_control)
    return lib


class Marine:
    """One World's marine terms in C: `step` runs `nstep` physics steps with them."""

    @staticmethod
    def of(data: mujoco.MjData, fossen: Fossen | None, strips: ArmStrips | None) -> Marine | None:
        """For these terms, or None where C does not have them (the library not built; a hull
        with a full added-mass matrix, which steps in Python)."""
        lib = library()
        if lib is None or fossen is None or fossen.diagonal is None:
            return None
        return Marine(lib, data, fossen, strips)

    def __init__(
        self, lib: ctypes.CDLL, data: mujoco.MjData, fossen: Fossen, strips: ArmStrips | None
    ) -> None:
        assert fossen.diagonal is not None
        self.current_mps_world = np.zeros(3)  # held here: C reads it through its pointer
        self._strip_entries = np.ascontiguousarray(strips.entries if strips else [], dtype=np.int32)
        # the strip model's own array, which its low level (Python's or C's) updates in place
        self._strip_values = strips.values if strips else np.zeros(0)
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
            links=len(self._strip_entries),
            link_entries=self._strip_entries.ctypes.data,
            link_values=self._strip_values.ctypes.data,
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
        self._terms.active = 1
        try:
            mujoco.mj_step(model, self._data, nstep=nstep)
        finally:
            self._terms.active = 0


class LowLevel:
    """One World's dynamic low level in C (native_physics.c's abyss_low_level): the controllers,
    the thrusters and the arm's strip model, once per control period, in one call. The Python's
    equations (lowlevel.Dynamic.apply, ArmStrips.apply) summed in C's order rather than numpy's BLAS's:
    alike to rounding, not bit for bit (tests/stations/simulation/test_native_physics.py). The
    state both keep (the integrals, the rotors, the faults' efficiencies, the strips' inertia
    entries) is the Python objects' own arrays, so either path can take over from the other."""

    LIMIT = 64  # thrusters, and dofs that move the arm's links: C's scratch
    FINGERS = 2  # C's struct's gripper

    @staticmethod
    def of(controller: object, strips: ArmStrips | None) -> LowLevel | None:
        """For this controller and this strip model, or None where C does not have them (the library
        not built; the kinematic low level; no strip model; more than LIMIT thrusters or dofs; a
        gripper of more than FINGERS, or thrusters that do not move surge, sway, heave and yaw)."""
        lib = library()
        if lib is None or not isinstance(controller, Dynamic) or strips is None:
            return None
        if len(controller.thrusters.actuators) > LowLevel.LIMIT or len(strips.dofs) > LowLevel.LIMIT:
            return None
        plant = controller.plant
        if (  # C's struct: two fingers at most, thrust in surge, sway, heave and yaw (and any of
            # roll and pitch the attitude hold adds: stations/simulation/attitude.py)
            len(plant.arm_dofs) > MAX_ARM_JOINTS
            or len(plant.gripper_dofs) > LowLevel.FINGERS
            or tuple(controller.thrusters.actuated) != COMMANDED_AXES
        ):
            return None
        return LowLevel(lib, controller, strips)

    def __init__(self, lib: ctypes.CDLL, controller: Dynamic, strips: ArmStrips) -> None:
        # vehicle 4, gripper, the period [s], then the arm's joints
        self.references = np.zeros(6 + len(controller.plant.arm_dofs))
        self.current_mps_world = np.zeros(3)
        self.jacobian = np.zeros((len(strips.bodies), 6, len(strips.dofs)))
        self.mass_q = np.zeros((len(strips.dofs), len(strips.dofs)))
        self._held = self._held_arrays(controller, strips)
        self._terms = self._low_level_terms(controller, strips)
        self._call = functools.partial(lib.abyss_low_level, ctypes.byref(self._terms))

    def _held_arrays(self, controller: Dynamic, strips: ArmStrips) -> dict[str, np.ndarray]:
        """The arrays C reads or writes through its pointers, by their field's name, kept alive here:
        the controller's and the thrusters' state, the strip model's tables and its inertia entries."""
        thrusters, attitude = controller.thrusters, controller.attitude
        rows = attitude if attitude.held else None  # the allocation through the hold's rows too

        def ints(values: object) -> np.ndarray:
            return np.ascontiguousarray(values, dtype=np.int32)

        held = {
            "integral": controller.vehicle_integral,
            "error": controller.vehicle_error,
            "actuators": ints(thrusters.actuators),
            "pinv": np.ascontiguousarray(rows.pseudo_inverse if rows else thrusters.pseudo_inverse),
            "allocation": np.ascontiguousarray(rows.allocation if rows else thrusters.actuated_allocation),
            "efficiency": thrusters.efficiency,
            "rotor_speed": thrusters.rotor_speed,
            "arm_integral": controller.arm_integral,
            "references": self.references,
            "current_mps_world": self.current_mps_world,
            "bodies": ints(strips.bodies),
            "owner": ints(strips.owner),
            "dof": ints(strips.dofs),
            "flat": ints(strips.flat),
            **strips.tables(),
            "jacobian": self.jacobian,
            "mass_q": self.mass_q,
            "values": strips.values,
        }
        for name, array in held.items():
            if not (array.flags.c_contiguous and array.dtype in (np.float64, np.int32)):
                raise TypeError(f"{name}: C takes contiguous float64 or int32 arrays")
        return held

    def _low_level_terms(self, controller: Dynamic, strips: ArmStrips) -> _LowLevelTerms:
        """C's struct: the gains, the thrusters' spec, the arm's dofs and motors, the strip model's
        sizes, and the held arrays' addresses."""
        plant, gains, thrusters, attitude = (
            controller.plant,
            controller.gains,
            controller.thrusters,
            controller.attitude,
        )
        spec = thrusters.spec
        held = [axis - ROLL for axis in attitude.held]
        linear, quadratic = controller.damping
        return _LowLevelTerms(
            qpos=plant.qpos,
            qvel=plant.qvel,
            kp=_double4(*gains.vehicle_kp),
            ki=_double4(*gains.vehicle_ki),
            kd=_double4(*gains.vehicle_kd),
            linear=_double4(*linear),
            quadratic=_double4(*quadratic),
            thrusters=len(thrusters.actuators),
            rows=len(COMMANDED_AXES) + len(held),
            held=_int2(*held),
            attitude_kp=_double2(*attitude.kp),
            attitude_kd=_double2(*attitude.kd),
            forward_max_n=spec.forward_max_n,
            reverse_max_n=spec.reverse_max_n,
            deadband=spec.deadband,
            time_constant_s=spec.time_constant_s,
            arm_joints=len(plant.arm_dofs),
            arm_dofs=_arm_ints(*plant.arm_dofs),
            arm_motors=_arm_ints(*plant.arm_motors),
            grippers=len(plant.gripper_motors),
            gripper_motors=_int2(*plant.gripper_motors),
            arm_kp=gains.arm_kp,
            arm_ki=gains.arm_ki,
            arm_force_limit=_arm_doubles(*controller.arm_force_limit),
            links=len(strips.bodies),
            strips=strips.strip_count,
            dofs=len(strips.dofs),
            root=strips.root,
            added_inertia=int(strips.added_inertia),
            entries=len(strips.entries),
            **{name: array.ctypes.data for name, array in self._held.items()},
        )

    def apply(
        self,
        data: mujoco.MjData,
        refs: References,
        current_mps_world: np.ndarray,
        period_s: float,
    ) -> None:
        """The controllers' outputs and the arm's forces for the next `period_s` [s], from the
        current kinematics (as lowlevel.Dynamic.apply, then ArmStrips.apply, do)."""
        r = self.references
        r[:4] = refs.vehicle_body
        r[4] = refs.gripper_mps
        r[5] = period_s
        r[6:] = refs.arm_radps
        self.current_mps_world[:] = current_mps_world
        self._call(data._address)


if __name__ == "__main__":
    print(f"built {build()}")
