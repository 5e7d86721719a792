"""Typed configuration: frozen dataclasses loaded from TOML (or the JSON that `abyss up`
hands its stations), overridable from the command line with `--set section.field=value`.
Every error names the file, the field and what is allowed."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from abyss.common import keys
from abyss.common.errors import ConfigError
from abyss.common.geometry import quat_wxyz_of, rotation_of_rpy
from abyss.common.linkprofile import LinkProfile, load_profiles, profile
from abyss.common.messages import CLOUD_SOURCES
from abyss.common.models import panel


@dataclass(frozen=True)
class LinksConfig:
    """Profile name per hop, from common/profiles.toml."""

    rov: str = "ideal"
    tether: str = "tether"
    satellite: str = "satellite"

    def __post_init__(self) -> None:
        available = load_profiles()
        for hop in keys.HOPS:
            name = getattr(self, hop)
            if name not in available:
                raise ConfigError(
                    f"links.{hop}", f"unknown profile {name!r}; allowed: {', '.join(sorted(available))}"
                )

    def profiles(self) -> dict[str, LinkProfile]:
        return {hop: profile(getattr(self, hop)) for hop in keys.HOPS}


LOW_LEVELS = ("kinematic", "dynamic")
WATER_TYPES = ("none", "I", "IA", "IB", "II", "III", "1C", "3C", "5C", "7C", "9C")  # optics.WATER_TYPES
HYDRODYNAMICS = ("fossen", "ellipsoid")


@dataclass(frozen=True)
class SimulationConfig:
    low_level: str = "dynamic"  # kinematic | dynamic
    physics_step_s: float = 0.002  # [s]
    low_level_period_s: float = 0.01  # [s] the low-level controllers' (and buoyancy's) update
    control_period_s: float = 0.05  # [s] rate of nav output and command intake
    command_timeout_s: float = 0.5  # [s] older commands make the low level hold still
    start_position_m_world: tuple[float, float, float] = (0.0, 0.0, -7.0)
    start_yaw_rad: float = 0.0
    # dynamic low level: PID on surge, sway, heave [N/(m/s)] and yaw rate [N m/(rad/s)]
    # (the damping is fed forward from the vehicle file; yaw's integral is slow so that the rotors'
    # lag does not wind it up into an overshoot)
    vehicle_kp: tuple[float, float, float, float] = (6000.0, 6000.0, 6000.0, 5000.0)
    vehicle_ki: tuple[float, float, float, float] = (1500.0, 1500.0, 1500.0, 600.0)
    vehicle_kd: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    arm_kp: float = 400.0  # [N m/(rad/s)]
    arm_ki: float = 200.0
    gripper_kp: float = 1000.0  # [N/(m/s)]
    # the vehicle's marine model: "fossen" (the vehicle file's coefficients) or "ellipsoid"
    # (MuJoCo's fluid model of its hull's geoms); the vehicle file also describes its thrusters
    hydrodynamics: str = "fossen"
    vehicle_file: str = ""  # "" is robot.xml's own, common/models/robot.toml
    # the current: a profile of rows (z [m, world], vx, vy, vz [m/s, world]), linear in between and
    # held beyond its ends, plus a first-order Gauss-Markov process on each horizontal component
    current_profile: tuple[tuple[float, float, float, float], ...] = ()
    current_sigma_mps: float = 0.0  # [m/s] the process's standard deviation
    current_time_constant_s: float = 60.0  # [s] its correlation time
    usbl_sigma_m: float = 0.02  # [m] a short-range USBL: 0.2 % of a 10 m slant range
    dvl_sigma_mps: float = 0.005
    imu_sigma_rad: float = 0.002
    # navigation sensors as real ones are (stations/simulation/navigation.py)
    pressure_sigma_pa: float = 100.0  # the depth sensor's noise [Pa]: 1 cm of sea water
    usbl_rate_hz: float = 1.0  # fixes taken [Hz]
    usbl_processing_s: float = 0.3  # [s] a fix is delivered this long after its ping came back
    usbl_transceiver_m_world: tuple[float, float, float] = (0.0, 0.0, 0.0)  # on the vessel, at the surface
    usbl_outlier_probability: float = 0.02  # a fix this often lands usbl_outlier_m off
    usbl_outlier_m: float = 3.0  # [m]
    usbl_dropout_probability: float = 0.05  # a fix this often never comes
    dvl_min_altitude_m: float = 0.3  # [m] bottom lock needs the seabed this far below
    dvl_max_altitude_m: float = 30.0  # [m] ... and no farther
    dvl_scale_error: float = 0.002  # velocity reads this fraction too high
    dvl_offset_mps_body: tuple[float, float, float] = (0.0005, -0.0005, 0.0)  # [m/s] and is this off
    gyro_bias_walk_radps: float = 1e-5  # [rad/s per sqrt(s)] the gyro's bias random walk
    camera_rate_hz: float = 1.0  # 0: no cameras
    camera_width_px: int = 640
    camera_height_px: int = 480
    jpeg_quality: int = 90
    # underwater optics on the RGB frames (stations/simulation/optics.py): a Jerlov water type
    # (WATER_TYPES, clearest first), or "none" for the plain render in MuJoCo's fog; marine snow
    # is a multiple of the water type's own (0: none)
    water: str = "none"
    marine_snow: float = 1.0
    sonar_rate_hz: float = 2.0  # the imaging sonar's frames (stations/simulation/sonar.py); 0: none
    # where the physics state is kept (every state_period_s) and resumed from at start, so that
    # a restarted simulation goes on where the vehicle was; "" keeps none (`abyss up` sets it)
    state_file: str = ""
    state_period_s: float = 0.5
    # in real time, the station's threads at this SCHED_FIFO priority (1-99) where the system
    # allows it, so that the physics keeps its deadlines on a loaded machine (common.workers.Realtime);
    # 0: the normal scheduler
    realtime_priority: int = 10

    def __post_init__(self) -> None:
        if self.low_level not in LOW_LEVELS:
            raise ConfigError(
                "simulation.low_level", f"{self.low_level!r} not one of {', '.join(LOW_LEVELS)}"
            )
        _positive("simulation.physics_step_s", self.physics_step_s)
        _positive("simulation.current_time_constant_s", self.current_time_constant_s)
        if self.vehicle_file:  # the stations run in the run directory: the path is the user's shell's
            vehicle_file = Path(self.vehicle_file).expanduser()
            if not vehicle_file.is_file():
                raise ConfigError("simulation.vehicle_file", f"no such file: {vehicle_file.resolve()}")
            object.__setattr__(self, "vehicle_file", str(vehicle_file.resolve()))
        if self.hydrodynamics not in HYDRODYNAMICS:
            raise ConfigError(
                "simulation.hydrodynamics", f"{self.hydrodynamics!r} not one of {', '.join(HYDRODYNAMICS)}"
            )
        for row in self.current_profile:
            if len(row) != 4 or not all(math.isfinite(v) and abs(v) < 1e4 for v in row):
                raise ConfigError("simulation.current_profile", f"{list(row)}: rows of [z_m, vx, vy, vz]")
        _positive("simulation.state_period_s", self.state_period_s)
        if not 0 <= self.realtime_priority <= 99:
            raise ConfigError(
                "simulation.realtime_priority",
                f"{self.realtime_priority}: 0 (the normal scheduler) or a SCHED_FIFO priority from 1 to 99",
            )
        _positive("simulation.arm_kp", self.arm_kp)
        _positive("simulation.gripper_kp", self.gripper_kp)
        for name in (
            "arm_ki",
            "current_sigma_mps",
            "usbl_sigma_m",
            "dvl_sigma_mps",
            "imu_sigma_rad",
            "camera_rate_hz",
            "sonar_rate_hz",
            "pressure_sigma_pa",
            "usbl_processing_s",
            "usbl_outlier_m",
            "dvl_min_altitude_m",
            "dvl_scale_error",
            "gyro_bias_walk_radps",
        ):
            _positive(f"simulation.{name}", getattr(self, name), allow_zero=True)
        _positive("simulation.usbl_rate_hz", self.usbl_rate_hz)
        for name in ("usbl_outlier_probability", "usbl_dropout_probability"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ConfigError(f"simulation.{name}", f"{getattr(self, name)} outside [0, 1)")
        if not self.dvl_min_altitude_m < self.dvl_max_altitude_m:
            raise ConfigError(
                "simulation.dvl_max_altitude_m",
                f"{self.dvl_max_altitude_m} m must lie above "
                f"dvl_min_altitude_m = {self.dvl_min_altitude_m} m",
            )
        if any(abs(v) > 1.0 for v in self.dvl_offset_mps_body):
            raise ConfigError("simulation.dvl_offset_mps_body", "each within [-1, 1] m/s")
        for name in ("vehicle_kp", "vehicle_ki", "vehicle_kd"):
            for value in getattr(self, name):
                _positive(f"simulation.{name}", value, allow_zero=True)
        if not (16 <= self.camera_width_px <= 4096 and 16 <= self.camera_height_px <= 4096):
            raise ConfigError("simulation.camera_width_px", "camera size must lie in [16, 4096] px")
        if not 1 <= self.jpeg_quality <= 100:
            raise ConfigError("simulation.jpeg_quality", f"{self.jpeg_quality} outside [1, 100]")
        if self.water not in WATER_TYPES:
            raise ConfigError("simulation.water", f"{self.water!r} not one of {', '.join(WATER_TYPES)}")
        _positive("simulation.marine_snow", self.marine_snow, allow_zero=True)
        for name, period, base, base_name in (
            ("low_level_period_s", self.low_level_period_s, self.physics_step_s, "physics_step_s"),
            ("control_period_s", self.control_period_s, self.physics_step_s, "physics_step_s"),
            ("control_period_s", self.control_period_s, self.low_level_period_s, "low_level_period_s"),
        ):
            ratio = period / base
            if ratio < 1 - 1e-9 or not math.isclose(ratio, round(ratio), rel_tol=0, abs_tol=1e-9):
                raise ConfigError(
                    f"simulation.{name}", f"{period} s is not a whole multiple of {base_name} = {base} s"
                )


STEREO_MODES = ("3way", "sgbm", "hh", "hh4")  # onboard.stereo_mode: OpenCV's semi-global matcher's modes
STEREO_SCALES = (1, 2)  # onboard.stereo_scale and stereo_lr_scale: full or half resolution
STEREO_SWITCHES = (
    "stereo_uniqueness_percent",
    "stereo_speckle_window_px",
    "stereo_lr_max_diff_px",
    "stereo_min_texture",
    "stereo_edge_step_px",
)  # 0: that filter off


@dataclass(frozen=True)
class OnboardConfig:
    control_period_s: float = 0.05  # [s]
    telemetry_period_s: float = 0.1  # [s]
    # vehicle: proportional on position (world) and heading, the speed bounded by a deceleration
    # limit, plus a feed-forward of the steady velocity offset (a current the low level does not
    # reject) that an observer estimates from the pose's change against the commands, low-passed
    # with offset_time_constant_s. Off by default: the simulation's dynamic low level rejects the
    # current itself (PID on the velocity over ground), and its lag reads as a passing offset
    # that stops the vehicle short or overshoots; 2 s suits a low level without that lag
    kp_position: float = 0.6  # [1/s]
    kp_heading: float = 1.0  # [1/s]
    max_accel_mps2: float = 0.2  # [m/s^2] on the approach, where kp_position would decelerate harder
    offset_time_constant_s: float = 0.0  # [s]; 0: no feed-forward
    max_speed_mps: float = 0.5  # [m/s]
    max_yaw_rate_radps: float = 0.5  # [rad/s]
    # navigation (stations/onboard/navigation.py): the DVL's velocity integrated, corrected by each
    # USBL fix as a Kalman filter weighs them; depth and attitude pulled to the pressure sensor's
    # and the IMU's with nav_time_constant_s
    nav_time_constant_s: float = 5.0  # [s]; 0: use depth and attitude as they come
    nav_usbl_sigma_m: float = 0.02  # [m] the fixes' noise, as the filter assumes it
    nav_dvl_sigma_mps: float = 0.005  # [m/s] the DVL's noise, as the filter assumes it
    nav_gate_sigmas: float = 5.0  # a fix farther off than this many standard deviations is rejected
    nav_delay_compensation: bool = True  # a fix is compared with the estimate when it was taken
    # arm: task-priority inverse kinematics
    kp_ee_position: float = 1.0  # [1/s]
    kp_ee_orientation: float = 1.0  # [1/s]
    max_ee_speed_mps: float = 0.1  # [m/s]
    max_ee_rate_radps: float = 0.3  # [rad/s]
    max_joint_speed_radps: float = 0.5  # [rad/s]
    damping: float = 0.05  # largest damping of the pseudo-inverse, reached at a singularity
    singular_value_threshold: float = 0.05  # damping starts below this singular value
    joint_limit_margin_rad: float = 0.05  # kept from each mechanical stop [rad]
    clearance_m: float = 0.05  # kept between the arm and the obstacles [m]
    kp_constraint: float = 2.0  # [1/s] how fast a joint limit or an obstacle may be approached
    whole_body: bool = False  # the vehicle's surge, sway, heave and yaw join the arm's joints
    # failsafe: hold station and hold the arm still when the vessel is silent this long
    goal_timeout_s: float = 2.0  # [s]
    hold_on_shore_loss: bool = True  # also when the vessel reports shore silent
    # perception: a coloured cloud per camera frame from each source, in the world frame
    cloud_sources: tuple[str, ...] = ("depth", "stereo")
    # the stereo pair is matched on every this many frame sets (the depth camera on each): the
    # matcher is most of onboard's CPU, and the map of a static seabed from a slow vehicle loses
    # little (bench/perception.py: recall 0.639 -> 0.623, precision 0.951 either way, clear water)
    stereo_every: int = 2
    cloud_voxel_m: float = 0.05  # [m] voxel downsampling before the tether (half the octree's 0.1 m)
    cloud_max_range_m: float = 8.0  # [m] farther points are dropped (the water's murk)
    cloud_scale_m: float = 0.002  # [m] quantisation on the wire
    stereo_disparities: int = 64  # searched by the stereo matcher (a multiple of 16) [px]
    # OpenCV's semi-global matcher: "hh" (eight directions, full: the most exact, 4.3 cm on the
    # panel at 4 m), "sgbm" (five), "3way" (one pass, three: a third of hh's time per pair, but
    # over the default mission's path the map's recall falls from 0.64 to 0.36 in clear water,
    # bench/perception.py, and it matches 1.4 % of a textureless pair's pixels, against none),
    # "hh4" (four directions: 0.62x hh's time per pair, recall 0.653 against 0.636 in clear water
    # and 0.248 against 0.243 in Jerlov I, but precision 0.945 against 0.951 and 0.556 against 0.563)
    stereo_mode: str = "hh"
    # the pair is matched at full resolution (1) or at half (2: shrunk by area averaging, the
    # disparities, blocks and filter windows scaled with it, the points at half resolution): 2 is
    # a tenth of the time per pair (19 vs 195 ms, 110 with stereo_lr_scale 2; onboard 0.23 vs 0.37
    # cores over a 40 s run, with 1), but SGBM's sub-pixel disparity snaps to whole pixels there,
    # half as fine: 13.3 cm on the panel's face at 4 m against 4.6, and over the default
    # mission's path (bench/perception.py) the map's precision falls from 0.95 to 0.88 in clear
    # water, 0.56 to 0.35 in Jerlov I
    stereo_scale: int = 1
    self_filter_radius_m: float = 0.15  # [m] points this close to the arm are the arm's
    # the stereo matcher's filters (perception.StereoFilter), against points floating in open
    # water (edges smeared by the block, sensor noise and marine snow matched at random); 0
    # switches one off: a match beats the second best by this margin [%], patches of like
    # disparity (within the range) smaller than the window dropped [px], the right-to-left
    # disparity within this of the left-to-right one [px], a block's intensity spread (after a
    # 5x5 blur) at least this [grey levels], no disparity step larger than this in a block [px]
    stereo_uniqueness_percent: int = 15
    stereo_speckle_window_px: int = 400
    stereo_speckle_range_px: int = 2
    stereo_lr_max_diff_px: float = 1.0
    stereo_min_texture: float = 0.5
    stereo_edge_step_px: float = 1.0
    # the left-right check's right-to-left match at full resolution (1) or at half (2; as
    # stereo_scale where that is coarser), its disparity looked up at the left one's pixel: 2 takes
    # 110 ms per pair against 183 (bench/perception.py), the map's precision and recall over the
    # default mission's path as with 1 (clear water 0.951/0.636 vs 0.951/0.639, Jerlov I
    # 0.563/0.243 vs 0.559/0.250; seed 1: 0.550/0.250 vs 0.534/0.245)
    stereo_lr_scale: int = 2
    image_rate_hz: float = 1.0  # the left camera's frames sent on to the vessel
    image_jpeg_quality: int = 70
    # perception is busy this share of the wall time at most, resting after each frame set in
    # proportion to its work: where the CPU is short (a capped onboard computer, a loaded host) it
    # sheds frame sets, and the control loop in the same process keeps its deadlines
    perception_max_busy: float = 0.5

    def __post_init__(self) -> None:
        for name in self.cloud_sources:
            if name not in CLOUD_SOURCES:
                raise ConfigError("onboard.cloud_sources", f"{name!r} not one of {', '.join(CLOUD_SOURCES)}")
        if self.stereo_mode not in STEREO_MODES:
            raise ConfigError(
                "onboard.stereo_mode", f"{self.stereo_mode!r} not one of {', '.join(STEREO_MODES)}"
            )
        for name in ("stereo_scale", "stereo_lr_scale"):
            if getattr(self, name) not in STEREO_SCALES:
                raise ConfigError(
                    f"onboard.{name}",
                    f"{getattr(self, name)} not one of {', '.join(map(str, STEREO_SCALES))}",
                )
        if self.stereo_disparities % 16 or not 16 <= self.stereo_disparities <= 256:
            raise ConfigError(
                "onboard.stereo_disparities", f"{self.stereo_disparities}: a multiple of 16 in [16, 256]"
            )
        if not 1 <= self.image_jpeg_quality <= 100:
            raise ConfigError("onboard.image_jpeg_quality", f"{self.image_jpeg_quality} outside [1, 100]")
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (bool, tuple, str)):
                _positive(
                    f"onboard.{f.name}",
                    value,
                    allow_zero=f.name in ("offset_time_constant_s", "nav_time_constant_s", "image_rate_hz")
                    or f.name in STEREO_SWITCHES,
                )
        if self.perception_max_busy > 1.0:
            raise ConfigError("onboard.perception_max_busy", f"{self.perception_max_busy} outside (0, 1]")
        if self.stereo_uniqueness_percent > 100:
            raise ConfigError(
                "onboard.stereo_uniqueness_percent", f"{self.stereo_uniqueness_percent} outside [0, 100]"
            )
        if self.kp_constraint * self.control_period_s >= 1.0:
            raise ConfigError(
                "onboard.kp_constraint",
                f"kp_constraint * control_period_s must stay below 1 (got "
                f"{self.kp_constraint * self.control_period_s:.2f}), or a limit can be "
                f"crossed within one period",
            )


@dataclass(frozen=True)
class VesselConfig:
    telemetry_period_s: float = 0.5  # [s] telemetry relayed to shore, downsampled
    heartbeat_period_s: float = 0.5  # [s] to onboard
    shore_timeout_s: float = 5.0  # [s] shore silent this long: the satellite link is reported lost
    # the scene model and its stream to shore
    octree_resolution_m: float = 0.1  # [m] edge of the finest voxel
    octree_max_range_m: float = 8.0  # [m] rays are cut here
    scene_share: float = 0.5  # of the satellite's measured capacity, at most, for scene updates
    scene_update_bytes: int = 16_000  # one update at most: telemetry waits behind no more than this
    # [s] the octree's changes are looked for at most this often, and go to shore as one delta:
    # over `abyss stress satellite --duration 15` the scene's bytes over the final map's .bt were
    # 3.0/2.3/1.7x at 0.2/0.1/0.05 m with 1 s, 1.4/1.1/0.95x with 5 s (zstd, hysteresis, Z order)
    scene_track_period_s: float = 5.0
    satellite_capacity_bps: float = 1e6  # [bit/s] the first guess, before one is measured
    recognition_period_s: float = 2.0  # [s]
    # [m, world] added to the recognised panel's position: a fault for scenarios, as a camera
    # calibrated wrong or a marker misplaced on the panel would bias it
    recognition_bias_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # the left camera's frame relayed to shore, within the scene's share of the satellite
    image_period_s: float = 5.0  # [s]
    image_scale: float = 0.5  # of the onboard frame's width and height
    image_jpeg_quality: int = 50
    sonar_period_s: float = 5.0  # [s] the sonar's image relayed to shore, as JPEG, as the camera's
    # the sonar's first echoes feed the scene model while the cameras' clouds bring no point for
    # this long (murk, a failed camera); before that, the cameras' alone
    sonar_fallback_s: float = 5.0  # [s]
    perception_period_s: float = 2.0  # [s] what perception works with, to shore (PerceptionStatus)
    perception_window_s: float = 10.0  # [s] ... counted over this long

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            if f.name != "recognition_bias_m":
                _positive(
                    f"vessel.{f.name}", getattr(self, f.name), allow_zero=f.name == "scene_track_period_s"
                )  # 0: after each cloud
        if len(self.recognition_bias_m) != 3 or not all(abs(b) <= 1.0 for b in self.recognition_bias_m):
            raise ConfigError("vessel.recognition_bias_m", "needs [x, y, z], each within [-1, 1] m")
        if self.image_scale > 1.0:
            raise ConfigError("vessel.image_scale", f"{self.image_scale} must lie in (0, 1]")
        if self.image_jpeg_quality > 100:
            raise ConfigError("vessel.image_jpeg_quality", f"{self.image_jpeg_quality} outside [1, 100]")
        if self.scene_share > 1.0:
            raise ConfigError("vessel.scene_share", f"{self.scene_share} must lie in (0, 1]")
        if self.octree_resolution_m < 0.01:
            raise ConfigError("vessel.octree_resolution_m", f"{self.octree_resolution_m} m: at least 0.01 m")


VIEWERS = ("save", "web", "spawn", "none")


@dataclass(frozen=True)
class OnshoreConfig:
    record_dir: str = ""  # where the run's scene and recording go; `abyss up` sets its run directory
    scene_request_period_s: float = 2.0  # [s] a missing snapshot is asked for again this often
    # the rerun viewer: save (onshore.rrd in record_dir), web (rerun's web viewer served on
    # viewer_web_port, its data on viewer_grpc_port), spawn (the native viewer), none; web and
    # spawn save the recording too
    viewer: str = "save"
    viewer_web_port: int = 9090
    viewer_grpc_port: int = 9876
    viewer_scene_period_s: float = 2.0  # [s] the whole octree is logged at most this often

    def __post_init__(self) -> None:
        _positive("onshore.scene_request_period_s", self.scene_request_period_s)
        _positive("onshore.viewer_scene_period_s", self.viewer_scene_period_s)
        if self.viewer not in VIEWERS:
            raise ConfigError("onshore.viewer", f"{self.viewer!r} not one of {', '.join(VIEWERS)}")
        for name in ("viewer_web_port", "viewer_grpc_port"):
            if not 0 < getattr(self, name) < 65536:
                raise ConfigError(f"onshore.{name}", f"{getattr(self, name)} outside [1, 65535]")


RECORD_LEVELS = ("none", "control", "all")


@dataclass(frozen=True)
class RecordConfig:
    """The bus recording (abyss.recording.store): what each station sent and received."""

    level: str = "all"  # none | control (what is not bulk) | all
    directory: str = ""  # where each station writes <station>.mcap; "" records nothing (`abyss up` sets it)
    max_rate_hz: float = 50.0  # per key and direction: the rest is skipped and counted
    bulk_max_rate_hz: float = 2.0  # the same for images, clouds, the scene stream

    def __post_init__(self) -> None:
        if self.level not in RECORD_LEVELS:
            raise ConfigError("record.level", f"{self.level!r} not one of {', '.join(RECORD_LEVELS)}")
        _positive("record.max_rate_hz", self.max_rate_hz)
        _positive("record.bulk_max_rate_hz", self.bulk_max_rate_hz)


MIN_CPU_CORES = 0.05  # a cap below this leaves a station too little to stop within its bound


@dataclass(frozen=True)
class CpuConfig:
    """A CPU cap per station [cores], the paper's processing power beside bandwidth, delay and
    sensor noise (`abyss up --cpu STATION=CORES`): a cgroup quota on Linux, `cpus:` in compose.
    0 leaves the station uncapped; a capped station sheds its oldest frames, and says so."""

    simulation: float = 0.0
    onboard: float = 0.0
    vessel: float = 0.0
    onshore: float = 0.0

    def __post_init__(self) -> None:
        for name, cores in dataclasses.asdict(self).items():
            if cores != 0.0 and not MIN_CPU_CORES <= cores <= 1024:
                raise ConfigError(f"cpu.{name}", f"{cores} cores: 0 (uncapped) or {MIN_CPU_CORES} to 1024")

    def capped(self) -> dict[str, float]:
        """The capped stations and their caps [cores]."""
        return {name: cores for name, cores in dataclasses.asdict(self).items() if cores}


TIME_MODES = ("real", "sim", "lockstep")


@dataclass(frozen=True)
class TimeConfig:
    """The system's time source (common.clock): `real` (the wall clock; the only mode with a real
    component, real links or an operator in the loop), `sim` (the simulation's clock drives every
    station's rates and timers and every emulated link, `speed` simulated seconds per wall
    second, or `max`: as fast as the slowest station allows) or `lockstep` (the same, one control
    period at a time, each station's loops one at a time: a run repeats bit for bit,
    common.lockstep)."""

    mode: str = "real"
    speed: str = "1"  # a positive number, or "max"
    max_lag_s: float = 0.1  # [simulated s] how far a station's loops may be behind the simulation
    # the stations whose progress the simulation waits for, with `sim`
    stations: tuple[str, ...] = ("onboard", "vessel", "onshore")
    # lockstep: the simulation stops advancing at this simulated time (abyss up's --duration), so
    # that a run ends on the same period whenever it is stopped; 0: never
    end_s: float = 0.0

    def __post_init__(self) -> None:
        if self.mode not in TIME_MODES:
            raise ConfigError("time.mode", f"{self.mode!r} not one of {', '.join(TIME_MODES)}")
        if self.speed != "max":
            try:
                speed = float(self.speed)
            except ValueError:
                speed = math.nan
            if not math.isfinite(speed) or not 0.01 <= speed <= 1000:
                raise ConfigError("time.speed", f"{self.speed!r}: a number from 0.01 to 1000, or max")
        if self.mode != "sim" and self.speed_factor != 1.0:
            raise ConfigError(
                "time.speed",
                f"{self.speed}: only with time.mode sim ({self.mode} runs at "
                f"{'1' if self.mode == 'real' else 'the speed its slowest station allows'})",
            )
        _positive("time.end_s", self.end_s, allow_zero=True)
        _positive("time.max_lag_s", self.max_lag_s, allow_zero=True)
        for station in self.stations:
            if station not in keys.STATIONS or station == "simulation":
                raise ConfigError("time.stations", f"{station!r}: not one of onboard, vessel, onshore")

    @property
    def speed_factor(self) -> float:
        """Simulated seconds per wall second asked for (inf: max)."""
        return math.inf if self.speed == "max" else float(self.speed)

    @property
    def simulated(self) -> bool:
        """On the simulation's clock: `sim` or `lockstep`."""
        return self.mode != "real"


