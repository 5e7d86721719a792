"""The sections of the configuration for onboard (`[onboard]`: control, navigation, the arm,
perception), the vessel (`[vessel]`: the relay, the scene model and its stream to shore) and
shore (`[onshore]`: the scene's receiver and the viewer)."""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass
from typing import Literal

from abyss.common.errors import ConfigError
from abyss.config.fields import one_of, positive
from abyss.interface.messages import CLOUD_SOURCES

# onboard.stereo_mode: OpenCV's semi-global matcher's modes
StereoMode = Literal["3way", "sgbm", "hh", "hh4"]
STEREO_MODES: tuple[StereoMode, ...] = typing.get_args(StereoMode)
StereoScale = Literal[1, 2]  # onboard.stereo_scale and stereo_lr_scale: full or half resolution
STEREO_SCALES: tuple[StereoScale, ...] = typing.get_args(StereoScale)
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
    # with whole_body, the vehicle's columns are scaled by this in the solver (a weighted least-norm
    # solution: a vehicle axis costs 1 / weight^2 what a joint does per unit of speed), so that
    # below 1 the arm does what it can and the vehicle what the arm cannot; 1: alike
    whole_body_weight: float = 1.0
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
    stereo_mode: StereoMode = "hh"
    # the pair is matched at full resolution (1) or at half (2: shrunk by area averaging, the
    # disparities, blocks and filter windows scaled with it, the points at half resolution): 2 is
    # a tenth of the time per pair (19 vs 195 ms, 110 with stereo_lr_scale 2; onboard 0.23 vs 0.37
    # cores over a 40 s run, with 1), but SGBM's sub-pixel disparity snaps to whole pixels there,
    # half as fine: 13.3 cm on the panel's face at 4 m against 4.6, and over the default
    # mission's path (bench/perception.py) the map's precision falls from 0.95 to 0.88 in clear
    # water, 0.56 to 0.35 in Jerlov I
    stereo_scale: StereoScale = 1
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
    stereo_lr_scale: StereoScale = 2
    image_rate_hz: float = 1.0  # the left camera's frames sent on to the vessel
    image_jpeg_quality: int = 70
    # perception is busy this share of the wall time at most, resting after each frame set in
    # proportion to its work: where the CPU is short (a capped onboard computer, a loaded host) it
    # sheds frame sets, and the control loop in the same process keeps its deadlines
    perception_max_busy: float = 0.5
    # [s] on simulated time, a frame set's clouds (and its image for the vessel) go out this long
    # after the set was taken: the onboard computer's time for the set, which the set's work runs
    # in, the control loop and the simulation going on meanwhile (docs/time.md, Bulk work); in
    # real time they go out when done. Below the cameras' period (simulation.camera_rate_hz).
    perception_latency_s: float = 0.3

    def __post_init__(self) -> None:
        for name in self.cloud_sources:
            if name not in CLOUD_SOURCES:
                raise ConfigError("onboard.cloud_sources", f"{name!r} not one of {', '.join(CLOUD_SOURCES)}")
        one_of("onboard.stereo_mode", self.stereo_mode, STEREO_MODES)
        for name in ("stereo_scale", "stereo_lr_scale"):
            one_of(f"onboard.{name}", getattr(self, name), STEREO_SCALES)
        if self.stereo_disparities % 16 or not 16 <= self.stereo_disparities <= 256:
            raise ConfigError(
                "onboard.stereo_disparities", f"{self.stereo_disparities}: a multiple of 16 in [16, 256]"
            )
        if not 1 <= self.image_jpeg_quality <= 100:
            raise ConfigError("onboard.image_jpeg_quality", f"{self.image_jpeg_quality} outside [1, 100]")
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, (bool, tuple, str)):
                positive(
                    f"onboard.{f.name}",
                    value,
                    allow_zero=f.name in ("offset_time_constant_s", "nav_time_constant_s", "image_rate_hz")
                    or f.name in STEREO_SWITCHES,
                )
        positive("onboard.perception_latency_s", self.perception_latency_s, allow_zero=True)
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
    # [s] on simulated time, clouds and echoes are in the octree this long after they came (their
    # changes queued for shore then): the insertion runs meanwhile, the relay and the stream going
    # on (docs/time.md, Bulk work); in real time they are in when inserted
    insertion_latency_s: float = 0.2
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
                positive(  # 0: after each cloud; at once
                    f"vessel.{f.name}",
                    getattr(self, f.name),
                    allow_zero=f.name in ("scene_track_period_s", "insertion_latency_s"),
                )
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


Viewer = Literal["save", "web", "spawn", "none"]
VIEWERS: tuple[Viewer, ...] = typing.get_args(Viewer)


@dataclass(frozen=True)
class OnshoreConfig:
    record_dir: str = ""  # where the run's scene and recording go; `abyss up` sets its run directory
    scene_request_period_s: float = 2.0  # [s] a missing snapshot is asked for again this often
    # the rerun viewer: save (onshore.rrd in record_dir), web (rerun's web viewer served on
    # viewer_web_port, its data on viewer_grpc_port), spawn (the native viewer), none; web and
    # spawn save the recording too
    viewer: Viewer = "save"
    viewer_web_port: int = 9090
    viewer_grpc_port: int = 9876
    viewer_scene_period_s: float = 2.0  # [s] the whole octree is logged at most this often

    def __post_init__(self) -> None:
        positive("onshore.scene_request_period_s", self.scene_request_period_s)
        positive("onshore.viewer_scene_period_s", self.viewer_scene_period_s)
        one_of("onshore.viewer", self.viewer, VIEWERS)
        for name in ("viewer_web_port", "viewer_grpc_port"):
            if not 0 < getattr(self, name) < 65536:
                raise ConfigError(f"onshore.{name}", f"{getattr(self, name)} outside [1, 65535]")
