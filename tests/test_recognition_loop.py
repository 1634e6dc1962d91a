"""Recognition: fusion and memory on synthetic silhouettes, then in the loop with real models."""

import gymnasium as gym
import numpy as np
import pytest

from pose.camera import CameraModel
from pose.recognition import (
    AppearanceRecognizer,
    DescriptorVoteRecognizer,
    Recognition,
    RecognitionMemory,
    ShortlistRecognizer,
    SilhouetteRecognizer,
    view_is_clear,
)
from pose.shape.silhouettes import synthetic_dataset
from pose.view import View
from scorbot_gym.envs.factory import make_env
from scorbot_gym.evaluation import run_episodes, summarize
from scorbot_gym.perception.model_set import ModelSetPoseSource
from scorbot_gym.perception.recognizers import train_silhouette_recognizer
from scorbot_gym.perception.training import train_models
from scorbot_gym.policies import ScriptedGraspPolicy
from scorbot_gym.wrappers.pose_observation import PoseEstimateObservation

OBJECTS = ["box", "tomato_soup_can"]


def test_costs_margin_and_memory():
    r = Recognition.from_costs({"a": 0.5, "b": 0.1, "c": np.inf})
    assert r.label == "b" and r.margin == pytest.approx(0.4)
    assert Recognition.from_costs({"a": np.inf}).label is None
    memory = RecognitionMemory(min_margin=0.2)
    assert not memory.offer(r, clear=False) and memory.label_for(r) == "b"  # used, not kept
    assert not memory.offer(Recognition.from_costs({"a": 0.0, "b": 0.1}), clear=True)
    assert memory.offer(r, clear=True) and memory.kept is r
    assert memory.label_for(Recognition.from_costs({"a": 0.0, "b": 9.0})) == "b"  # kept wins
    memory.reset()
    assert memory.label_for(None) is None
    with pytest.raises(ValueError, match="min_margin"):
        RecognitionMemory(min_margin=-1)


def test_view_is_clear():
    mask = np.zeros((60, 80), bool)
    mask[20:40, 30:50] = True
    assert view_is_clear(mask, min_area=100)
    assert not view_is_clear(mask, min_area=1000)
    arm = np.zeros_like(mask)
    arm[41:, :] = True  # touches the silhouette's lower edge
    assert not view_is_clear(mask, arm, min_area=100)
    edge = np.zeros_like(mask)
    edge[0:20, 0:20] = True
    assert not view_is_clear(edge, min_area=100) and not view_is_clear(None)


def test_silhouette_recognizer_fuses_cameras():
    train, test = synthetic_dataset(12, seed=0), synthetic_dataset(5, seed=1)
    cams = {"a": train.masks, "b": train.masks[::-1]}
    labels = {"a": train.labels, "b": train.labels[::-1]}
    rec = SilhouetteRecognizer().fit(cams, labels)
    assert rec.cameras == ("a", "b")
    right = [
        rec.recognize({"a": m, "b": m}).label == y
        for m, y in zip(test.masks, test.labels, strict=True)
    ]
    assert np.mean(right) > 0.9
    assert rec.recognize({"a": None, "b": np.zeros((9, 9))}).label is None
    with pytest.raises(ValueError, match="masks but"):
        SilhouetteRecognizer().fit({"a": train.masks}, {"a": train.labels[:3]})


class _Shape:
    """A silhouette recogniser with fixed class costs."""

    reads = "silhouettes"

    def __init__(self, costs):
        self.costs = costs

    def recognize(self, masks):
        return Recognition.from_costs(self.costs)


class _Estimator:
    def __init__(self, inliers, asked):
        self.inliers, self.asked = inliers, asked

    def predict(self, view):
        self.asked.append(self)
        return type("Est", (), {"valid": self.inliers > 0, "n_inliers": self.inliers})()


def test_shortlist_lets_appearance_decide_among_the_shape_classifiers_best():
    asked = []
    inliers = {"can": 5, "ball": 40, "cylinder": 0, "banana": 99}
    appearance = AppearanceRecognizer(
        {k: _Estimator(v, asked) for k, v in inliers.items()}, fallback=None
    )
    shape = _Shape({"can": 0.0, "ball": 0.2, "cylinder": 0.3, "banana": 5.0})
    rec = ShortlistRecognizer(shape, appearance, k=3)
    result = rec.recognize({"top": None}, view=object())
    assert result.label == "ball"  # the most inliers among the 3 best outlines
    assert len(asked) == 3  # the banana's model was never run
    none_valid = ShortlistRecognizer(shape, appearance, k=1)
    none_valid.silhouettes = _Shape({"cylinder": 0.0, "can": 1.0})
    assert none_valid.recognize({}, view=object()).label == "cylinder"  # the outline stands
    blind = ShortlistRecognizer(_Shape({"can": np.inf}), appearance)
    assert blind.recognize({}, view=object()).label == "banana"  # no outline: all by appearance
    with pytest.raises(ValueError, match="shortlist"):
        ShortlistRecognizer(shape, appearance, k=0)