ROS2_STATIONS = ("onboard", "vessel")  # the stations a ROS 2 node can stand for (ros2.gateway)
_ROS_NAMESPACE = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)+$")


@dataclass(frozen=True)
class Ros2Config:
    """The ROS 2 gateway (abyss.ros2.gateway): a ROS 2 node over rmw_zenoh in a station's place."""

    station: str = ""  # the station the gateway stands for (`abyss up --ros2 STATION`); "" none
    domain: int = 0  # ROS_DOMAIN_ID: the first chunk of every rmw_zenoh key
    namespace: str = "/abyss"  # the gateway's topics: <namespace>/<station>/<topic>
    # the Zenoh router the ROS 2 nodes connect to: the gateway listens as one (rmw_zenohd's default
    # endpoint) or, with `connect`, joins one that runs already (rmw_zenohd)
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    connect: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.station not in ("", *ROS2_STATIONS):
            raise ConfigError(
                "ros2.station", f"{self.station!r}: a ROS 2 node can stand for {', '.join(ROS2_STATIONS)}"
            )
        if not 0 <= self.domain <= 232:
            raise ConfigError("ros2.domain", f"{self.domain}: a ROS domain id is 0 to 232")
        if not _ROS_NAMESPACE.match(self.namespace):
            raise ConfigError(
                "ros2.namespace",
                f"{self.namespace!r} is not an absolute ROS 2 namespace such as /abyss or /team/rov1",
            )
        if not self.listen and not self.connect:
            raise ConfigError(
                "ros2.listen", "empty, and so is ros2.connect: the ROS 2 nodes would have no router"
            )


