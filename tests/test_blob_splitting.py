"""Issue 37 item 2: blobs that touching objects share are split (keypoint-to-model assignment,
then a watershed seeded by each object's keypoints), each region recognised; a blob of one
object is left whole. The splitters are components: swapped by name, measured."""

from __future__ import annotations

import numpy as np
import pytest

from pose.camera import CameraModel
from pose.recognition import AppearanceRecognizer
from pose.segmentation import components
from pose.splitting import (
    DistanceWatershedSplitter,
    KeypointWatershedSplitter,
    Region,
    SplitMemory,
    WholeComponents,
)
from pose.view import View
from scorbot_gym.envs.factory import make_env
from scorbot_gym.perception import make_pose_source
from scorbot_gym.perception.base import PerceptionFrame
from scorbot_gym.perception.splitters import make_splitter
from scorbot_gym.perception.training import train_models
from scorbot_gym.tasks.clutter import slide_into_contact

OBJECTS = ["box", "tomato_soup_can", "banana"]


def _two_discs(gap: int = 0) -> np.ndarray:
    """Two discs of radius 14 whose rims are ``gap`` pixels apart (0: they touch, one blob)."""
    yy, xx = np.mgrid[0:60, 0:100]
    a = (xx - 30) ** 2 + (yy - 30) ** 2 <= 14**2
    b = (xx - (59 + gap)) ** 2 + (yy - 30) ** 2 <= 14**2
    return a | b


# --- model-free parts -----------------------------------------------------------------------------
def test_whole_components_leave_every_blob_whole():
    image = np.zeros((60, 100, 3), np.uint8)
    comps = components(_two_discs(gap=10), min_area=10)
    regions = WholeComponents().split(image, comps, camera=None)
    assert [r.component for r in regions] == [0, 1]
    for r, c in zip(regions, comps, strict=True):
        assert np.array_equal(r.mask, c) and r.label is None
    with pytest.raises(ValueError, match="component 0 has shape"):
        WholeComponents().split(image, [np.ones((5, 5), bool)])


def test_distance_watershed_splits_two_touching_discs_and_leaves_one_whole():
    image = np.zeros((60, 100, 3), np.uint8)
    touching = components(_two_discs(gap=0), min_area=10)
    assert len(touching) == 1  # one blob for the two discs
    regions = DistanceWatershedSplitter(min_area=50).split(image, touching)
    assert len(regions) == 2
    areas = sorted(int(r.mask.sum()) for r in regions)
    assert abs(areas[0] - areas[1]) <= 0.1 * areas[1]  # cut at the neck, not anywhere
    assert not (regions[0].mask & regions[1].mask).any()
    assert np.array_equal(regions[0].mask | regions[1].mask, touching[0])
    yy, xx = np.mgrid[0:60, 0:100]
    disc = (xx - 40) ** 2 + (yy - 30) ** 2 <= 20**2
    (whole,) = DistanceWatershedSplitter().split(image, [disc])
    assert np.array_equal(whole.mask, disc)


class _CountingSplitter:
    """Splits every component into its left and right halves, counting the calls."""

    def __init__(self) -> None:
        self.calls = 0

    def split(self, image, comps, camera=None):
        self.calls += 1
        out = []
        for i, c in enumerate(comps):
            xs = np.nonzero(c)[1]
            left = c & (np.arange(c.shape[1]) < np.median(xs))[None, :]
            out += [Region(left, i, "a", 5, left), Region(c & ~left, i, "b", 5, c & ~left)]
        return out


def test_split_memory_reuses_the_split_of_an_unchanged_blob():
    image = np.zeros((60, 100, 3), np.uint8)
    blob = _two_discs(gap=0)
    inner = _CountingSplitter()
    memory = SplitMemory(inner, min_iou=0.9, min_area=10)
    first = memory.split(image, [blob])
    again = memory.split(image, [blob])
    assert inner.calls == 1 and [r.label for r in again] == ["a", "b"]
    assert sum(int(r.mask.sum()) for r in again) == int(blob.sum())
    moved = np.roll(blob, 30, axis=1)  # another blob: split afresh
    memory.split(image, [moved])
    assert inner.calls == 2
    memory.reset()
    memory.split(image, [moved])
    assert inner.calls == 3 and len(first) == 2
    with pytest.raises(ValueError, match="min_iou"):
        SplitMemory(inner, min_iou=0.0)


