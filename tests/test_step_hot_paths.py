"""The env step's hot paths, made cheap, against the plain implementations they replaced: the
contact test (a loop over the few contacts instead of ``np.isin``), the IK loop (buffers
reused), and the pose scoring of ``info["perception"]`` (cached symmetry sets, bounded ADD-S
search)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from pose.metrics import add_s, rotation_error_deg
from pose.rotations import geodesic_deg
from pose.symmetry import Symmetry
from scorbot_gym.objects import CATALOGUE, get_object
from scorbot_gym.robot import JOINT_HIGH, JOINT_LOW, Robot, tool_pitch
from scorbot_gym.robot.kinematics import ArmKinematics
from scorbot_gym.sim import Simulation
from scorbot_gym.sim.arm import GRIPPER_MAX_OPENING, HOME_QPOS
from scorbot_gym.tasks import GraspTask


# --- the implementations before the speed-up, kept here as the reference -------------------
def _contacts_with_isin(robot: Robot, geoms: np.ndarray) -> tuple[bool, bool, bool]:
    d = robot.sim.data
    pairs = d.contact.geom[: d.ncon]
    if not len(pairs):
        return False, False, False
    g1, g2 = pairs[:, 0], pairs[:, 1]
    in1, in2 = np.isin(g1, geoms), np.isin(g2, geoms)
    other = np.where(in1, g2, np.where(in2, g1, -1))
    other = other[other >= 0]
    return (
        bool(np.isin(other, robot.finger_geoms[0]).any()),
        bool(np.isin(other, robot.finger_geoms[1]).any()),
        bool(np.isin(other, robot.link_geoms).any()),
    )


def _self_collision_isin(task: GraspTask) -> bool:
    d = task.sim.data
    pairs = d.contact.geom[: d.ncon]
    return bool(np.isin(pairs, task._arm_geoms).all(axis=1).any())


def _ik_textbook(kin: ArmKinematics, target_pos, pitch, q_init, iterations=60, damping=0.02):
    import mujoco

    m, d = kin.model, kin.data
    q = np.clip(np.array(q_init, dtype=float), JOINT_LOW, JOINT_HIGH)
    err = np.inf
    for _ in range(iterations):
        d.qpos[kin._qpos] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        e = np.r_[target_pos - d.site_xpos[kin._tcp], pitch - tool_pitch(q)]
        err = float(np.linalg.norm(e[:3]))
        if err < 1e-4 and abs(e[3]) < 1e-3:
            break
        mujoco.mj_jacSite(m, d, kin._jacp, None, kin._tcp)
        J = np.vstack([kin._jacp[:, kin._dof[:4]], [0.0, 1.0, 1.0, 1.0]])
        dq = J.T @ np.linalg.solve(J @ J.T + damping**2 * np.eye(4), e)
        scale = min(1.0, 0.3 / (np.abs(dq).max() + 1e-12))
        q[:4] = np.clip(q[:4] + scale * dq, JOINT_LOW[:4], JOINT_HIGH[:4])
    return q, err


# --- contacts ------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scene():
    sim = Simulation("tomato_soup_can")
    robot = Robot(sim)
    yield sim, robot, GraspTask(sim, robot)
    sim.close()


def test_contact_test_equals_the_isin_one_on_random_states(scene):
    """Random arm configurations, half with the object dropped into the gripper: every answer
    of the lookup-based contact test is the ``np.isin`` one, and every kind of contact occurs
    (fingers and links on the object, links on the table, the arm on itself)."""
    sim, robot, task = scene
    rng = np.random.default_rng(0)
    seen = np.zeros(5, int)  # left finger, right finger, link on the object; link on table; self
    for i in range(200):
        sim.reset()
        sim.data.qpos[robot.qpos_idx] = rng.uniform(JOINT_LOW, JOINT_HIGH)
        sim.data.qpos[robot.finger_qpos] = rng.uniform(0.0, GRIPPER_MAX_OPENING / 2, 2)
        sim.forward()
        if i % 2:
            sim.set_object_pose(robot.tcp_pos + rng.normal(0.0, 0.02, 3), [1.0, 0.0, 0.0, 0.0])
            sim.forward()
        on_object = robot.contacts_with(sim.object_geoms)
        on_table = robot.contacts_with(task._table_geom)
        assert on_object == _contacts_with_isin(robot, sim.object_geoms), i
        assert on_table == _contacts_with_isin(robot, task._table_geom), i
        assert task.self_collision() == _self_collision_isin(task), i
        seen += (*on_object, on_table[2], task.self_collision())
    assert (seen > 0).all(), seen  # every kind of contact was compared


def test_geom_set_is_cached(scene):
    sim, robot, _ = scene
    members = robot.geom_set(sim.object_geoms)
    assert members is robot.geom_set(np.array(sim.object_geoms))
    assert members == frozenset(sim.object_geoms.tolist())


# --- inverse kinematics --------------------------------------------------------------------
def test_ik_gives_the_textbook_loops_joint_angles_to_the_last_bit():
    fast, plain = ArmKinematics(), ArmKinematics()
    rng = np.random.default_rng(1)
    for i in range(150):
        q0 = np.asarray(HOME_QPOS) + rng.normal(0.0, 0.5, 5)
        target = fast.forward(q0)[0] + rng.normal(0.0, 0.02 if i % 2 else 0.2, 3)
        pitch, iterations = rng.uniform(-2.0, 0.0), (15, 60)[i % 2]
        q_a, err_a = fast.ik(target, pitch, q0, iterations=iterations)
        q_b, err_b = _ik_textbook(plain, target, pitch, q0, iterations=iterations)
        assert np.array_equal(q_a, q_b) and err_a == err_b, i


# --- pose scoring --------------------------------------------------------------------------
def test_symmetry_rotations_are_built_once_and_read_only():
    sym = Symmetry("axial", [0, 0, 1])  # lists are stored as tuples: hashable
    rots = sym.rotations()
    assert rots is Symmetry("axial", (0.0, 0.0, 1.0)).rotations() and rots.shape == (360, 3, 3)
    assert not rots.flags.writeable
    assert sym.rotations(10.0).shape == (36, 3, 3)


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_rotation_error_equals_the_minimum_over_every_symmetric_equivalent(name):
    sym = get_object(name).symmetry
    rng = np.random.default_rng(2)
    for i in range(20):
        R_gt = Rotation.random(random_state=i).as_matrix()
        R_est = Rotation.from_rotvec(rng.normal(0.0, 0.5, 3)).as_matrix() @ R_gt
        plain = geodesic_deg(R_est[None], R_gt[None] @ sym.rotations()).min()
        assert rotation_error_deg(R_est, R_gt, sym) == pytest.approx(plain, abs=1e-9)


@pytest.mark.parametrize("noise", [0.0, 1e-4, 1e-2, 0.3, 3.0])
def test_add_s_equals_the_unbounded_nearest_neighbour_mean(noise):
    pts = get_object("banana").mesh_vertices()[::10]
    tree = cKDTree(pts)
    rng = np.random.default_rng(3)
    for i in range(10):
        R_gt, t_gt = Rotation.random(random_state=i).as_matrix(), rng.normal(0.0, 0.3, 3)
        R_est = Rotation.from_rotvec(rng.normal(0.0, noise, 3)).as_matrix() @ R_gt
        t_est = t_gt + rng.normal(0.0, noise / 10, 3)
        est, gt = pts @ R_est.T + t_est, pts @ R_gt.T + t_gt
        plain = cKDTree(est).query(gt, k=1)[0].mean()
        assert add_s(R_est, t_est, R_gt, t_gt, pts) == pytest.approx(plain, abs=1e-12)
        assert add_s(R_est, t_est, R_gt, t_gt, pts, tree) == pytest.approx(plain, abs=1e-12)