@pytest.fixture(scope="module")
def models():
    return train_models(OBJECTS, n_views=72, progress=False)[0]


@pytest.fixture(scope="module")
def flr(models):
    return train_silhouette_recognizer(OBJECTS, ["top", "side"], 320, 240, n_per_object=40)


def _env(models, recognizer, cameras=None, estimate_every=4):
    return make_env(
        pose="manifold",
        pose_kwargs={"models": models, "segmenter": "background", "recognizer": recognizer},
        identity="recognize",
        pose_cameras=cameras,
        objects=OBJECTS,
        estimate_every=estimate_every,
    )


def _records(env, seed, steps=12):
    obs, info = env.reset(seed=seed)
    policy = ScriptedGraspPolicy.for_env(env)
    policy.reset(obs, info)
    recs = [{**info["perception"], **(env.perception_timings or {})}]
    for _ in range(steps):
        obs, _, term, trunc, info = env.step(policy.act(obs))
        recs.append({**info["perception"], **(env.perception_timings or {})})
        if term or trunc:
            break
    return obs, recs


@pytest.mark.slow
@pytest.mark.parametrize("recognizer", ["appearance", "flr", "flr+appearance"])
def test_recognize_in_the_loop(models, flr, recognizer):
    chosen = {
        "appearance": "appearance",
        "flr": flr,
        "flr+appearance": ShortlistRecognizer(flr, AppearanceRecognizer(models.estimators), k=1),
    }[recognizer]
    env = _env(models, chosen, cameras=["top", "side"])
    assert {"top_rgb", "side_rgb"} <= set(env.unwrapped.observation_space.spaces)
    for seed in (0, 1):
        obs, recs = _records(env, seed)
        first = recs[0]
        assert first["identity"] == "recognize" and first["valid"]
        assert first["recognised"] == first["true_class"]  # both objects are easy from above
        assert first["timings_ms"]["recognise"] > 0 and first["timings_ms"]["segment"] > 0
        assert {r["recognised"] for r in recs if r["estimated"]} == {first["true_class"]}
        assert set(obs) >= {"object_pos", "pose_valid", "object_class"}
    env.close()


@pytest.mark.slow
def test_recognition_is_counted_in_the_summary(models):
    env = _env(models, "appearance", estimate_every=0)
    results = run_episodes(env, ScriptedGraspPolicy.for_env(env), episodes=2, seed=3)
    perception = summarize(results)["perception"]
    assert perception["recognition_accuracy"] == 1.0
    env.close()


@pytest.mark.slow
def test_recognition_in_the_loop_is_deterministic(models):
    env = _env(models, "appearance")
    a, b = _records(env, 7)[1], _records(env, 7)[1]
    keys = ("recognised", "valid", "pos_err_cm", "rot_err_deg", "n_inliers")
    assert [[r[k] for k in keys] for r in a] == [[r[k] for k in keys] for r in b]
    env.close()


class _Blind(gym.Wrapper):
    """Shows the camera the empty workspace (``"blank"``) or a grey card over the object."""

    def __init__(self, env, mode):
        super().__init__(env)
        self.mode, self._bg = mode, None

    def _edit(self, obs):
        img = obs["top_rgb"].copy()
        if self.mode == "blank":
            img = self._bg.copy()
        else:
            ys, xs = np.nonzero((img.astype(int) - self._bg).any(axis=2))
            img[ys.min() - 5 : ys.max() + 5, xs.min() - 5 : xs.max() + 5] = 128
        return {**obs, "top_rgb": img}

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._bg = info["camera_background"]["top"]["rgb"]
        return self._edit(obs), info

    def step(self, action):
        obs, *rest = self.env.step(action)
        return (self._edit(obs), *rest)


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["blank", "occluded"])
def test_blank_or_occluded_view_gives_pose_valid_0(models, mode):
    source = ModelSetPoseSource(models, segmenter="background", recognizer="appearance")
    base = gym.make("ScorbotGrasp-v0", objects=OBJECTS, **source.env_requirements)
    env = PoseEstimateObservation(_Blind(base, mode), source, identity="recognize")
    obs, info = env.reset(seed=0)
    assert obs["pose_valid"][0] == 0.0 and not info["perception"]["valid"]
    assert info["perception"]["reason"]
    obs, *_ = env.step(np.zeros(6))
    assert obs["pose_valid"][0] == 0.0
    env.close()