def test_splitters_by_name_and_their_errors():
    assert isinstance(make_splitter("none"), WholeComponents)
    assert isinstance(make_splitter("distance"), DistanceWatershedSplitter)
    with pytest.raises(ValueError, match="unknown splitter 'watershed'; valid: none, keypoints"):
        make_splitter("watershed")
    with pytest.raises(ValueError, match="needs the pose models"):
        make_splitter("keypoints")
    with pytest.raises(TypeError, match="has no split"):
        make_splitter(object())
    with pytest.raises(RuntimeError, match="before fit"):
        KeypointWatershedSplitter().split(np.zeros((4, 4, 3), np.uint8), [])
    with pytest.raises(ValueError, match="min_votes must be an int >= 1"):
        KeypointWatershedSplitter(min_votes=0).fit({})
    with pytest.raises(ValueError, match="training descriptors"):
        KeypointWatershedSplitter().fit({"box": object()})


def test_a_rollout_names_its_splitter():
    from scorbot_gym.evaluation.rollout import RolloutConfig

    config = RolloutConfig(pose="manifold_clutter", pose_model="m.npz", splitter="keypoints")
    assert config.pose_kwargs()["splitter"] == "keypoints"
    assert config.to_dict()["splitter"] == "keypoints"
    with pytest.raises(ValueError, match="splitter must be one of"):
        RolloutConfig(pose="manifold_clutter", splitter="magic")
    with pytest.raises(ValueError, match="only applies to the clutter pose sources"):
        RolloutConfig(pose="manifold", splitter="keypoints")
    from scorbot_gym.cli import build_parser
    from scorbot_gym.cli.rollout import config_from_args

    argv = ["rollout", "--pose", "manifold_clutter", "--distractors", "2"]
    argv += ["--splitter", "keypoints"]
    assert config_from_args(build_parser().parse_args(argv)).splitter == "keypoints"


# --- a rendered table with two objects touching in the top image ---------------------------------
@pytest.fixture(scope="module")
def models():
    return train_models(OBJECTS, n_views=72, progress=False)[0]


def _touch(sim, mover: str, still: str) -> None:
    assert slide_into_contact(sim, mover, still), f"{mover} never reached {still}"


def _true_masks(sim, camera: str, names) -> dict[str, np.ndarray]:
    """Each object's visible pixels in ``camera`` (the simulator's segmentation: scoring only)."""
    import mujoco

    out = sim.renderer.render(sim.model, sim.data, sim.camera_id(camera), "segmentation",
                              sim.render_width, sim.render_height)  # fmt: skip
    is_geom = out[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)
    return {n: is_geom & np.isin(out[..., 0], sim.objects[n].geoms) for n in names}


@pytest.fixture(scope="module")
def touching_scene(models):
    """Seeded table (target box + 2 distractors, 320 x 240), one distractor slid against the
    box: ``(frame, camera model, image, true masks, neighbour, info, source's env)``."""
    env = make_env(
        "ScorbotGrasp-v0", pose="manifold_clutter",
        pose_kwargs={"models": models, "recognizer": "appearance", "splitter": "keypoints"},
        objects=OBJECTS, distractors=2,
    )  # fmt: skip
    inner = env.env  # under the pose wrapper: its observation still holds the images
    obs, info = inner.reset(seed=1, options={"target": "box"})
    cams = {n: CameraModel(**p) for n, p in info["camera_params"].items()}
    backgrounds = dict(info["camera_background"])
    first = PerceptionFrame(obs, cams, "box", backgrounds=backgrounds)
    neighbour = next(n for n in info["objects"] if n != "box")
    sim = inner.unwrapped.sim
    _touch(sim, neighbour, "box")
    obs, *_, info = inner.step(np.zeros(6, np.float32))
    frame = PerceptionFrame(obs, cams, "box", step=1, backgrounds=backgrounds)
    truth = _true_masks(sim, "top", list(info["objects"]))
    yield first, frame, cams["top"], np.asarray(obs["top_rgb"]), truth, neighbour, info
    env.close()


