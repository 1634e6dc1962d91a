"""Camera re-calibration from a known body's silhouette: synthetic spheres with exact masks and
depths first (pose/), then the rendered arm of a miscalibrated env (scorbot_gym)."""

import numpy as np
import pytest
from sklearn.base import BaseEstimator

from pose.calibration import SilhouetteExtrinsicsFilter, corrected
from pose.camera import CameraModel
from scorbot_gym.data.perturbations import Perturbation
from scorbot_gym.envs.factory import make_env
from scorbot_gym.evaluation.rollout import RolloutConfig
from scorbot_gym.perception.base import PerceptionFrame
from scorbot_gym.perception.calibration import ArmCalibration, make_calibration
from scorbot_gym.perception.segmenters import BackgroundSegmenter
from scorbot_gym.policies import ScriptedGraspPolicy
from scorbot_gym.sim.scene import TABLE_HEIGHT

W, H = 160, 120


def _camera() -> CameraModel:
    """Looking straight down from 0.6 m above the table plane z = 0 (image x = world y)."""
    K = np.array([[200.0, 0, W / 2], [0, 200.0, H / 2], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])  # camera z down
    T[:3, 3] = (0.0, 0.0, 0.6)
    return CameraModel(K, T, W, H, "top")


def _sphere(camera: CameraModel, centre: np.ndarray, radius: float):
    """Exact mask and optical-axis depth of a sphere seen by ``camera``."""
    v, u = np.mgrid[:H, :W]
    K = camera.K
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((H, W))], -1)
    c = camera.camera_from_world[:3, :3] @ centre + camera.camera_from_world[:3, 3]
    a = (rays * rays).sum(-1)
    b = (rays @ c) * -2.0
    disc = b * b - 4 * a * (c @ c - radius**2)
    hit = disc >= 0
    t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)  # the near intersection; z = t
    return hit, np.where(hit, t, 0.0)


def _table_error_mm(
    estimate: CameraModel, true: CameraModel, centre=(0.0, 0.0), table_z: float = 0.0
) -> float:
    """How far ``estimate`` places table points the ``true`` camera sees (worst of a 3 x 3 grid
    of 16 x 20 cm about ``centre``)."""
    pts = np.array(
        [[centre[0] + x, centre[1] + y, table_z] for x in (-0.08, 0, 0.08) for y in (-0.1, 0, 0.1)]
    )
    uv = true.project(pts)
    return float(np.abs(estimate.backproject_to_plane(uv, table_z) - pts).max() * 1e3)


def _run(delta_true: np.ndarray, frames: int = 40) -> tuple[SilhouetteExtrinsicsFilter, float]:
    nominal = _camera()
    true = corrected(nominal, delta_true)
    f = SilhouetteExtrinsicsFilter().reset(nominal)
    rng = np.random.default_rng(0)
    for _ in range(frames):  # a body moving about the workspace, at several heights
        centre = np.r_[rng.uniform(-0.08, 0.08), rng.uniform(-0.1, 0.1), rng.uniform(0.02, 0.3)]
        mask, depth = _sphere(f.camera, centre, 0.04)
        observed, _ = _sphere(true, centre, 0.04)
        f.update(mask, depth, observed)
    return f, _table_error_mm(nominal, true)


def test_a_miscalibrated_camera_is_recovered_from_silhouettes():
    delta = np.r_[0.004, -0.003, 0.003, np.deg2rad([0.6, -0.5, 0.3])]
    f, nominal_error = _run(delta)
    assert nominal_error > 5.0  # the error a grasp cannot take
    assert _table_error_mm(f.camera, corrected(_camera(), delta)) < 1.0
    assert f.n_frames_ == 40 and (f.std < np.r_[[0.01] * 3, [np.deg2rad(2)] * 3]).all()


def test_a_correct_calibration_stays_put():
    f, _ = _run(np.zeros(6))
    assert _table_error_mm(f.camera, _camera()) < 0.5


