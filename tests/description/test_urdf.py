"""Robot packages in URDF (description/urdf.py): the tests' minirov (urdf_package.py: xacro with macros,
an argument, a second package's include through ABYSS_PACKAGE_PATH, package:// meshes; every
name its own) loads, compiles with what robot.toml adds (the free joint, the sites, cameras,
motors and servos, the wet class), floats neutral, and Pinocchio, reading the MJCF robot_mjcf
writes, places the arm's frames where MuJoCo does; each kind of broken package is refused at
load naming robot.toml and the field."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from urdf_package import BOOM_M, KIT, PACKAGE, STICK_M, UrdfPackage, buoyancy, write_urdf_package

from abyss.common.errors import ConfigError
from abyss.description.robot import SHIPPED_ROBOT_DIR, Robot, load_robot, robot_mjcf, robot_spec
from abyss.description.ros_packages import PACKAGE_PATH_ENV, find_package, package_name
from abyss.stations.simulation.marine import geom_volume_m3, wet_geoms

RHO_KGPM3 = 1025.0


@pytest.fixture
def package(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> UrdfPackage:
    written = write_urdf_package(tmp_path)
    monkeypatch.setenv(PACKAGE_PATH_ENV, written.package_path)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return written


@pytest.fixture
def robot(package: UrdfPackage) -> Robot:
    return load_robot(package.directory)


def test_the_urdf_package_loads_with_its_own_names(package: UrdfPackage, robot: Robot) -> None:
    assert robot.arm_joints == package.arm_joints and robot.gripper_joints == package.gripper_joints
    assert robot.thrusters == package.thrusters and robot.cameras == package.cameras
    assert robot.end_effector_site == package.end_effector_site and robot.base == package.base
    assert robot.actuated_axes == (0, 1, 2, 5)  # surge, sway, heave, yaw from the six thrusters
    model = robot_spec(robot).compile()
    base = model.joint(package.base)
    assert base.type[0] == mujoco.mjtJoint.mjJNT_FREE and model.body(base.bodyid[0]).name == package.base
    assert model.nmesh == 2  # package://minirov_description/... and package://claw_kit/...
    # xacro's arguments: the boom's given (not its default, 0.3 m), the stick's required one
    assert model.body("stick").pos[0] == pytest.approx(BOOM_M)
    assert model.body("wrist").pos[0] == pytest.approx(STICK_M)


def test_robot_toml_adds_the_sites_cameras_motors_and_servos(package: UrdfPackage, robot: Robot) -> None:
    model = robot_spec(robot).compile()
    hull = model.body(package.base).id
    for name in package.thrusters:  # on the hull (their links fused into it), pushing along z
        motor = model.actuator(name)
        assert motor.trntype[0] == mujoco.mjtTrn.mjTRN_SITE and model.site(motor.trnid[0]).name == name
        assert model.site(name).bodyid[0] == hull
        np.testing.assert_allclose(motor.gear, [0, 0, 1, 0, 0, 0])
        np.testing.assert_allclose(motor.ctrlrange, [-50.0, 50.0])  # forward_max_n
    # prop_a's link yawed -45 degrees, its site's z along the link's x: forward and to the right
    rotation = model.site("prop_a").quat
    z_axis = np.zeros(3)
    mujoco.mju_rotVecQuat(z_axis, np.array([0.0, 0.0, 1.0]), rotation)
    np.testing.assert_allclose(z_axis, [math.sqrt(0.5), -math.sqrt(0.5), 0.0], atol=1e-6)
    for name in ("fls", "beacon", "doppler", "ahrs", "baro", package.end_effector_site):
        assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name) >= 0, name
    for name in package.cameras:
        assert model.camera(name).bodyid[0] == hull and model.cam_fovy[model.camera(name).id] == 70.0
    servos = {  # name: (kv, force limit, speed limit, armature): j1's force robot.toml's, others the URDF's
        "j1": (400.0, 30.0, 1.0, 0.2),
        "j2": (400.0, 40.0, 1.0, 0.2),
        "j4": (400.0, 10.0, 1.5, 0.2),
        "grip_a": (1000.0, 20.0, 0.05, 0.5),
    }
    for name, (kv, force, speed, armature) in servos.items():
        servo = model.actuator(name)
        assert servo.trntype[0] == mujoco.mjtTrn.mjTRN_JOINT and model.joint(servo.trnid[0]).name == name
        assert servo.gainprm[0] == kv and servo.biasprm[2] == -kv  # a velocity servo
        np.testing.assert_allclose(servo.forcerange, [-force, force])
        np.testing.assert_allclose(servo.ctrlrange, [-speed, speed])
        assert model.joint(name).armature[0] == armature


def test_the_collision_geoms_are_wet_and_the_vehicle_floats_neutral(robot: Robot) -> None:
    """Every link's collision geoms are wet (the default); the hull's mass is the water its wet
    geoms displace, [buoyancy] their volume and centroid; each arm link is neutral on its own."""
    model = robot_spec(robot).compile()
    wet = wet_geoms(model)
    assert np.all(model.geom_contype[wet] == 1) and not np.any(wet & (model.geom_contype == 0))
    volume_m3, centre = buoyancy()
    assert robot.spec.buoyancy["volume_m3"] == pytest.approx(volume_m3)
    for b in range(1, model.nbody):
        geoms = np.flatnonzero(wet & (model.geom_bodyid == b))
        volumes = np.array([geom_volume_m3(model.geom_type[g], model.geom_size[g]) for g in geoms])
        assert model.body_mass[b] == pytest.approx(RHO_KGPM3 * volumes.sum(), rel=1e-6), model.body(b).name
        if model.body(b).name == robot.base:
            assert volumes.sum() == pytest.approx(volume_m3)
            np.testing.assert_allclose(volumes @ model.geom_pos[geoms] / volumes.sum(), centre, atol=1e-9)
            assert model.body_ipos[b][2] < centre[2]  # the centre of gravity under that of buoyancy


def test_the_stowed_arm_touches_nothing_and_the_cameras_see_the_claw(robot: Robot) -> None:
    model = robot_spec(robot).compile()
    data = mujoco.MjData(model)
    for name, angle_rad in zip(robot.arm_joints, robot.stowed_rad, strict=True):
        data.qpos[model.joint(name).qposadr[0]] = angle_rad
    mujoco.mj_forward(model, data)
    assert data.ncon == 0
    claw = data.site_xpos[model.site(robot.end_effector_site).id]
    for name in robot.cameras:
        camera = model.camera(name).id
        looking = -data.cam_xmat[camera].reshape(3, 3)[:, 2]  # a camera looks along its -z
        to_claw = (claw - data.cam_xpos[camera]) / np.linalg.norm(claw - data.cam_xpos[camera])
        assert math.degrees(math.acos(looking @ to_claw)) < model.cam_fovy[camera] / 2, name


def test_a_world_fuses_nothing_yet_finds_the_fixed_links_fused(robot: Robot) -> None:
    """A world compiles the robot's spec under its own compiler, which fuses no static body:
    the spec comes with the URDF's fixed links already fused, its thrusters on the hull."""
    spec = robot_spec(robot)
    spec.compiler.fusestatic = False
    model = spec.compile()
    names = {model.body(b).name for b in range(model.nbody)}
    assert not names & {"pod", "eye_bar", "palm", "arm_mount", "prop_a_link"}
    assert all(model.body(model.site(n).bodyid[0]).name == robot.base for n in robot.thrusters)