@pytest.mark.slow
def test_descriptor_votes_recognise_a_half_hidden_object(models):
    env = make_env(
        pose="oracle",
        cameras=["top"],
        image_width=320,
        image_height=240,
        image_types=["rgb", "privileged_segmentation"],
        objects=OBJECTS,
    )
    votes = DescriptorVoteRecognizer(models.estimators)
    appearance = AppearanceRecognizer(models.estimators)
    for seed in (0, 1, 2):
        obs, info = env.reset(seed=seed)
        mask = obs["top_privileged_segmentation"][..., 0] > 0
        rows = np.nonzero(mask.any(axis=1))[0]
        half = mask.copy()
        half[: rows[len(rows) // 2]] = False  # the top half of the silhouette hidden
        cam = CameraModel(**info["camera_params"]["top"])
        for m in (mask, half):
            view = View(obs["top_rgb"], cam, m)
            assert votes.recognize(view).label == info["object_name"]
            assert appearance.recognize(view).label == info["object_name"]
    with pytest.raises(ValueError, match="ratio"):
        DescriptorVoteRecognizer(models.estimators, ratio=0.0)
    env.close()


@pytest.mark.slow
def test_fallback_camera_estimates_where_the_top_view_is_hidden(models):
    """With the top camera blind, the side camera's models give the pose (same object)."""
    side = train_models(OBJECTS, n_views=72, camera="side", progress=False)[0]
    source = ModelSetPoseSource(models, segmenter="background", fallback_models=[side])
    assert source.cameras == ("top", "side")
    base = gym.make("ScorbotGrasp-v0", objects=OBJECTS, **source.env_requirements)
    env = PoseEstimateObservation(_Blind(base, "blank"), source, identity="given")
    obs, info = env.reset(seed=0)
    rec = info["perception"]
    assert obs["pose_valid"][0] == 1.0 and rec["camera"] == "side"
    timings = env.perception_timings  # wall-clock: kept out of info
    assert rec["pos_err_cm"] < 3.0 and "estimate_side" in timings["timings_ms"]
    assert timings["total_ms"] >= timings["timings_ms"]["fallback"] > 0
    alone = ModelSetPoseSource(models, segmenter="background")
    blind = PoseEstimateObservation(_Blind(base, "blank"), alone, identity="given")
    assert blind.reset(seed=0)[0]["pose_valid"][0] == 0.0
    with pytest.raises(ValueError, match="other cameras"):
        ModelSetPoseSource(models, fallback_models=[models])
    env.close()


@pytest.mark.slow
def test_motion_places_the_object_where_no_camera_can_estimate_it(models):
    """The object is pushed 3 cm while the top camera is blind: with ``motion="silhouette"``
    the side camera's silhouette moves the last estimate there, and confirms it at the next
    step; without it, no answer."""
    from pose.camera import CameraModel
    from scorbot_gym.perception.base import PerceptionFrame

    answers = {}
    for motion in (None, "silhouette"):
        source = ModelSetPoseSource(models, cameras=("top", "side"), motion=motion)
        base = gym.make("ScorbotGrasp-v0", objects=["box"], **source.env_requirements)
        obs, info = base.reset(seed=0)
        cameras = {c: CameraModel(**p) for c, p in info["camera_params"].items()}

        def frame(o, cameras=cameras, backgrounds=info["camera_background"]):
            return PerceptionFrame(o, cameras, "box", backgrounds=backgrounds)

        source.reset(frame(obs), np.random.default_rng(0))
        assert source.estimate(frame(obs)).valid
        sim = base.unwrapped.sim  # the test pushes the object; the source sees images only
        pos, quat = sim.object_pose()
        sim.set_object_pose(pos + np.array([0.0, 0.03, 0.0]), quat)
        obs, *_ = base.step(np.zeros(base.action_space.shape))
        obs = {**obs, "top_rgb": info["camera_background"]["top"]["rgb"]}  # top: blind
        answers[motion] = (source.estimate(frame(obs)), sim.object_pose()[0])
        obs, *_ = base.step(np.zeros(base.action_space.shape))  # still blind from above
        obs = {**obs, "top_rgb": info["camera_background"]["top"]["rgb"]}
        answers[motion] += (source.estimate(frame(obs)),)
        base.close()
    assert not answers[None][0].valid and not answers[None][2].valid
    moved, truth, again = answers["silhouette"]
    assert moved.valid and moved.camera == "side" and moved.reason.startswith("moved")
    assert np.linalg.norm(moved.position - truth) < 0.005
    assert moved.timings_ms["motion"] > 0
    # the next step's silhouette agrees: the moved pose again, so a filter can confirm the jump
    assert again.valid and again.reason == "moved: confirmed by the silhouette"
    np.testing.assert_allclose(again.position, moved.position)