def test_a_foreground_edge_the_image_does_not_show_is_ignored():
    """The change mask also marks where the body stood when the reference frame was taken: an
    edge there is no edge of the body in this image. Given the image, such edges are skipped
    and a correct calibration stays put; from the mask alone they pull it off."""
    cam = _camera()
    errors = {}
    for with_image in (False, True):
        f = SilhouetteExtrinsicsFilter().reset(cam)
        rng = np.random.default_rng(1)
        for _ in range(30):
            centre = np.r_[rng.uniform(-0.08, 0.08), rng.uniform(-0.1, 0.1), rng.uniform(0.02, 0.3)]
            mask, depth = _sphere(f.camera, centre, 0.04)
            body, _ = _sphere(cam, centre, 0.04)
            ghost = np.roll(body, 6, axis=1)  # a stale outline 6 px beside the body's
            image = np.where(body, 60, 180).astype(np.uint8)  # the body dark on a light table
            f.update(mask, depth, body | ghost, image if with_image else None)
        errors[with_image] = _table_error_mm(f.camera, cam)
    assert errors[True] < 1.0 < 3.0 < errors[False], errors


def test_an_edge_many_pixels_off_does_not_pull_the_camera():
    """A pale part of the body that the change mask misses (against a pale table) puts the
    observed edge 15 px inside the body's along a quarter of its outline, every frame, and
    the image shows a step there (pale against dark): what the arm's light links do. Huber
    alone bounds each point's pull but not their common direction, and a correct calibration
    drifts by millimetres; with the residuals beyond ``reject_px`` given no weight it stays
    within one."""
    cam = _camera()
    v = np.mgrid[:H, :W][0]
    errors = {}
    for reject_px in (None, 6.0):
        f = SilhouetteExtrinsicsFilter(reject_px=reject_px).reset(cam)
        rng = np.random.default_rng(2)
        for _ in range(30):
            centre = np.r_[rng.uniform(-0.08, 0.08), rng.uniform(-0.1, 0.1), rng.uniform(0.02, 0.2)]
            mask, depth = _sphere(f.camera, centre, 0.06)
            body, _ = _sphere(cam, centre, 0.06)
            rows = v[body]
            lower = v > rows.mean() + 0.5 * (rows.max() - rows.mean())
            pale = body & ~np.roll(body, -15, axis=1) & lower  # 15 px of its lower right side
            image = np.where(body, np.where(pale, 150, 60), 180).astype(np.uint8)
            f.update(mask, depth, body & ~pale, image)
        errors[reject_px] = _table_error_mm(f.camera, cam)
    assert errors[6.0] < 1.0 < 3.0 < errors[None], errors


def test_a_frame_without_the_body_changes_nothing():
    f = SilhouetteExtrinsicsFilter().reset(_camera())
    empty = np.zeros((H, W), bool)
    assert f.update(empty, np.zeros((H, W)), empty) == 0
    assert f.camera is f.nominal_ and f.n_frames_ == 0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"memory_frames": 0.5}, "memory_frames"),
        ({"prior_rot_deg": 0}, "prior_rot_deg"),
        ({"search_px": 0}, "search_px"),
        ({"max_points": 2.5}, "max_points"),
        ({"contrast": -1.0}, "contrast"),
        ({"min_points": 2}, "min_points"),
        ({"reject_px": 0.0}, "reject_px"),
    ],
)
def test_bad_parameters_are_a_clear_error(kwargs, match):
    with pytest.raises(ValueError, match=match):
        SilhouetteExtrinsicsFilter(**kwargs).reset(_camera())


def test_mismatched_images_are_a_clear_error():
    f = SilhouetteExtrinsicsFilter().reset(_camera())
    with pytest.raises(ValueError, match="share one shape"):
        f.update(np.zeros((H, W), bool), np.zeros((H, W)), np.zeros((10, 10), bool))
    mask, depth = _sphere(_camera(), np.r_[0.0, 0.0, 0.1], 0.04)
    with pytest.raises(ValueError, match="uint8 RGB or grey image"):
        f.update(mask, depth, mask, np.zeros((H, W), np.float32))


