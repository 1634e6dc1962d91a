"""Placing a moved object from its silhouette where no pose estimate is possible."""

import numpy as np
import pytest
import trimesh

from pose.metrics import rotation_error_deg
from scorbot_gym.objects import get_object
from scorbot_gym.perception.motion import SilhouetteMotion, _hull_centre, make_motion
from scorbot_gym.sim import Simulation
from scorbot_gym.sim.simulation import quat_from_yaw, quat_mul, quat_to_mat


@pytest.fixture(scope="module")
def pushed_duplo():
    """A Duplo brick's side-camera mask after a 3.6 cm push, and its pose before and after."""
    sim = Simulation("lego_duplo", render_width=320, render_height=240)
    before, quat = sim.resting_pose((0.28, -0.01), 0.4)
    after = before + np.array([-0.02, 0.03, 0.0])
    masks = {}
    for key, pos in (("before", before), ("after", after)):
        sim.set_object_pose(pos, quat)
        sim.forward()
        masks[key] = sim.render("side", "segmentation")
    camera = sim.camera_model("side")
    sim.close()
    hull = trimesh.convex.convex_hull(get_object("lego_duplo").mesh_vertices()).vertices
    return masks, camera, before, after, quat_to_mat(quat), np.asarray(hull)


def test_a_pushed_object_is_placed_from_its_silhouette(pushed_duplo):
    masks, camera, before, after, R, hull = pushed_duplo
    assert 30 < masks["after"].sum() < 2000  # a few keypoints' worth: too small to estimate
    moved = SilhouetteMotion().moved_pose(masks["after"], None, camera, before, R, hull)
    assert moved is not None
    assert np.linalg.norm(moved[0] - after) < 0.001  # 0.2 mm when written
    # what sliding the model's silhouette corrects: the mask centre itself lifted onto the
    # plane misses the object's centre (8.7 mm when written; an oblique view's centroid is
    # not the projection of the object's centre)
    ys, xs = np.nonzero(masks["after"])
    raw = camera.backproject_to_plane(_hull_centre(np.c_[xs, ys].astype(np.float32))[None],
                                      before[2])[0]  # fmt: skip
    assert np.linalg.norm(raw - after) > 0.005


def test_no_move_no_answer_and_hidden_silhouettes_are_not_used(pushed_duplo):
    masks, camera, before, _, R, hull = pushed_duplo
    motion = SilhouetteMotion(min_shift_m=0.015)
    assert motion.moved_pose(masks["before"], None, camera, before, R, hull) is None
    touching_arm = masks["after"]  # an excluded region over the silhouette: the arm may hide it
    assert motion.moved_pose(masks["after"], touching_arm, camera, before, R, hull) is None
    assert motion.moved_pose(None, None, camera, before, R, hull) is None


def test_motion_by_name_and_bad_parameters():
    assert isinstance(make_motion("silhouette"), SilhouetteMotion)
    assert make_motion(None) is None
    with pytest.raises(ValueError, match="unknown motion detector 'optical'; valid: silhouette"):
        make_motion("optical")
    with pytest.raises(ValueError, match="min_shift_m must be a positive"):
        SilhouetteMotion(min_shift_m=float("nan"))
    with pytest.raises(ValueError, match="min_area must be >= 1"):
        SilhouetteMotion(min_area=0)
    with pytest.raises(ValueError, match="turns_deg must be finite angles"):
        SilhouetteMotion(turns_deg=(0, 400))
    with pytest.raises(ValueError, match="min_gain must be an IoU gain"):
        SilhouetteMotion(min_gain=-0.1)


def test_rollout_configuration_checks_the_motion_detector():
    from scorbot_gym.evaluation.rollout import RolloutConfig

    with pytest.raises(ValueError, match="unknown motion detector 'optical'"):
        RolloutConfig(pose="manifold", motion="optical")
    with pytest.raises(ValueError, match="motion only applies to pose 'manifold', not 'oracle'"):
        RolloutConfig(pose="oracle", motion="silhouette")
    assert RolloutConfig(pose="manifold", motion="silhouette").to_dict()["motion"] == "silhouette"


@pytest.fixture(scope="module")
def pushed_and_turned():
    """Side-camera masks of a marker and a Duplo brick pushed 3.6 cm and turned 30 deg."""
    out = {}
    for name in ("large_marker", "lego_duplo"):
        sim = Simulation(name, render_width=320, render_height=240)
        before, quat = sim.resting_pose((0.28, -0.01), 0.4)
        after = before + np.array([-0.02, 0.03, 0.0])
        turned = quat_mul(quat_from_yaw(np.deg2rad(30.0)), quat)
        sim.set_object_pose(after, turned)
        sim.forward()
        mask = sim.render("side", "segmentation")
        camera = sim.camera_model("side")
        sim.close()
        hull = trimesh.convex.convex_hull(get_object(name).mesh_vertices()).vertices
        out[name] = (mask, camera, before, after, quat_to_mat(quat), quat_to_mat(turned), hull)
    return out


@pytest.mark.parametrize("name", ["large_marker", "lego_duplo"])
def test_a_pushed_and_turned_object_gets_its_new_heading(pushed_and_turned, name):
    mask, camera, before, after, R, turned, hull = pushed_and_turned[name]
    spec = get_object(name)
    pos, R_new = SilhouetteMotion().moved_pose(mask, None, camera, before, R, hull)
    assert np.linalg.norm(pos - after) < 0.003
    assert rotation_error_deg(R_new, turned, spec.symmetry) <= 5.0
    assert rotation_error_deg(R, turned, spec.symmetry) > 25.0  # the held heading was off
    held = SilhouetteMotion(turns_deg=()).moved_pose(mask, None, camera, before, R, hull)
    np.testing.assert_allclose(held[1], R)  # the ablation keeps the heading


def test_an_object_symmetric_about_the_vertical_keeps_its_heading():
    sim = Simulation("tomato_soup_can", render_width=320, render_height=240)
    before, quat = sim.resting_pose((0.28, -0.01), 0.4)
    sim.set_object_pose(before + np.array([0.03, 0.0, 0.0]), quat)
    sim.forward()
    mask, camera = sim.render("side", "segmentation"), sim.camera_model("side")
    sim.close()
    hull = trimesh.convex.convex_hull(get_object("tomato_soup_can").mesh_vertices()).vertices
    R = quat_to_mat(quat)
    moved = SilhouetteMotion().moved_pose(mask, None, camera, before, R, hull)
    assert moved is not None
    np.testing.assert_allclose(moved[1], R)  # every turn looks the same: no gain, none taken
