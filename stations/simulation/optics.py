"""Underwater optics on a rendered camera image: what the water between the vehicle's lamps, the
scene and the camera does to MuJoCo's (in-air) render. A pure core: an RGB render, the range
along each pixel's ray and a seeded generator in, the underwater image out.

The image formation model, per channel c (R, G, B at WAVELENGTHS_NM), after Akkaynak & Treibitz,
"A revised underwater image formation model", CVPR 2018, with the deep sea's only light the
vehicle's lamps (Jaffe, "Computer modeling and the design of optimal underwater imaging
systems", IEEE J. Oceanic Eng. 1990: light -> object -> camera):

    I_c = J_c * E_c(x) * exp(-beta_D,c * r)  +  B_inf,c(ray) * (1 - exp(-beta_B,c(ray) * r))

- J: the render, the scene's colours as MuJoCo lights them in air;
- E_c(x): the lamps' irradiance at the point x seen, relative to that on a lamp's axis at
  REFERENCE_M in air: each lamp's cone (cos^exponent inside its cutoff, as MuJoCo's spot
  lights), inverse-square falloff and the water on the lamp's path, exp(-beta_D,c * d_lamp);
- r: the range from the camera [m] (the render's depth is along the optical axis);
- B_inf,c(ray), beta_B,c(ray): the lamps' own beams scattered back into each ray, integrated
  along it once, at start (the lamps move with the camera): B_inf is the whole ray's, and
  beta_B is set so that half of it is reached where the integral reaches half, which makes the
  backscatter coefficient differ from the attenuation, as in the revised model; this veil,
  brightest where the ray crosses the beams near the camera, is what turns turbid water milky.

Coefficients (WATER_TYPES): beta_D = Jerlov's diffuse attenuation K_d at 600, 525 and 475 nm
(N. G. Jerlov, "Marine Optics", 2nd ed., Elsevier 1976, Table XXVII; the types that Solonenko
& Mobley, "Inherent optical properties of Jerlov water types", Applied Optics 54(17), 2015,
give inherent properties for). The scattering coefficient b is taken as K_d less pure water's
absorption (Pope & Fry, Applied Optics 36(33), 1997: 0.222, 0.048, 0.011 1/m), at least a tenth
of K_d, with a particle phase function of BACKSCATTER_PHASE_PER_SR in the backward directions
(Petzold's average particle, roughly): a modelling choice, stated as such.

Then the camera: an exposure that holds the image's mean at EXPOSURE_TARGET
(gain within EXPOSURE_GAIN), marine snow (particles lit by the lamps, drawn in front of the
scene: bright near the lamps, a few pixels across, denser in turbid types) and sensor noise
(read and shot), both from the generator passed in.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from abyss.common.geometry import Intrinsics

WAVELENGTHS_NM = (600, 525, 475)  # R, G, B
PURE_WATER_ABSORPTION_PER_M = (0.222, 0.048, 0.011)  # Pope & Fry 1997, at WAVELENGTHS_NM
BACKSCATTER_PHASE_PER_SR = 0.01  # particle scattering per steradian at 90-180 degrees, of b
LAMBERT_WHITE = 0.9 / np.pi  # radiance of a white face per unit irradiance: the render's 1.0
REFERENCE_M = 2.0  # [m] on a lamp's axis, where the lamps light the scene as MuJoCo's render
EXPOSURE_TARGET = 0.3  # the image's mean after the exposure (of full scale)
EXPOSURE_GAIN = (0.25, 8.0)
READ_NOISE = 1.0 / 255  # [of full scale]
SHOT_NOISE = 0.5 / 255  # variance per unit signal [of full scale]
SNOW_RANGE_M = (0.15, 4.0)  # marine snow is drawn this far from the camera
SNOW_DIAMETER_M = (0.001, 0.005)


@dataclass(frozen=True)
class WaterType:
    """A Jerlov water type: attenuation and scattering [1/m] at R, G, B (WAVELENGTHS_NM), and
    how much marine snow it carries [particles/m^3]."""

    name: str
    attenuation_per_m: tuple[float, float, float]
    snow_per_m3: float

    @property
    def scattering_per_m(self) -> tuple[float, float, float]:
        return tuple(
            max(k - a, 0.1 * k)
            for k, a in zip(self.attenuation_per_m, PURE_WATER_ABSORPTION_PER_M, strict=True)  # type: ignore[return-value]
        )


def _jerlov(name: str, kd_600: float, kd_525: float, kd_475: float, snow_per_m3: float) -> WaterType:
    return WaterType(name, (kd_600, kd_525, kd_475), snow_per_m3)


# Jerlov 1976, Table XXVII (K_d [1/m]); oceanic I-III, coastal 1C-9C, clearest first
WATER_TYPES: dict[str, WaterType] = {
    w.name: w
    for w in (
        _jerlov("I", 0.235, 0.043, 0.018, 7.0),
        _jerlov("IA", 0.240, 0.048, 0.025, 10.0),
        _jerlov("IB", 0.245, 0.054, 0.033, 13.0),
        _jerlov("II", 0.260, 0.076, 0.062, 20.0),
        _jerlov("III", 0.295, 0.116, 0.116, 30.0),
        _jerlov("1C", 0.300, 0.130, 0.170, 50.0),
        _jerlov("3C", 0.330, 0.200, 0.290, 80.0),
        _jerlov("5C", 0.400, 0.310, 0.430, 130.0),
        _jerlov("7C", 0.480, 0.490, 0.710, 200.0),
        _jerlov("9C", 0.600, 0.780, 1.230, 300.0),
    )
}


@dataclass(frozen=True)
class Lamp:
    """A spot light in the camera's frame (OpenCV axes): position [m], unit direction, cutoff
    [rad] and exponent (MuJoCo's spot: cos^exponent of the angle off its axis, 0 past cutoff)."""

    position_m_camera: tuple[float, float, float]
    direction_camera: tuple[float, float, float]
    cutoff_rad: float
    exponent: float

    def irradiance(self, points_m_camera: np.ndarray, attenuation_per_m: np.ndarray) -> np.ndarray:
        """Irradiance at the points (..., 3) per channel (..., 3), relative to that at REFERENCE_M
        on the axis in air: cone, inverse square, the water on the way."""
        geometric, distance_m = self._falloff(points_m_camera)
        water = distance_m[..., None] * attenuation_per_m
        np.negative(water, out=water)
        np.exp(water, out=water)
        water *= geometric[..., None]
        return water.astype(np.float32, copy=False)

    def irradiance_planes(self, points_m_camera: np.ndarray, attenuation_per_m: np.ndarray) -> np.ndarray:
        """The same per channel first (3, ...): each channel's plane in one contiguous pass."""
        geometric, distance_m = self._falloff(points_m_camera)
        water = np.multiply.outer(attenuation_per_m, distance_m)
        np.negative(water, out=water)
        np.exp(water, out=water)
        water *= geometric
        return water.astype(np.float32, copy=False)

    def _falloff(self, points_m_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The cone and the inverse square (relative to REFERENCE_M) at each point (...), and its
        distance from the lamp [m]; each step in place where the arrays allow it."""
        position = np.asarray(self.position_m_camera, np.float32)
        to_point = np.empty(points_m_camera.shape, np.result_type(points_m_camera, position))
        for i in range(3):  # a component at a time: no broadcast over the three
            np.subtract(points_m_camera[..., i], position[i], out=to_point[..., i])
        x, y, z = to_point[..., 0], to_point[..., 1], to_point[..., 2]
        distance_m = x * x  # the squares summed in order, as np.einsum("...i,...i->...") sums them
        distance_m += y * y
        distance_m += z * z
        np.sqrt(distance_m, out=distance_m)
        np.maximum(distance_m, np.float32(0.05), out=distance_m)
        cos = to_point @ np.asarray(self.direction_camera, np.float32)
        del to_point
        cos /= distance_m
        inside = cos > np.float32(np.cos(self.cutoff_rad))
        cone = np.maximum(cos, 0, out=cos)
        cone **= np.float32(self.exponent)
        cone[~inside] = 0
        geometric = np.float32(REFERENCE_M) / distance_m
        geometric **= 2
        geometric *= cone
        return geometric, distance_m


def lit(
    lamps: tuple[Lamp, ...], points_m_camera: np.ndarray, attenuation_per_m: np.ndarray, planes: bool = False
) -> np.ndarray | int:
    """The lamps' irradiance summed (Lamp.irradiance, or irradiance_planes), 0 without lamps."""
    total: np.ndarray | int = 0
    for i, lamp in enumerate(lamps):
        each = (lamp.irradiance_planes if planes else lamp.irradiance)(points_m_camera, attenuation_per_m)
        if i == 0:
            total = each
        else:
            total += each
    return total


def rays(intrinsics: Intrinsics, step_px: int = 1) -> np.ndarray:
    """Unit vectors (h, w, 3) through the pixels' centres, in the camera's frame."""
    u = np.arange(0, intrinsics.width_px, step_px, dtype=np.float32) + 0.5 * step_px - 0.5
    v = np.arange(0, intrinsics.height_px, step_px, dtype=np.float32) + 0.5 * step_px - 0.5
    x = ((u - intrinsics.cx_px + 0.5) / intrinsics.fx_px)[None, :]
    y = ((v - intrinsics.cy_px + 0.5) / intrinsics.fy_px)[:, None]
    xyz = np.stack(np.broadcast_arrays(x, y, np.ones_like(x * y)), axis=-1)
    return (xyz / np.linalg.norm(xyz, axis=-1, keepdims=True)).astype(np.float32)


@functools.lru_cache(maxsize=8)
def _rays_z(intrinsics: Intrinsics) -> np.ndarray:
    """The rays' optical-axis components (h, w), made once per camera (read-only)."""
    z = np.ascontiguousarray(rays(intrinsics)[..., 2])
    z.flags.writeable = False
    return z


def range_of_depth(depth_m: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Range [m] along each pixel's ray from depth [m] along the optical axis."""
    return (depth_m / _rays_z(intrinsics)).astype(np.float32, copy=False)


class Optics:
    """One camera's underwater optics: coefficients, the lamps and the backscatter maps are fixed
    at start; `radiance` is the formation model, `image` the camera's picture of it."""

    def __init__(
        self,
        water: WaterType,
        intrinsics: Intrinsics,
        lamps: tuple[Lamp, ...],
        marine_snow: float = 1.0,
        backscatter_step_px: int = 8,
    ) -> None:
        self.water = water
        self.intrinsics = intrinsics
        self.lamps = lamps
        self.marine_snow = marine_snow
        self.beta_d = np.asarray(water.attenuation_per_m, np.float32)
        self.rays = rays(intrinsics)
        self.backscatter_inf, self.beta_b = self._backscatter(backscatter_step_px)
        self._backscatter_inf_planes = np.ascontiguousarray(np.moveaxis(self.backscatter_inf, -1, 0))
        self._minus_beta_b_planes = np.ascontiguousarray(np.moveaxis(-self.beta_b, -1, 0))

    def _backscatter(self, step_px: int) -> tuple[np.ndarray, np.ndarray]:
        """B_inf and beta_B per pixel and channel: the lamps' beams scattered into each ray,
        integrated along it (on a coarse grid of rays, then resized)."""
        coarse = rays(self.intrinsics, step_px)
        edges_m = np.geomspace(0.02, 60.0, 97, dtype=np.float32)
        s_m, ds_m = 0.5 * (edges_m[1:] + edges_m[:-1]), np.diff(edges_m)
        points = coarse[:, :, None, :] * s_m[:, None]  # (h, w, k, 3)
        irradiance = lit(self.lamps, points, self.beta_d)
        scatter = (
            np.asarray(self.water.scattering_per_m, np.float32) * BACKSCATTER_PHASE_PER_SR / LAMBERT_WHITE
        )
        dl = irradiance * scatter * np.exp(-s_m[:, None] * self.beta_d) * ds_m[:, None]  # (h, w, k, 3)
        cumulative = np.cumsum(dl, axis=2)
        total = cumulative[:, :, -1, :]
        half = np.argmax(cumulative >= 0.5 * total[:, :, None, :], axis=2)  # first knot past half
        beta_b = np.log(2.0) / np.maximum(edges_m[1:][half], 1e-3)
        size = (self.intrinsics.width_px, self.intrinsics.height_px)
        return (
            cv2.resize(total, size, interpolation=cv2.INTER_LINEAR),
            cv2.resize(beta_b.astype(np.float32), size, interpolation=cv2.INTER_LINEAR),
        )

    def radiance(self, rgb: np.ndarray, range_m: np.ndarray) -> np.ndarray:
        """The underwater radiance (h, w, 3) [1: a white face at REFERENCE_M in air] of the render
        `rgb` (h, w, 3, uint8) with `range_m` (h, w) along each ray."""
        # I = J * E * exp(-beta_D r) + B_inf * (1 - exp(-beta_B r)), in that order, a channel's
        # plane at a time (3, h, w) and in place: per-pixel factors broadcast over a contiguous
        # plane, not over pixels' three channels (numpy's slowest case, 2-3 ms a pass here)
        r = range_m.astype(np.float32, copy=False)
        points = np.empty(self.rays.shape, np.result_type(self.rays, r))
        for i in range(3):
            np.multiply(self.rays[..., i], r, out=points[..., i])
        irradiance = lit(self.lamps, points, self.beta_d, planes=True)
        del points
        direct = np.moveaxis(rgb, -1, 0).astype(np.float32)
        direct *= 1.0 / 255
        direct *= irradiance
        del irradiance
        attenuated = np.multiply.outer(-self.beta_d, r)
        direct *= np.exp(attenuated, out=attenuated)
        veil = self._minus_beta_b_planes * r
        np.exp(veil, out=veil)
        np.subtract(1.0, veil, out=veil)
        veil *= self._backscatter_inf_planes
        direct += veil
        return np.ascontiguousarray(np.moveaxis(direct, 0, -1))

    def image(self, rgb: np.ndarray, range_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """What the camera takes (h, w, 3, uint8): the radiance with marine snow, exposed, with
        sensor noise."""
        exposed = self.radiance(rgb, range_m)
        exposed += self.snow(range_m, rng)
        mean = float(exposed[::4, ::4].mean())
        gain = float(np.clip(EXPOSURE_TARGET / max(mean, 1e-6), *EXPOSURE_GAIN))
        exposed *= gain
        sigma = exposed * SHOT_NOISE
        sigma += (READ_NOISE * gain) ** 2
        np.sqrt(sigma, out=sigma)
        noisy = rng.standard_normal(exposed.shape, dtype=np.float32)
        noisy *= sigma
        noisy += exposed
        noisy *= 255
        noisy += 0.5
        return np.clip(noisy, 0, 255, out=noisy).astype(np.uint8)

    def snow(self, range_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Marine snow (h, w, 3) in radiance: particles uniform in the view's volume out to
        SNOW_RANGE_M, lit by the lamps, each covering its footprint (a pixel or a few), hidden
        behind the scene."""
        h, w = range_m.shape
        k = self.intrinsics
        near_m, far_m = SNOW_RANGE_M
        half_x, half_y = (w / 2) / k.fx_px, (h / 2) / k.fy_px  # frustum half-widths per metre of depth
        volume_m3 = 4 * half_x * half_y * (far_m**3 - near_m**3) / 3
        count = int(rng.poisson(self.water.snow_per_m3 * self.marine_snow * volume_m3))
        layer = np.zeros((h, w, 3), np.float32)
        if count == 0:
            return layer
        z = np.cbrt(near_m**3 + rng.random(count) * (far_m**3 - near_m**3))  # density uniform in volume
        x = (rng.random(count) * 2 - 1) * half_x * z
        y = (rng.random(count) * 2 - 1) * half_y * z
        diameter_m = rng.uniform(*SNOW_DIAMETER_M, count)
        u = np.clip((x / z * k.fx_px + k.cx_px).astype(int), 0, w - 1)
        v = np.clip((y / z * k.fy_px + k.cy_px).astype(int), 0, h - 1)
        points = np.stack((x, y, z), axis=1).astype(np.float32)
        distance_m = np.linalg.norm(points, axis=1)
        seen = distance_m < range_m[v, u]
        # a pale particle
        brightness = 0.7 * lit(self.lamps, points, self.beta_d) * np.exp(-self.beta_d * distance_m[:, None])
        footprint_px = k.fx_px * diameter_m / z
        small = seen & (footprint_px < 2.0)
        big = seen & ~small
        # a small particle spreads over a pixel and its blur; a big one over its own footprint
        area = np.minimum(footprint_px[small], 1.0)[:, None] ** 2
        np.add.at(layer, (v[small], u[small]), brightness[small] * area)
        blurred: np.ndarray = cv2.GaussianBlur(layer, (3, 3), 0.7)
        blurred *= 2.0
        if big.any():
            near_layer = np.zeros_like(layer)
            np.add.at(near_layer, (v[big], u[big]), brightness[big] * (footprint_px[big] ** 2)[:, None])
            blurred += cv2.GaussianBlur(near_layer, (0, 0), float(np.median(footprint_px[big])) / 2.5)
        return blurred
