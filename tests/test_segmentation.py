"""Background subtraction: synthetic images, then rendered frames with the arm in view."""

import numpy as np
import pytest
from sklearn.exceptions import NotFittedError

from pose.camera import CameraModel
from pose.segmentation import BackgroundSubtractionSegmenter, fill_holes, mask_iou
from scorbot_gym.envs.factory import make_env
from scorbot_gym.perception.arm_mask import ArmMaskRenderer
from scorbot_gym.perception.base import PerceptionFrame
from scorbot_gym.perception.segmenters import BackgroundSegmenter, make_segmenter
from scorbot_gym.policies import ScriptedGraspPolicy


def _background(h=120, w=160, seed=0):
    rng = np.random.default_rng(seed)
    base = np.array([150, 140, 120], np.uint8)  # a grey-beige table with sensor noise
    return np.clip(base + rng.normal(0, 2, (h, w, 3)), 0, 255).astype(np.uint8)


def test_finds_a_coloured_object_and_ignores_noise():
    bg = _background()
    img = _background(seed=1)  # fresh noise: nothing else changed
    img[40:80, 50:90] = (200, 40, 40)
    seg = BackgroundSubtractionSegmenter().fit(bg)
    truth = np.zeros(bg.shape[:2], bool)
    truth[40:80, 50:90] = True
    assert mask_iou(seg.segment(img), truth) > 0.97


def test_excluded_pixels_are_removed_before_the_largest_component():
    bg = _background()
    img = bg.copy()
    img[10:30, 10:30] = (30, 160, 30)  # the object, small
    img[50:110, 60:150] = (40, 40, 40)  # the arm, larger
    arm = np.zeros(bg.shape[:2], bool)
    arm[50:110, 60:150] = True
    seg = BackgroundSubtractionSegmenter().fit(bg)
    assert seg.segment(img).sum() > 1000  # without exclusion the arm wins
    mask = seg.segment(img, exclude_mask=arm)
    truth = np.zeros_like(arm)
    truth[10:30, 10:30] = True
    assert mask_iou(mask, truth) > 0.95 and not (mask & arm).any()


def test_blank_frame_gives_an_empty_mask():
    bg = _background()
    seg = BackgroundSubtractionSegmenter().fit(bg)
    assert not seg.segment(bg).any()
    assert not seg.segment(_background(seed=3)).any()


def test_fill_holes_and_iou():
    ring = np.zeros((20, 20), bool)
    ring[5:15, 5:15] = True
    ring[8:12, 8:12] = False
    assert fill_holes(ring)[9, 9] and fill_holes(ring).sum() == 100
    assert mask_iou(ring, ring) == 1.0 and mask_iou(ring, ~ring) == 0.0
    assert mask_iou(np.zeros((2, 2)), np.zeros((2, 2))) == 1.0


def test_bad_input_is_a_clear_error():
    bg = _background()
    with pytest.raises(NotFittedError):
        BackgroundSubtractionSegmenter().segment(bg)
    with pytest.raises(ValueError, match="threshold"):
        BackgroundSubtractionSegmenter(threshold=-1).fit(bg)
    with pytest.raises(ValueError, match="kernel"):
        BackgroundSubtractionSegmenter(kernel=0).fit(bg)
    with pytest.raises(ValueError, match="uint8"):
        BackgroundSubtractionSegmenter().fit(bg.astype(float))
    seg = BackgroundSubtractionSegmenter().fit(bg)
    with pytest.raises(ValueError, match="background reference"):
        seg.segment(bg[:60])
    with pytest.raises(ValueError, match="exclude_mask"):
        seg.segment(bg, exclude_mask=np.zeros((3, 3), bool))
    with pytest.raises(ValueError, match="valid: background, depth, privileged"):
        make_segmenter("magic")


def _scripted_frames(cameras, image_types, **env_kwargs):
    """Frames along two scripted grasps (oracle pose), with the arm moving through the view:
    ``(obs, calibration by camera, background)`` every 8 steps; a camera on the arm sends its
    calibration with every step."""
    env = make_env(
        pose="oracle",
        cameras=cameras,
        image_width=320,
        image_height=240,
        image_types=image_types,
        objects=["box", "tomato_soup_can"],
        **env_kwargs,
    )
    frames = []
    for seed in (0, 1):
        obs, info = env.reset(seed=seed)
        policy = ScriptedGraspPolicy.for_env(env)
        policy.reset(obs, info)
        background = info.get("camera_background")
        params = dict(info["camera_params"])
        for t in range(40):
            if t % 8 == 0:
                frames.append((obs, dict(params), background))
            obs, _, term, trunc, info = env.step(policy.act(obs))
            params.update(info.get("camera_params", {}))
            if term or trunc:
                break
    env.close()
    return frames


@pytest.fixture(scope="module")
def grasp_frames():
    return _scripted_frames(
        ["top", "side"], ["rgb", "privileged_segmentation"], capture_background=True
    )


@pytest.mark.slow
def test_background_frames_are_the_empty_workspace(grasp_frames):
    obs, _, background = grasp_frames[0]
    for cam in ("top", "side"):
        ref = background[cam]
        assert ref["rgb"].shape == obs[f"{cam}_rgb"].shape and ref["joint_pos"].shape == (5,)
        obj = obs[f"{cam}_privileged_segmentation"][..., 0] > 0
        assert obj.any()
        changed = (ref["rgb"].astype(int) - obs[f"{cam}_rgb"]).any(axis=2)
        assert changed[obj].mean() > 0.9 and changed[~obj].mean() < 0.01  # only the object