def test_pinocchio_and_mujoco_place_the_arm_alike(package: UrdfPackage, robot: Robot, tmp_path: Path) -> None:
    mjcf = robot_mjcf(robot)
    assert mjcf.is_relative_to(tmp_path / "cache") and robot_mjcf(robot) == mjcf  # one file per content
    mj, pm = robot_spec(robot).compile(), pin.buildModelFromMJCF(str(mjcf))
    md, pd = mujoco.MjData(mj), pm.createData()
    rng = np.random.default_rng(3)
    for _ in range(5):
        position, quat_wxyz = rng.uniform(-3, 3, 3), rng.normal(size=4)
        quat_wxyz /= np.linalg.norm(quat_wxyz)
        md.qpos[:], q = mj.qpos0, pin.neutral(pm)
        md.qpos[0:3], md.qpos[3:7] = position, quat_wxyz
        q[0:3], q[3:7] = position, np.r_[quat_wxyz[1:], quat_wxyz[0]]  # Pinocchio: x, y, z, w
        for name in robot.arm_joints:
            angle_rad = rng.uniform(*mj.joint(name).range)
            md.qpos[mj.joint(name).qposadr[0]] = angle_rad
            q[pm.joints[pm.getJointId(name)].idx_q] = angle_rad
        mujoco.mj_kinematics(mj, md)
        pin.forwardKinematics(pm, pd, q)
        pin.updateFramePlacements(pm, pd)
        site = mj.site(robot.end_effector_site).id
        ee = pd.oMf[pm.getFrameId(robot.end_effector_site)]
        # MuJoCo writes the MJCF with six significant digits
        np.testing.assert_allclose(ee.translation, md.site_xpos[site], atol=1e-6)
        np.testing.assert_allclose(ee.rotation, md.site_xmat[site].reshape(3, 3), atol=1e-6)
        for name in robot.spec.arm.clearance_bodies:
            np.testing.assert_allclose(
                pd.oMf[pm.getFrameId(name)].translation, md.xpos[mj.body(name).id], atol=1e-6
            )


