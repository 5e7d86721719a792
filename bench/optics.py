"""Underwater optics' cost per RGB frame at the configured camera size, from the default
mission's start pose (the panel 4 m off) and from its last waypoint (at arm's length):
- the plain render (MuJoCo, as with simulation.water = "none");
- the render with the optics: the plain render, a depth render of the same camera for the range,
  and the optics (the formation model, marine snow, exposure and noise), for a clear oceanic
  type (I) and a turbid coastal one (9C), with the optics' share on its own;
- the same through to the JPEG the station publishes (encoding.encode_image);
- the imaging sonar's image (stations/simulation/sonar.py), against the plain render.
Run: .venv/bin/python bench/optics.py. Prints figures; asserts nothing."""

from __future__ import annotations

import numpy as np

from abyss.stations.simulation.rendering import choose_gl_backend

choose_gl_backend()

from abyss.config.simulation import SimulationConfig  # noqa: E402
from abyss.description.robot import robot_at  # noqa: E402
from abyss.stations.simulation.encoding import encode_image  # noqa: E402
from abyss.stations.simulation.optics import range_of_depth  # noqa: E402
from abyss.stations.simulation.rendering import Cameras  # noqa: E402
from abyss.stations.simulation.sonar import ImagingSonar, SonarSpec  # noqa: E402
from abyss.stations.simulation.world import World  # noqa: E402
from scene import timed  # noqa: E402  (bench/ is on the path when a bench runs)

REPEATS = 5  # as scene.timed takes them
ROBOT = robot_at("")  # the shipped robot package
CAMERA = ROBOT.stereo_left


def main() -> None:
    sim = SimulationConfig()
    print(f"per {CAMERA} frame at {sim.camera_width_px}x{sim.camera_height_px} px, mean of {REPEATS}:")
    for where, position in (("start", sim.start_position_m_world), ("last waypoint", (3.2, 0.0, -8.0))):
        world = World(SimulationConfig(start_position_m_world=position), np.random.default_rng(0))
        plain = Cameras(
            world.model, sim.camera_width_px, sim.camera_height_px, depth_camera=ROBOT.depth_camera
        )
        plain_s = timed(lambda: plain.rgb(world.data, CAMERA))  # noqa: B023
        jpeg_s = timed(lambda: encode_image(plain, world.data, CAMERA, sim.jpeg_quality))  # noqa: B023
        print(f"  {where}: plain render {plain_s * 1e3:.1f} ms, to JPEG {jpeg_s * 1e3:.1f} ms")
        sonar, spec = ImagingSonar(world.model), SonarSpec()
        sonar_s = timed(lambda: sonar.image(world.data, np.random.default_rng(0)))  # noqa: B023
        print(
            f"    imaging sonar, {spec.beams} beams x {spec.rays_per_beam} rays, {spec.bins} bins: "
            f"{sonar_s * 1e3:.1f} ms ({sonar_s / plain_s:.2f}x the plain render)"
        )
        for water in ("I", "9C"):
            cameras = Cameras(
                world.model,
                sim.camera_width_px,
                sim.camera_height_px,
                water,
                rng=np.random.default_rng(0),
                depth_camera=ROBOT.depth_camera,
            )
            optics = cameras.optics(CAMERA)
            assert optics is not None
            rgb = cameras.plain_rgb(world.data, CAMERA)
            range_m = range_of_depth(cameras.depth_m(world.data, CAMERA), cameras.intrinsics(CAMERA))
            total_s = timed(lambda: cameras.rgb(world.data, CAMERA))  # noqa: B023
            optics_s = timed(lambda: optics.image(rgb, range_m, cameras.rng))  # noqa: B023
            encoded_s = timed(lambda: encode_image(cameras, world.data, CAMERA, sim.jpeg_quality))  # noqa: B023
            made_s = timed(
                lambda: Cameras(
                    world.model,  # noqa: B023
                    sim.camera_width_px,
                    sim.camera_height_px,
                    water,  # noqa: B023
                    depth_camera=ROBOT.depth_camera,
                ).optics(CAMERA),
                1,
            )
            print(
                f"    water {water}: render + depth + optics {total_s * 1e3:.1f} ms "
                f"({total_s / plain_s:.1f}x the plain render; the optics alone {optics_s * 1e3:.1f} ms), "
                f"to JPEG {encoded_s * 1e3:.1f} ms ({encoded_s / jpeg_s:.1f}x); "
                f"set up once per camera {made_s * 1e3:.0f} ms"
            )
            cameras.close()
        plain.close()


if __name__ == "__main__":
    main()