def test_names_and_configuration_errors():
    assert make_calibration("none") is None and make_calibration(None) is None
    assert isinstance(make_calibration("arm"), ArmCalibration)
    with pytest.raises(ValueError, match="calibration must be one of none, arm"):
        make_calibration("magic")
    with pytest.raises(ValueError, match="segmenter 'background'"):
        RolloutConfig(pose="manifold", segmenter="privileged", calibration="arm")
    with pytest.raises(ValueError, match="pose 'manifold'"):
        RolloutConfig(pose="oracle", calibration="arm")
    with pytest.raises(ValueError, match="calibration must be one of"):
        RolloutConfig(pose="manifold", calibration="magic")
    with pytest.raises(ValueError, match="segmenter='background'"):
        ArmCalibration.check_segmenter(object())


def _grasp_frames(perturbation: Perturbation | None, steps: int = 30):
    """A scripted grasp of the box (oracle pose) seen by the top camera: the reset's frame,
    then each step's, with the nominal calibration; and the true camera (the test's truth)."""
    env = make_env(
        pose="oracle",
        cameras=["top"],
        image_width=320,
        image_height=240,
        capture_background=True,
        objects=["box"],
        perturbation=perturbation,
    )
    obs, info = env.reset(seed=0)
    policy = ScriptedGraspPolicy.for_env(env)
    policy.reset(obs, info)
    nominal = CameraModel(**info["camera_params"]["top"])
    true = env.unwrapped.sim.camera_model("top", 320, 240)  # the test's truth only
    frames = [PerceptionFrame(obs, {"top": nominal}, backgrounds=info["camera_background"])]
    for _ in range(steps):
        obs, *_ = env.step(policy.act(obs))
        raw = env.unwrapped._observation()  # the images the oracle-wrapped env does not pass on
        frames.append(PerceptionFrame(observation=raw, cameras={"top": nominal}))
    env.close()
    return frames, true


def _calibrated(frames, calibration: ArmCalibration) -> list[CameraModel]:
    """The top camera ``calibration`` answers at each step after the reset."""
    segmenter = BackgroundSegmenter()
    segmenter.reset(frames[0], "top")
    calibration.reset(frames[0], ("top",), segmenter)
    return [calibration.update(f, segmenter).cameras["top"] for f in frames[1:]]


def test_the_arm_recalibrates_a_miscalibrated_env_camera():
    """The rendered arm of a real grasp, the top camera moved by a calibration error the
    estimator is not told of: its table points land where the true camera's do. The nominal
    camera is answered until the correction matters, the estimate from then on."""
    frames, true = _grasp_frames(Perturbation(camera_rot_deg=1.0, camera_pos_m=0.005, seed=3))
    answered = _calibrated(frames, ArmCalibration())
    nominal = frames[0].cameras["top"]
    switched = [cam is not nominal for cam in answered]
    assert switched[-1] and switched == sorted(switched)  # nominal, then corrected for good
    where = dict(centre=(0.28, 0.0), table_z=TABLE_HEIGHT)  # the placement region
    before = _table_error_mm(nominal, true, **where)
    after = _table_error_mm(answered[-1], true, **where)
    assert before > 4.0 and after < 0.4 * before, (before, after)


def test_a_correct_env_calibration_is_left_alone():
    """No calibration error: the silhouette's estimate wanders by a millimetre or so, under
    ``min_correction_m``, and the cameras answered are the nominal ones throughout."""
    frames, _ = _grasp_frames(None)
    answered = _calibrated(frames, ArmCalibration())
    assert all(cam is frames[0].cameras["top"] for cam in answered)
    with pytest.raises(ValueError, match="min_correction_m"):
        ArmCalibration(min_correction_m=-1.0)