def _best_iou(region: np.ndarray, truth: dict[str, np.ndarray]) -> tuple[str, float]:
    ious = {n: (region & m).sum() / max((region | m).sum(), 1) for n, m in truth.items()}
    name = max(ious, key=ious.get)
    return name, float(ious[name])


@pytest.mark.slow
def test_touching_objects_are_split_and_each_region_recognised(models, touching_scene):
    first, frame, cam, image, truth, neighbour, info = touching_scene
    src = make_pose_source("manifold_clutter", models=models, recognizer="appearance")
    src.reset(first, np.random.default_rng(0))
    comps = src.segmenter.blobs(frame, "top")
    assert len(comps) == len(info["objects"]) - 1  # box and its neighbour share one blob
    shared = next(i for i, c in enumerate(comps) if (c & truth["box"]).sum() > 100)
    assert (comps[shared] & truth[neighbour]).sum() > 100

    splitter = KeypointWatershedSplitter().fit(models.estimators)
    with pytest.raises(ValueError, match="needs the image's camera model"):
        splitter.split(image, comps)
    regions = splitter.split(image, comps, cam)
    parts = [r for r in regions if r.component == shared]
    assert len(parts) == 2
    recognise = AppearanceRecognizer(models.estimators)
    for part in parts:
        true_name, iou = _best_iou(part.mask, truth)
        assert iou > 0.7, (true_name, iou)  # its own object's pixels, not a cut anywhere
        assert part.label == true_name  # the keypoints that seeded it were its object's
        assert recognise.recognize(View(image, cam, part.mask)).label == true_name
    # a blob of one object only is left whole
    alone = [r for r in regions if r.component != shared]
    assert len(alone) == 1 and np.array_equal(alone[0].mask, comps[1 - shared])
    assert _best_iou(alone[0].mask, truth)[1] > 0.8


@pytest.mark.slow
def test_the_clutter_source_estimates_the_target_on_its_own_region(models, touching_scene):
    first, frame, cam, image, truth, neighbour, info = touching_scene
    src = make_pose_source(
        "manifold_clutter", models=models, recognizer="appearance", splitter="keypoints"
    )
    src.reset(first, np.random.default_rng(0))
    est = src.estimate(frame)
    assert est.valid, est.reason
    assert est.details["n_components"] == len(info["objects"]) - 1
    blobs = est.details["blobs"]
    assert len(blobs) == len(info["objects"])  # one region per object after splitting
    chosen = blobs[est.details["chosen"]]
    assert chosen["split_label"] == "box" and chosen["recognised"] == "box"
    assert chosen["area"] < truth["box"].sum() * 1.3  # the box's pixels, not its neighbour's
    truth_pos = np.asarray(info["object_pose"]["position"])
    assert np.linalg.norm(est.position - truth_pos) < 0.01
    assert est.timings_ms["segment_split"] >= 0.0


@pytest.mark.slow
def test_info_reports_blobs_before_and_after_splitting(models):
    """Through the env: ``info["perception"]`` counts the blobs before and after splitting and
    scores each region against the object under it."""
    env = make_env(
        "ScorbotGrasp-v0", pose="manifold_clutter",
        pose_kwargs={"models": models, "recognizer": "appearance", "splitter": "keypoints"},
        objects=OBJECTS, distractors=2,
    )  # fmt: skip
    try:
        _, info = env.reset(seed=1, options={"target": "box"})
        p = info["perception"]
        assert p["n_objects"] == 3 and p["n_blobs"] >= p["n_components"] >= 1
        assert all({"component", "split_label", "true_class"} <= set(b) for b in p["objects"])
        assert p["target_recognised"]
    finally:
        env.close()