Box = tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class MissionConfig:
    # rows of x, y, z [m, world] and yaw [rad]
    # the last, 1.8 m off the panel's face and level with its middle: the arm reaches the
    # valves above and the levers below without the vehicle moving
    waypoints: tuple[tuple[float, float, float, float], ...] = (
        (1.5, 0.0, -7.0, 0.0),
        (2.5, 0.8, -7.6, 0.3),
        (3.2, 0.0, -8.0, 0.0),
    )
    position_tolerance_m: float = 0.15
    heading_tolerance_rad: float = 0.1
    # [s] a waypoint not reached within its leg flown at onboard's speed limits (its length over
    # max_speed_mps, its turn over max_yaw_rate_radps) plus this is missed: onboard holds it and
    # reports the mode "missed", and the mission is not done; 0: no limit
    waypoint_timeout_s: float = 30.0
    # the end-effector's goal once the last waypoint is reached: x, y, z [m, world], roll, pitch,
    # yaw [rad] (rotations about the world's x, y, z, in that order); empty: no arm goal. E.g.
    # [4.86, 0, -8.35, 1.5708, 0, 0]: the fingers either side of the middle valve's handle.
    arm_target: tuple[float, ...] = ()
    # or the interventions, one after the other once the last waypoint is reached: rows of a part
    # of the panel and what to do with it: a valve and the angle to turn it by [deg], or a lever
    # and the stop to throw it to (up, down); the success of each is judged on the simulation's truth
    interventions: tuple[tuple[str, str], ...] = (("valve_1", "90"), ("lever_0", "down"))
    arm_position_tolerance_m: float = 0.005
    arm_orientation_tolerance_rad: float = 0.02
    arm_settle_s: float = 2.0  # [s] within both tolerances this long: the goal is reached
    # boxes the arm keeps clear of: centre x, y, z and half sizes [m, world]
    obstacles: tuple[Box, ...] = (
        (5.0, 0.0, -8.6, 0.05, 0.8, 0.6),  # the panel's plate
        (5.0, 0.0, -20.0, 50.0, 50.0, 10.0),  # the seabed around the panel, a floor at z = -10 m
    )
    resend_period_s: float = 2.0  # [s] shore resends a command until onboard acknowledges it
    # onboard refuses a waypoint closer than this to an obstacle or the surface, and an arm
    # goal out of the arm's reach from where the vehicle will be [m]
    vehicle_clearance_m: float = 0.5

    def __post_init__(self) -> None:
        if not 1 <= len(self.waypoints) <= 1000:
            raise ConfigError("mission.waypoints", "needs 1 to 1000 rows of [x, y, z, yaw]")
        if len(self.arm_target) not in (0, 6):
            raise ConfigError("mission.arm_target", "needs [x, y, z, roll, pitch, yaw], or [] for none")
        if self.arm_target and self.interventions:
            raise ConfigError(
                "mission.interventions",
                "an arm goal (mission.arm_target) or interventions, not both: set the other to []",
            )
        for i, (part, amount) in enumerate(self.interventions):
            try:
                panel.intent(part, amount)
            except ValueError as exc:
                raise ConfigError(f"mission.interventions[{i}]", str(exc)) from None
        _positive("mission.waypoint_timeout_s", self.waypoint_timeout_s, allow_zero=True)
        for name in (
            "position_tolerance_m",
            "heading_tolerance_rad",
            "arm_position_tolerance_m",
            "arm_orientation_tolerance_rad",
            "arm_settle_s",
            "resend_period_s",
            "vehicle_clearance_m",
        ):
            _positive(f"mission.{name}", getattr(self, name))
        for i, box in enumerate(self.obstacles):
            for size in box[3:]:
                _positive(f"mission.obstacles[{i}] half size", size)

    def arm_goal(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The end-effector goal as position [m, world] and quaternion (w, x, y, z), or None."""
        if not self.arm_target:
            return None
        x, y, z, roll, pitch, yaw = self.arm_target
        return np.array([x, y, z]), quat_wxyz_of(rotation_of_rpy(roll, pitch, yaw))


@dataclass(frozen=True)
class Config:
    system: str = "default"
    seed: int = 0
    links: LinksConfig = field(default_factory=LinksConfig)
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    onboard: OnboardConfig = field(default_factory=OnboardConfig)
    vessel: VesselConfig = field(default_factory=VesselConfig)
    onshore: OnshoreConfig = field(default_factory=OnshoreConfig)
    mission: MissionConfig = field(default_factory=MissionConfig)
    record: RecordConfig = field(default_factory=RecordConfig)
    ros2: Ros2Config = field(default_factory=Ros2Config)
    cpu: CpuConfig = field(default_factory=CpuConfig)
    time: TimeConfig = field(default_factory=TimeConfig)

    def __post_init__(self) -> None:
        keys.check_system_id(self.system)
        if self.time.simulated and self.ros2.station:
            raise ConfigError(
                "time.mode",
                "sim: a ROS 2 node (ros2.station, --ros2) runs on the wall clock; use --time real with it",
            )

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), indent=2)


def _positive(name: str, value: float, allow_zero: bool = False) -> None:
    if not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        allowed = "zero or a positive number" if allow_zero else "a positive number"
        raise ConfigError(name, f"{value} must be {allowed}")


def _coerce(name: str, kind: Any, value: Any) -> Any:
    """Check `value` against the type hint `kind`, converting CLI strings."""
    origin = typing.get_origin(kind)
    if dataclasses.is_dataclass(kind):
        return _build(kind, value, name)
    if origin is tuple:
        args = typing.get_args(kind)
        if isinstance(value, str):
            value = json.loads(value)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(name, f"expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(f"{name}[{i}]", args[0], v) for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(name, f"expected {len(args)} values, got {len(value)}")
        return tuple(_coerce(f"{name}[{i}]", a, v) for i, (a, v) in enumerate(zip(args, value, strict=True)))
    if kind is float:
        try:
            number = float(value) if not isinstance(value, bool) else math.nan
        except (TypeError, ValueError):
            number = math.nan
        if not math.isfinite(number):
            raise ConfigError(name, f"expected a finite number, got {value!r}")
        return number
    if kind is int:
        if isinstance(value, str) and value.strip().lstrip("-").isdigit():
            value = int(value)
        if not isinstance(value, int) or isinstance(value, bool):
            raise ConfigError(name, f"expected a whole number, got {value!r}")
        return value
    if kind is bool:
        if isinstance(value, str) and value.lower() in ("true", "false"):
            value = value.lower() == "true"
        if not isinstance(value, bool):
            raise ConfigError(name, f"expected true or false, got {value!r}")
        return value
    if kind is str:
        if not isinstance(value, str):
            raise ConfigError(name, f"expected a string, got {value!r}")
        return value
    raise ConfigError(name, f"unsupported type {kind}")


def _build(cls: Any, table: Any, prefix: str = "") -> Any:
    if not isinstance(table, dict):
        raise ConfigError(prefix or "config", f"expected a table, got {table!r}")
    hints = typing.get_type_hints(cls)
    allowed = {f.name for f in dataclasses.fields(cls)}
    unknown = set(table) - allowed
    if unknown:
        raise ConfigError(
            f"{prefix}{'.' if prefix else ''}{sorted(unknown)[0]}",
            f"unknown field; allowed: {', '.join(sorted(allowed))}",
        )
    values = {n: _coerce(f"{prefix}{'.' if prefix else ''}{n}", hints[n], v) for n, v in table.items()}
    return cls(**values)


def load(
    path: Path | None = None,
    overrides: typing.Sequence[str] = (),
    base: dict[str, Any] | None = None,
    options: dict[str, str] | None = None,
) -> Config:
    """Defaults, then the file (TOML or JSON), then `section.field=value` overrides. An error
    names where its field's value came from: the option in `options` (field -> the option the
    user typed, e.g. "time.speed" -> "--speed"), else --set, else the file."""
    table: dict[str, Any] = dict(base or {})
    source = str(path) if path else "--set"
    overridden: dict[str, str] = {}
    if path is not None:
        try:
            text = path.read_text()
            table = json.loads(text) if path.suffix == ".json" else tomllib.loads(text)
        except (OSError, ValueError) as exc:
            raise ConfigError("config", f"cannot read: {exc}", source) from None
    for item in overrides:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise ConfigError("--set", f"{item!r} is not section.field=value")
        *sections, leaf = name.split(".")
        node = table
        for section in sections:
            node = node.setdefault(section, {})
            if not isinstance(node, dict):
                raise ConfigError(name, "is not a section")
        node[leaf] = value
        overridden[name] = (options or {}).get(name, "--set")
    try:
        return typing.cast(Config, _build(Config, table))
    except ConfigError as exc:
        raise ConfigError(exc.field, exc.reason, overridden.get(exc.field, source)) from None
    except json.JSONDecodeError as exc:
        raise ConfigError("config", f"bad list value: {exc}", source) from None
