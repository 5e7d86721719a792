"""The simulation's sensors in processes of their own (stations.simulation.offload): the child's
frames and pings are the ones the same state gives in this process, byte for byte; its CPU counts
in the station's; a Ctrl-C to the station's process group leaves it to its station; a child that
dies fails the loop naming the sensor instead of hanging it."""

from __future__ import annotations

import dataclasses
import signal

import mujoco
import numpy as np
import pytest

from abyss.common.workers import children_cpu_s
from abyss.config.simulation import SimulationConfig
from abyss.description.robot import robot_at
from abyss.interface.messages import Message
from abyss.stations.simulation.encoding import encode_image
from abyss.stations.simulation.offload import Offloaded, OffloadFailed, state_of
from abyss.stations.simulation.rendering import Cameras
from abyss.stations.simulation.sonar import ImagingSonar
from abyss.stations.simulation.world import World, references

ROBOT = robot_at("")  # the shipped robot package


def fields(message: Message) -> list[object]:
    """A message's fields, arrays as lists (comparable with ==)."""
    return [v.tolist() if isinstance(v, np.ndarray) else v for v in dataclasses.astuple(message)]


@pytest.fixture(scope="module")
def moved() -> tuple[SimulationConfig, World]:
    """A world some steps into a commanded motion (velocities, time and pose not at their start)."""
    config = SimulationConfig(water="I")  # the optics' random stream in play (snow, noise)
    world = World(config, np.random.default_rng(0))
    for _ in range(10):
        world.step(references(None, None), config.control_period_s)
    world.data.qpos[world.plant.qpos : world.plant.qpos + 3] += [0.3, -0.2, 0.1]
    return config, world


def test_the_childs_frames_and_pings_are_this_process_ones(moved: tuple[SimulationConfig, World]) -> None:
    config, world = moved
    state = state_of(world.data)
    data = mujoco.MjData(world.model)
    mujoco.mj_copyData(data, world.model, world.data)
    mujoco.mj_forward(world.model, data)
    cameras = Cameras(
        world.model,
        config.camera_width_px,
        config.camera_height_px,
        config.water,
        config.marine_snow,
        np.random.default_rng([7, 1]),
        depth_camera=ROBOT.depth_camera,
    )
    try:
        here = [encode_image(cameras, data, camera, config.jpeg_quality) for camera in ROBOT.cameras]
    finally:
        cameras.close()
    ping_here = ImagingSonar(world.model).message(data, np.random.default_rng([7, 2]))
    before_cpu_s = children_cpu_s()
    offloaded = Offloaded("cameras", world.model, config, [7, 1])
    sonar = Offloaded("sonar", world.model, config, [7, 2])
    try:
        offloaded.submit(state, set(), ROBOT.cameras, ROBOT)  # the child renders meanwhile
        sonar.process.send_signal(signal.SIGINT)  # a Ctrl-C in the station's terminal: its station ends it
        [(sonar_topic, ping_there)] = sonar.messages(state, set())
        topics, there = zip(*offloaded.collect(), strict=True)
        dark = [
            image for _, image in offloaded.messages(state, {"cam_left"}, ("cam_left", "cam_depth"), ROBOT)
        ]
    finally:
        offloaded.close()
        sonar.close()
    assert [image.camera for image in there] == list(ROBOT.cameras)
    assert list(topics) == [ROBOT.camera_topic(camera) for camera in ROBOT.cameras] and sonar_topic == "sonar"
    assert [fields(image) for image in there] == [fields(image) for image in here]  # pixels, pose, time
    assert fields(ping_there) == fields(ping_here)
    assert there[0].sim_time_s == pytest.approx(world.data.time) and there[0].sim_time_s > 0
    assert dark[0].data != there[0].data  # a blacked-out camera is dark there too
    assert [image.camera for image in dark] == ["cam_left", "cam_depth"]  # the cameras asked for alone
    assert children_cpu_s() > before_cpu_s  # what the children used counts in the station's CPU
    assert offloaded.process.returncode == 0 and sonar.process.returncode == 0  # closed, not killed


def test_a_child_that_dies_fails_the_loop_naming_the_sensor(moved: tuple[SimulationConfig, World]) -> None:
    config, world = moved
    sonar = Offloaded("sonar", world.model, config, [7, 2])
    sonar.process.kill()
    sonar.process.wait()
    with pytest.raises(OffloadFailed, match="the sonar process ended"):
        sonar.messages(state_of(world.data), set())
    sonar.close()