def test_wet_links_name_the_wet_ones(package: UrdfPackage) -> None:
    toml = package.directory / "robot.toml"
    toml.write_text(
        toml.read_text().replace('base = "hull"', 'base = "hull"\nwet_links = ["hull", "boom"]', 1)
    )
    model = robot_spec(load_robot(package.directory)).compile()
    wet_bodies = {model.body(b).name for b in model.geom_bodyid[wet_geoms(model)]}
    assert wet_bodies == {"hull", "boom"}  # the pod's box is the hull's now, and dry


def test_a_plain_urdf_loads_as_its_xacro_does(package: UrdfPackage, robot: Robot) -> None:
    """The xacro's output written as the package's model: the same model, package:// and all."""
    from abyss.description.ros_packages import xacro_text

    toml = package.directory / "robot.toml"
    xacro = package.directory / "urdf" / "minirov.urdf.xacro"
    plain = xacro.with_name("minirov.urdf")
    plain.write_text(
        xacro_text(
            xacro, {"boom_length_m": str(BOOM_M), "stick_length_m": str(STICK_M)}, package.directory, toml
        )
    )
    text = toml.read_text().replace("minirov.urdf.xacro", "minirov.urdf")
    toml.write_text("\n".join(line for line in text.splitlines() if not line.startswith("xacro_args")))
    copy = package.directory.parent / "plain"
    shutil.copytree(package.directory, copy)
    from_xacro, from_urdf = robot_spec(robot).compile(), robot_spec(load_robot(copy)).compile()
    assert from_urdf.nmesh == 2 and from_urdf.nbody == from_xacro.nbody and from_urdf.nu == from_xacro.nu
    np.testing.assert_array_equal(from_urdf.body_pos, from_xacro.body_pos)
    np.testing.assert_array_equal(from_urdf.body_mass, from_xacro.body_mass)


def test_packages_resolve_by_name_own_first_then_the_search_path(
    package: UrdfPackage, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert package_name(package.directory) == PACKAGE  # package.xml's name
    assert find_package(PACKAGE, package.directory) == package.directory
    assert find_package(KIT, package.directory) == Path(package.package_path).resolve() / KIT
    renamed = tmp_path / "elsewhere" / "kit_checkout"  # found by its package.xml's name
    shutil.copytree(Path(package.package_path) / KIT, renamed)
    monkeypatch.setenv(PACKAGE_PATH_ENV, f"{tmp_path / 'nothing'}:{renamed.parent}")
    assert find_package(KIT, package.directory) == renamed.resolve()
    assert find_package("no_such_pkg", package.directory) is None


def _broken(package: UrdfPackage, file: str, old: str, new: str) -> Path:
    path = package.directory / file
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new, 1))
    return package.directory


