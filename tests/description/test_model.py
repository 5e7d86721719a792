"""The shared model: MuJoCo (world.xml, which includes robot.xml) and Pinocchio (robot.xml)
agree on the arm."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from abyss.description.robot import robot_at
from abyss.description.site import Site, shipped_sites, site_at, world_model

panel = site_at("").panel  # the shipped site's

ROBOT = robot_at("")  # the shipped robot package


@pytest.fixture(scope="module")
def models() -> tuple[mujoco.MjModel, pin.Model]:
    return world_model(ROBOT, site_at("")), pin.buildModelFromMJCF(str(ROBOT.model_file))


def test_forward_kinematics_and_jacobians_agree(models: tuple[mujoco.MjModel, pin.Model]) -> None:
    mj, pm = models
    md, pd = mujoco.MjData(mj), pm.createData()
    rng = np.random.default_rng(7)
    fid = pm.getFrameId(ROBOT.end_effector_site)
    arm_dofs_mj = [mj.joint(n).dofadr[0] for n in ROBOT.arm_joints]
    arm_dofs_pin = [pm.joints[pm.getJointId(n)].idx_v for n in ROBOT.arm_joints]
    for _ in range(50):
        position = rng.uniform(-5, 5, 3)
        quat_wxyz = rng.normal(size=4)
        quat_wxyz /= np.linalg.norm(quat_wxyz)
        arm = [rng.uniform(*mj.joint(n).range) for n in ROBOT.arm_joints]
        md.qpos[:] = mj.qpos0
        md.qpos[0:3], md.qpos[3:7] = position, quat_wxyz
        for name, value in zip(ROBOT.arm_joints, arm, strict=True):
            md.qpos[mj.joint(name).qposadr[0]] = value
        mujoco.mj_kinematics(mj, md)
        mujoco.mj_comPos(mj, md)
        q = pin.neutral(pm)
        q[0:3], q[3:7] = position, np.r_[quat_wxyz[1:], quat_wxyz[0]]  # Pinocchio: x, y, z, w
        for name, value in zip(ROBOT.arm_joints, arm, strict=True):
            q[pm.joints[pm.getJointId(name)].idx_q] = value
        pin.forwardKinematics(pm, pd, q)
        pin.updateFramePlacements(pm, pd)
        pin.computeJointJacobians(pm, pd, q)
        site = mj.site(ROBOT.end_effector_site).id
        np.testing.assert_allclose(pd.oMf[fid].translation, md.site_xpos[site], atol=1e-9)
        np.testing.assert_allclose(pd.oMf[fid].rotation, md.site_xmat[site].reshape(3, 3), atol=1e-9)
        jacp, jacr = np.zeros((3, mj.nv)), np.zeros((3, mj.nv))
        mujoco.mj_jacSite(mj, md, jacp, jacr, site)
        jac = pin.getFrameJacobian(pm, pd, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(jac[:3, arm_dofs_pin], jacp[:, arm_dofs_mj], atol=1e-9)
        np.testing.assert_allclose(jac[3:, arm_dofs_pin], jacr[:, arm_dofs_mj], atol=1e-9)
        for name in ("arm_link2", "arm_link4", "arm_link6"):
            np.testing.assert_allclose(
                pd.oMf[pm.getFrameId(name)].translation, md.xpos[mj.body(name).id], atol=1e-9
            )


def test_joint_limits_agree(models: tuple[mujoco.MjModel, pin.Model]) -> None:
    mj, pm = models
    for name in ROBOT.arm_joints:
        idx = pm.joints[pm.getJointId(name)].idx_q
        np.testing.assert_allclose(
            [pm.lowerPositionLimit[idx], pm.upperPositionLimit[idx]], mj.joint(name).range, atol=1e-12
        )


def test_the_panel_recognition_knows_is_the_panel_in_the_world(
    models: tuple[mujoco.MjModel, pin.Model], tmp_path
) -> None:  # type: ignore[no-untyped-def]
    import cv2

    from abyss.description.site import site_at

    world, _ = models
    assert np.allclose(world.body("panel").pos, panel.position_m_world)
    assert np.allclose(world.geom("panel_plate").size, panel.plate_half_size_m)
    face = world.geom("panel_face")
    assert face.pos[0] + face.size[0] <= -panel.plate_half_size_m[0] + 1e-9  # on the face towards -x
    for name, offset in (*panel.valves.items(), *panel.levers.items()):
        assert np.allclose(world.body(name).pos, offset), name
    panel.write_face_texture(tmp_path / "face.png")  # the shipped texture is the one drawn
    drawn = cv2.imread(str(tmp_path / "face.png"), cv2.IMREAD_GRAYSCALE)
    shipped = cv2.imread(str(site_at("").face_texture_file), cv2.IMREAD_GRAYSCALE)
    assert drawn is not None and shipped is not None and np.array_equal(drawn, shipped)


@pytest.mark.parametrize("site", shipped_sites(), ids=lambda site: site.directory.name)
def test_every_shipped_sites_face_texture_is_the_one_its_panel_draws(site: Site, tmp_path: Path) -> None:
    import cv2

    site.panel.write_face_texture(tmp_path / "face.png")
    drawn = cv2.imread(str(tmp_path / "face.png"), cv2.IMREAD_GRAYSCALE)
    shipped = cv2.imread(str(site.face_texture_file), cv2.IMREAD_GRAYSCALE)
    assert drawn is not None and shipped is not None and np.array_equal(drawn, shipped)


def test_the_arm_touches_nothing_of_the_robot_straight_or_stowed(
    models: tuple[mujoco.MjModel, pin.Model],
) -> None:
    """No contact at all with the arm straight or stowed and the vehicle in open water: a contact
    between two of the robot's own bodies there would press on the joints in every step."""
    mj, _ = models
    md = mujoco.MjData(mj)
    for pose_rad in (np.zeros(len(ROBOT.arm_joints)), np.array(ROBOT.stowed_rad)):
        md.qpos[:] = mj.qpos0
        md.qpos[0:3] = (0.0, 0.0, -5.0)  # in open water, 5 m above the seabed
        for name, value in zip(ROBOT.arm_joints, pose_rad, strict=True):
            md.qpos[mj.joint(name).qposadr[0]] = value
        mujoco.mj_forward(mj, md)
        touching = [
            (
                mj.body(mj.geom_bodyid[c.geom[0]]).name,
                mj.body(mj.geom_bodyid[c.geom[1]]).name,
                round(float(c.dist), 4),
            )
            for c in md.contact[: md.ncon]
        ]
        assert touching == [], (pose_rad, touching)
