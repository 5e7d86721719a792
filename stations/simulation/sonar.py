"""A forward-looking imaging sonar from MuJoCo ray casts: a fan of beams across the horizontal
field of view, each a spread of rays over the vertical aperture; every ray's echo is summed into
its beam's range bin, weighted by the beam pattern in elevation, the surface's incidence
(Lambertian backscatter, cos^2) and the two-way absorption (10^(-2 alpha r / 10)), spreading
compensated (as a sonar's time-varied gain does). Rayleigh speckle multiplies the intensity and
a noise floor adds to it, both seeded; the image is in decibels over a fixed dynamic range. It
is polar: rows are range bins (nearest first), columns beams (port to starboard). A pure core:
model, state and a generator in, image out; `message` wraps it for the wire (messages.SonarImage),
which the station publishes at simulation.sonar_rate_hz."""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from abyss.interface.messages import SonarImage
from abyss.interface.sonar_frames import encode_polar


@dataclass(frozen=True)
class SonarSpec:
    beams: int = 128
    horizontal_fov_rad: float = math.radians(130.0)
    vertical_aperture_rad: float = math.radians(20.0)
    rays_per_beam: int = 12  # across the vertical aperture
    range_max_m: float = 10.0
    bins: int = 200
    absorption_db_per_m: float = 0.2  # about 750 kHz in sea water
    noise_floor: float = 1e-4  # of a square-on wall's echo (-40 dB)
    dynamic_range_db: float = 40.0  # from the noise floor (black) to a square-on wall (white)
    site: str = "sonar"

    def bearings_rad(self) -> np.ndarray:
        """Each beam's bearing, port (left, positive) to starboard."""
        half = self.horizontal_fov_rad / 2
        return np.linspace(half, -half, self.beams)

    def bin_m(self) -> float:
        return self.range_max_m / self.bins


class ImagingSonar:
    def __init__(self, model: mujoco.MjModel, spec: SonarSpec = SonarSpec()) -> None:
        self.model, self.spec = model, spec
        self.site = model.site(spec.site).id
        self.body = int(model.site_bodyid[self.site])
        half = spec.vertical_aperture_rad / 2
        elevations = np.linspace(-half, half, spec.rays_per_beam)
        azimuth, elevation = np.meshgrid(spec.bearings_rad(), elevations, indexing="ij")  # beam, ray
        self.directions_site = np.stack(
            (np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)),
            axis=-1,
        ).reshape(-1, 3)
        # the beam pattern in elevation: a sinc^2 main lobe whose first nulls fall just past the aperture
        self.pattern = np.sinc(elevation / (1.2 * half)).reshape(-1) ** 2
        self._beam_of_ray = np.repeat(np.arange(spec.beams), spec.rays_per_beam)

    def cast(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every ray's range [m] (-1: nothing within range), the geom it hit, and the cosine of
        its incidence on that surface."""
        rotation = data.site_xmat[self.site].reshape(3, 3)
        directions = self.directions_site @ rotation.T
        n = len(directions)
        distance = np.empty(n)
        geoms = np.empty(n, np.int32)
        normals = np.empty((n, 3))
        mujoco.mj_multiRay(
            self.model,
            data,
            data.site_xpos[self.site].copy(),
            directions.reshape(-1),
            None,
            True,
            self.body,
            geoms,
            distance,
            normals.reshape(-1),
            n,
            self.spec.range_max_m,
        )
        distance[distance > self.spec.range_max_m] = -1.0
        incidence = np.abs(np.einsum("ij,ij->i", normals, directions))
        return distance, geoms, incidence

    def image(self, data: mujoco.MjData, rng: np.random.Generator) -> np.ndarray:
        """The polar intensity image (bins x beams), uint8."""
        s = self.spec
        distance, _, incidence = self.cast(data)
        hit = distance > 0
        absorbed = 10.0 ** (-2.0 * s.absorption_db_per_m * distance[hit] / 10.0)
        echo = self.pattern[hit] * incidence[hit] ** 2 * absorbed
        bins = np.minimum((distance[hit] / s.bin_m()).astype(int), s.bins - 1)
        intensity = np.zeros((s.bins, s.beams))
        np.add.at(intensity, (bins, self._beam_of_ray[hit]), echo)
        intensity /= float(self.pattern.reshape(s.beams, -1)[0].sum())  # a wall square on: 0 dB
        speckle = rng.exponential(1.0, intensity.shape)  # Rayleigh amplitude: exponential intensity
        intensity = intensity * speckle + rng.exponential(s.noise_floor, intensity.shape)
        # shown in decibels, as sonars show it: the dynamic range maps onto the grey levels
        db = 10.0 * np.log10(intensity)
        return np.clip(255.0 * (db + s.dynamic_range_db) / s.dynamic_range_db, 0, 255).astype(np.uint8)

    def message(self, data: mujoco.MjData, rng: np.random.Generator) -> SonarImage:
        """The image as the sonar sends it: PNG, with its geometry and its mounting on the body
        that carries it (the vehicle frame)."""
        s, m = self.spec, self.model
        return SonarImage(
            sonar=s.site,
            encoding="png8",
            pose_frame="vehicle",
            beams=s.beams,
            bins=s.bins,
            range_max_m=s.range_max_m,
            horizontal_fov_rad=s.horizontal_fov_rad,
            vertical_aperture_rad=s.vertical_aperture_rad,
            dynamic_range_db=s.dynamic_range_db,
            pose_sonar=np.r_[m.site_pos[self.site], m.site_quat[self.site]],
            data=encode_polar(self.image(data, rng), "png8"),
            sim_time_s=float(data.time),
        )