TOML, XACRO = "robot.toml", "urdf/minirov.urdf.xacro"
BROKEN = {  # (the file, its text, what it becomes, the field named, what is said)
    "a site on a link the URDF lacks": (TOML, 'link = "pod"', 'link = "skid"', "model.sites[9].link", "skid"),
    "a camera on a link the URDF lacks": (
        TOML,
        'link = "eye_bar"',
        'link = "mast"',
        "model.cameras[0].link",
        "mast",
    ),
    "a wet link the URDF lacks": (
        TOML,
        'base = "hull"',
        'base = "hull"\nwet_links = ["hull", "keel"]',
        "model.wet_links",
        "keel",
    ),
    "a base that is not the root link": (
        TOML,
        'base = "hull"',
        'base = "boom"',
        "model.base",
        "not the root link",
    ),
    "a thruster with no site": (TOML, 'name = "prop_f"', 'name = "prop_z"', "thrusters.names", "prop_f"),
    "a servo for a joint not the arm's": (
        TOML,
        "[model.servos.joints.j1]",
        "[model.servos.joints.pod_mount]",
        "model.servos.joints.pod_mount",
        "not one of",
    ),
    "a joint with no effort limit and no force_max": (
        XACRO,
        'effort="10" velocity="1.5"',
        'velocity="1.5"',
        "model.servos.joints.j4.force_max",
        "no effort limit",
    ),
    "a site given two orientations": (
        TOML,
        "zaxis = [0.0, 0.0, -1.0]",
        "zaxis = [0.0, 0.0, -1.0]\nxyaxes = [1, 0, 0, 0, 1, 0]",
        "model.sites[9]",
        "not both",
    ),
    "a missing xacro argument": (TOML, ', stick_length_m = "0.18"', "", "model.xacro_args", "stick_length_m"),
    "a missing mesh": (XACRO, "meshes/hull.stl", "meshes/hull_v2.stl", "model.file", "no such file"),
    "a package:// of no package": (
        XACRO,
        f"package://{PACKAGE}/",
        "package://minirov_meshes/",
        "model.file",
        "minirov_meshes",
    ),
    "a $(find) of no package": (XACRO, f"$(find {KIT})", "$(find gripper_kit)", "model.file", "gripper_kit"),
    "a URDF MuJoCo refuses": (
        XACRO,
        '<parent link="boom"/>',
        '<parent link="bom"/>',
        "model.file",
        "MuJoCo refuses",
    ),
    "a missing xacro include": (XACRO, "/urdf/claw.xacro", "/urdf/claws.xacro", "model.file", "claws.xacro"),
    "a site named twice": (
        TOML,
        'name = "ahrs"',
        'name = "beacon"',
        "model.sites",
        "beacon named more than once",
    ),
    "a model file of another kind": (
        TOML,
        'file = "urdf/minirov.urdf.xacro"',
        'file = "robot.toml"',
        "model.file",
        "*.urdf",
    ),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_a_broken_urdf_package_is_refused_naming_the_field(package: UrdfPackage, case: str) -> None:
    file, old, new, field, said = BROKEN[case]
    directory = _broken(package, file, old, new)
    with pytest.raises(ConfigError) as refused:
        load_robot(directory)
    assert refused.value.source == str(directory.resolve() / "robot.toml"), refused.value
    assert refused.value.field == field, refused.value
    assert said in refused.value.reason, refused.value


def test_a_package_out_of_the_search_path_is_refused(
    package: UrdfPackage, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(PACKAGE_PATH_ENV)
    with pytest.raises(ConfigError, match=rf"model\.file: .*\$\(find {KIT}\).*{PACKAGE_PATH_ENV} is unset"):
        load_robot(package.directory)


def test_an_mjcf_package_refuses_the_urdf_fields(tmp_path: Path) -> None:
    copy = tmp_path / "workclass"
    shutil.copytree(SHIPPED_ROBOT_DIR, copy)
    toml = copy / "robot.toml"
    toml.write_text(toml.read_text().replace('format = "mjcf"', 'format = "mjcf"\nwet_links = ["hull"]'))
    with pytest.raises(ConfigError) as refused:
        load_robot(copy)
    assert refused.value.field == "model.wet_links" and "URDF package's" in refused.value.reason


def test_the_docs_example_is_the_package_these_tests_write(tmp_path: Path) -> None:
    """docs/examples (docs/own-robot.md's worked example) holds exactly what write_urdf_package
    writes: the page's package is the one the tests load, check and fly."""
    examples = Path(__file__).resolve().parents[2] / "docs" / "examples"
    write_urdf_package(tmp_path)
    written = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    shipped = sorted(p.relative_to(examples) for p in examples.rglob("*") if p.is_file())
    assert written == shipped
    for relative in written:
        assert (tmp_path / relative).read_bytes() == (examples / relative).read_bytes(), relative


def test_the_sonar_is_the_site_robot_toml_names_and_a_robot_without_one_says_so(
    package: UrdfPackage, robot: Robot
) -> None:
    """The sonar's site was found by the name `sonar` alone: no field named it, the robot checked
    clean, and the simulation died at start. It is `[sonar] site` now (here "fls"); one named and
    missing is refused with the sites there are, and a robot without one runs with the sonar off
    (`simulation.sonar_rate_hz = 0`), refused at start otherwise."""
    from abyss.config import load
    from abyss.stations.simulation.sonar import ImagingSonar, SonarSpec

    assert robot.sonar_site == "fls" and robot.has_sonar
    model = robot_spec(robot).compile()
    sonar = ImagingSonar(model, SonarSpec(site=robot.sonar_site))  # what the simulation pings with
    assert model.site(sonar.site).name == "fls"
    text = (package.directory / "robot.toml").read_text()

    def variant(
        name: str, toml: str
    ) -> Path:  # the package again, another robot.toml (loads are cached per directory)
        directory = package.directory.with_name(name)
        shutil.copytree(package.directory, directory)
        (directory / "robot.toml").write_text(toml)
        return directory

    with pytest.raises(ConfigError) as refused:
        load_robot(variant("misnamed", text.replace('[sonar]\nsite = "fls"', '[sonar]\nsite = "fsl"')))
    assert refused.value.field == "sonar.site" and "fsl: no site of that name" in refused.value.reason
    assert "fls" in refused.value.reason and "doppler" in refused.value.reason  # the sites there are
    without = variant(
        "without", text.replace('[sonar]\nsite = "fls"\n', "").replace('name = "fls"', 'name = "fwd"')
    )
    assert not load_robot(without).has_sonar  # no [sonar], no site "sonar": a robot without one
    with pytest.raises(ConfigError) as refused:
        load(overrides=[f"simulation.robot={without}"])
    assert refused.value.field == "simulation.sonar_rate_hz" and "[sonar]" in refused.value.reason
    assert (
        load(overrides=[f"simulation.robot={without}", "simulation.sonar_rate_hz=0"]).simulation.sonar_rate_hz
        == 0
    )


def test_a_name_the_model_lacks_is_refused_with_the_names_there_are(package: UrdfPackage) -> None:
    toml = package.directory / "robot.toml"
    toml.write_text(toml.read_text().replace('joints = ["j1", "j2"', 'joints = ["j1", "j2x"', 1))
    with pytest.raises(ConfigError) as refused:
        load_robot(package.directory)
    assert refused.value.field == "arm.joints"
    assert "j2x: no joint of that name in the model (its joints: hull, j1, j2, j3" in refused.value.reason