@pytest.mark.slow
def test_arm_mask_matches_the_rendered_arm(grasp_frames):
    arm = ArmMaskRenderer()
    obs, params, _ = grasp_frames[2]
    cam = CameraModel(**params["top"])
    mask = arm.render(cam, obs["joint_pos"], obs["gripper_opening"])
    assert mask.shape == (240, 320) and mask.sum() > 500
    with pytest.raises(ValueError, match="joint_pos"):
        arm.render(cam, np.zeros(3))
    arm.close()


@pytest.mark.slow
def test_segmenter_on_rendered_frames_with_the_arm_in_view(grasp_frames):
    seg = BackgroundSegmenter()
    ious, arm_pixels = [], []
    for obs, params, background in grasp_frames:
        cameras = {c: CameraModel(**p) for c, p in params.items()}
        frame = PerceptionFrame(observation=obs, cameras=cameras, backgrounds=background)
        for cam in ("top", "side"):
            seg.reset(frame, cam)
            truth = obs[f"{cam}_privileged_segmentation"][..., 0] > 0
            mask = seg.segment(frame, cam)
            arm_pixels.append(seg.excluded(cam).sum())
            if truth.sum() >= 500:  # the object clearly visible (not under the gripper)
                ious.append(mask_iou(mask if mask is not None else np.zeros_like(truth), truth))
    assert min(arm_pixels) > 500  # the arm is in view in every frame
    assert len(ious) >= 10 and np.median(ious) > 0.9 and min(ious) > 0.6
    # a blank frame (the reference itself) has no object: None, no exception
    obs, params, background = grasp_frames[0]
    ref = background["top"]
    blank = {**obs, "top_rgb": ref["rgb"], "joint_pos": ref["joint_pos"]}
    frame = PerceptionFrame(
        observation=blank,
        cameras={c: CameraModel(**p) for c, p in params.items()},
        backgrounds=background,
    )
    seg.reset(frame, "top")
    assert seg.segment(frame, "top") is None


@pytest.mark.slow
def test_background_segmenter_needs_a_reference_frame(grasp_frames):
    obs, params, _ = grasp_frames[0]
    frame = PerceptionFrame(
        observation=obs, cameras={c: CameraModel(**p) for c, p in params.items()}
    )
    with pytest.raises(ValueError, match="capture_background=True"):
        BackgroundSegmenter().reset(frame, "top")


@pytest.fixture(scope="module")
def hand_camera_frames():
    """The hand camera (it moves) and the top camera along a scripted grasp, with depth."""
    frames = _scripted_frames(["top", "eye_in_hand"], ["rgb", "depth", "privileged_segmentation"])
    return [(obs, {c: CameraModel(**p) for c, p in params.items()}) for obs, params, _ in frames]


@pytest.mark.slow
def test_depth_segmenter_serves_a_moving_camera(hand_camera_frames):
    """Above-the-table pixels minus the arm: IoU with the true mask on the hand camera (its
    fingers in view) and on the top camera (the arm in view), with no reference frame."""
    seg = make_segmenter("depth")
    assert seg.image_types == ("depth",) and not seg.privileged
    ious = {"top": [], "eye_in_hand": []}
    for obs, cameras in hand_camera_frames:
        frame = PerceptionFrame(observation=obs, cameras=cameras)
        for cam in ious:
            seg.reset(frame, cam)
            mask = seg.segment(frame, cam)
            truth = obs[f"{cam}_privileged_segmentation"][..., 0] > 0
            ious[cam].append(mask_iou(mask if mask is not None else np.zeros_like(truth), truth))
            assert seg.excluded(cam).any()  # the arm (or its fingers) is in both views
    assert np.median(ious["eye_in_hand"]) > 0.9 and np.median(ious["top"]) > 0.9, ious


def test_height_segmenter_checks_its_input():
    from pose.segmentation import HeightAboveTableSegmenter

    down = np.diag([1.0, -1.0, -1.0, 1.0])  # optical axis along -z
    down[2, 3] = 1.0  # 1 m above the table (z = 0)
    K = np.array([[100.0, 0, 16], [0, 100.0, 12], [0, 0, 1]])
    cam = CameraModel(K=K, world_from_camera=down, width=32, height=24)
    depth = np.full((24, 32), 1.0)
    depth[8:16, 10:20] = 0.95  # a 5 cm block
    mask = HeightAboveTableSegmenter(min_area=4).segment(depth, cam)
    assert mask[8:16, 10:20].all() and mask.sum() == 80
    assert not HeightAboveTableSegmenter().segment(np.full((24, 32), 1.0), cam).any()
    with pytest.raises(ValueError, match="depth is 10x10 but the camera is 32x24"):
        HeightAboveTableSegmenter().segment(np.ones((10, 10)), cam)
    with pytest.raises(ValueError, match="min_height must be a positive"):
        HeightAboveTableSegmenter(min_height=-1).segment(depth, cam)
    with pytest.raises(ValueError, match="no valid pixel"):
        HeightAboveTableSegmenter().segment(np.zeros((24, 32)), cam)