class _TurnedAbout(BaseEstimator):
    """A stand-in filter whose estimate, after any update, is the nominal camera turned by
    ``angle_deg`` about the vertical through the world point ``about``: a correction that
    leaves that point where it was and moves points away from it (as a small wander of the
    rotation estimate moves the placement region's far corners)."""

    def __init__(self, angle_deg: float = 2.0, about: tuple = (0.28, 0.0, TABLE_HEIGHT)):
        self.angle_deg = angle_deg
        self.about = about

    def reset(self, camera: CameraModel) -> "_TurnedAbout":
        self.nominal_ = self.camera = camera
        return self

    def update(self, *frame) -> int:
        a, p = np.deg2rad(self.angle_deg), np.asarray(self.about, float)
        turn = np.eye(4)
        turn[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
        turn[:3, 3] = p - turn[:3, :3] @ p
        n = self.nominal_
        self.camera = CameraModel(n.K, turn @ n.world_from_camera, n.width, n.height, n.name)
        return 100


class _NoArm:
    """A segmenter stand-in: empty masks, no arm (the stand-in filter reads none of them)."""

    def __init__(self):
        self.arm = self

    def render(self, camera, joint_pos, opening):
        return np.zeros((H, W), bool)

    def render_with_depth(self, camera, joint_pos, opening):
        return np.zeros((H, W), bool), np.zeros((H, W))

    def foreground(self, frame, camera):
        return np.zeros((H, W), bool)


@pytest.mark.parametrize(
    "at, switched",
    [
        ((0.28, 0.0, TABLE_HEIGHT), False),  # the object where the turn leaves it
        ((0.40, 0.15, TABLE_HEIGHT), True),  # an object far from it
        (None, True),  # no estimate yet: the placement region's far corners
    ],
)
def test_the_correction_is_switched_on_by_what_it_does_at_the_object(at, switched):
    """``min_correction_m`` is measured where the object was last estimated: a correction that
    moves the region's corners by millimetres but leaves the object in place keeps the
    nominal camera."""
    above = _camera()  # moved over the placement region
    T = above.world_from_camera.copy()
    T[:3, 3] = (0.28, 0.0, TABLE_HEIGHT + 0.6)
    nominal = CameraModel(above.K, T, W, H, "top")
    zeros = {"joint_pos": np.zeros(5), "gripper_opening": np.zeros(1)}
    first = PerceptionFrame(zeros, {"top": nominal}, backgrounds={"top": zeros})
    frame = PerceptionFrame({**zeros, "top_rgb": np.zeros((H, W, 3), np.uint8)}, {"top": nominal})
    calibration = ArmCalibration(_TurnedAbout(), min_correction_m=0.003)
    calibration.reset(first, ("top",), _NoArm())
    answered = calibration.update(frame, _NoArm(), None if at is None else np.array(at))
    assert (answered.cameras["top"] is not nominal) == switched


@pytest.mark.slow
def test_the_manifold_source_grasps_through_a_miscalibrated_camera(tmp_path):
    """The box under a 1 degree / 5 mm calibration error of the top camera (one that moves the
    box's image by 11 mm on the table), the scripted
    controller grasping from the manifold source's estimates (small PnP models): re-calibrated
    from the arm, the estimates it grasps from sit where the box is; as calibrated, they are
    off by the error's projection. While the arm hides the box, the last estimate is answered
    again through the camera as calibrated now."""
    from dataclasses import replace

    from scorbot_gym.perception.training import IN_LOOP_TRAINING, train_models

    small = replace(IN_LOOP_TRAINING, yaw_step_deg=30.0, tilted_views=48)
    models, _ = train_models(["box"], progress=False, cache_dir=str(tmp_path), training=small)
    errors, reasons = {}, {}
    for calibration in ("none", "arm"):
        env = make_env(
            "ScorbotGrasp-v0",
            pose="manifold",
            pose_kwargs={"models": models, "calibration": calibration},
            objects=["box"],
            perturbation=Perturbation(camera_rot_deg=1.0, camera_pos_m=0.005, seed=6),
        )
        obs, info = env.reset(seed=0)
        policy = ScriptedGraspPolicy.for_env(env)
        policy.reset(obs, info)
        valid, reasons[calibration] = [], []
        for _ in range(60):  # through the approach and the descent
            obs, _, term, trunc, info = env.step(policy.act(obs))
            rec = info["perception"]
            if rec["valid"]:
                valid.append(rec["pos_err_cm"])
                reasons[calibration].append(rec["reason"])
            if term or trunc:
                break
        env.close()
        errors[calibration] = float(np.median(valid[-10:]))
    assert errors["none"] > 0.8 and errors["arm"] < 0.6 * errors["none"], errors
    assert any(r.startswith("re-calibrated") for r in reasons["arm"]), reasons["arm"]
    assert not any(r.startswith("re-calibrated") for r in reasons["none"])
