"""Issue 37 items 2, 4 and 5 on cluttered tables: the blob-choice baselines (largest and random
blob) as registered pose sources, a target touching a neighbour in the image, the ``clutter``
ablation protocol with its measured occlusion, the winners table, and the video overlay."""

from __future__ import annotations

import numpy as np
import pytest

from pose.camera import CameraModel
from scorbot_gym.envs.factory import make_env
from scorbot_gym.perception import make_pose_source, pose_source_names
from scorbot_gym.perception.base import PerceptionFrame
from scorbot_gym.perception.training import train_models
from scorbot_gym.tasks.clutter import slide_into_contact

OBJECTS = ["box", "tomato_soup_can", "banana"]


@pytest.fixture(scope="module")
def models():
    return train_models(OBJECTS, n_views=72, progress=False)[0]


# --- blob-choice baselines ----------------------------------------------------------------------
def test_blob_choice_sources_are_registered_and_check_their_choice(models):
    assert {"largest_blob", "random_blob"} <= set(pose_source_names())
    src = make_pose_source("random_blob", models=models)
    assert src.choice == "random" and not src.privileged and src.name == "random_blob"
    from scorbot_gym.perception.blob_choice import BlobChoicePoseSource

    with pytest.raises(ValueError, match="choice must be one of"):
        BlobChoicePoseSource(models, choice="smallest")


@pytest.mark.slow
@pytest.mark.parametrize("source", ["largest_blob", "random_blob"])
def test_blob_choice_sources_pick_a_blob_and_answer_a_valid_pose(models, source):
    """Each reset picks one blob (the largest, or a seeded random one), scored against the
    object under it; the pose is valid (the target's model, or the target placed on the
    blob's silhouette), and the same seed picks the same blob."""
    env = make_env(
        "ScorbotGrasp-v0", pose=source, pose_kwargs={"models": models}, objects=OBJECTS,
        distractors=2,
    )  # fmt: skip
    try:
        picks = []
        for seed in range(6):
            _, info = env.reset(seed=seed)
            p = info["perception"]
            assert p["source"] == source and not p["privileged"] and p["valid"]
            assert p["recognised"] is None and all(b["recognised"] is None for b in p["objects"])
            chosen = env.get_wrapper_attr("source")._chosen_at
            areas = [b["area"] for b in p["objects"]]
            i = int(np.argmin([np.linalg.norm(chosen - b["centroid_px"]) for b in p["objects"]]))
            picks.append((i, p["target_recognised"]))
            if source == "largest_blob":
                assert areas[i] == max(areas)
            if p["target_recognised"]:  # the target's own blob: its model's estimate
                assert p["pos_err_cm"] < 2.0
        if source == "random_blob":
            assert len({i for i, _ in picks}) >= 2  # not always the same blob
            _, again = env.reset(seed=3)
            assert again["perception"]["target_recognised"] == picks[3][1]
    finally:
        env.close()


def test_blob_choice_sources_run_from_a_rollout_config():
    from scorbot_gym.evaluation.rollout import RolloutConfig

    config = RolloutConfig(pose="largest_blob", pose_model="m.npz", distractors=2)
    assert config.pose_kwargs() == {"models": "m.npz", "splitter": "none", "support": "table"}
    with pytest.raises(ValueError, match="chooses its blob itself: drop recognize"):
        RolloutConfig(pose="random_blob", recognize=True)


# --- a target touching a neighbour in the image ---------------------------------------------------
def _touch(sim, mover: str, still: str) -> None:
    assert slide_into_contact(sim, mover, still), f"{mover} never reached {still}"


@pytest.mark.slow
def test_a_target_touching_a_neighbour_is_estimated_on_the_merged_blob(models):
    """Objects touching in the image share one blob; the target's model explains its own
    keypoints on it (keypoint-to-model assignment), so the pose is still right."""
    env = make_env(
        "ScorbotGrasp-v0", pose="manifold_clutter",
        pose_kwargs={"models": models, "recognizer": "appearance"}, objects=OBJECTS,
        distractors=2,
    )  # fmt: skip
    inner = env.env  # the env under the pose wrapper: its observation still holds the images
    try:
        obs, info = inner.reset(seed=1, options={"target": "box"})
        cams = {n: CameraModel(**p) for n, p in info["camera_params"].items()}
        backgrounds = dict(info["camera_background"])
        src = make_pose_source("manifold_clutter", models=models, recognizer="appearance")
        src.reset(PerceptionFrame(obs, cams, "box", backgrounds=backgrounds),
                  np.random.default_rng(0))  # fmt: skip
        neighbour = next(n for n in info["objects"] if n != "box")
        _touch(inner.unwrapped.sim, neighbour, "box")
        obs, *_, info = inner.step(np.zeros(6, np.float32))
        frame = PerceptionFrame(obs, cams, "box", step=1, backgrounds=backgrounds)
        n_blobs = len(src.segmenter.blobs(frame, "top"))
        est = src.estimate(frame)
        assert n_blobs == len(info["objects"]) - 1  # the two touching objects: one blob
        assert est.valid, est.reason
        truth = np.asarray(info["object_pose"]["position"])
        assert np.linalg.norm(est.position - truth) < 0.01
    finally:
        env.close()


# --- the clutter protocol -------------------------------------------------------------------------
def test_measured_occlusion_and_bins():
    from scorbot_gym.data.clutter_views import measured_occlusion, occlusion_bin
    from scorbot_gym.data.protocols import CLUTTER_BINS

    full = np.zeros((10, 10), bool)
    full[2:6, 2:7] = True  # 20 px
    visible = full.copy()
    visible[2:3, 2:7] = False  # 5 hidden
    assert measured_occlusion(visible, full) == pytest.approx(0.25)
    assert measured_occlusion(full, np.zeros_like(full)) == 0.0
    assert occlusion_bin(0.25, CLUTTER_BINS) == 0.2
    assert occlusion_bin(0.0, CLUTTER_BINS) == 0.0
    assert occlusion_bin(0.97, CLUTTER_BINS) is None  # nothing left to estimate from


def test_clutter_protocol_rejects_levels_that_are_not_bin_edges():
    from scorbot_gym.experiments.spec import SweepSpec

    with pytest.raises(ValueError, match="bin edges"):
        SweepSpec("clutter", ("chance",), (0.0, 0.25))
    assert SweepSpec("clutter", ("chance",), (0.0, 0.3)).occlusions == (0.0, 0.3)


@pytest.mark.slow
def test_clutter_protocol_renders_real_occluders_with_measured_occlusion(tmp_path):
    from scorbot_gym.data.protocols import (
        CLUTTER_BINS,
        PoseProtocol,
        _grid,
        _random,
        held_out_views,
    )

    small = PoseProtocol("clutter-small", 1, ("side",), "side", _grid(90.0), _random(12),
                         "test", CLUTTER_BINS, {"distractors": 3})  # fmt: skip
    kw = dict(width=160, height=120, seed=1, cache_dir=tmp_path)
    by_bin = {b: held_out_views(small, "box", b, **kw) for b in CLUTTER_BINS}
    views = [v for vs in by_bin.values() for v in vs]
    assert 0 < len(views) <= 12  # every view in one bin (or none: hidden beyond 95 %)
    for b, vs in by_bin.items():
        assert all(b <= v.occlusion < b + 0.1 + 1e-9 for v in vs)
        assert all(v.view.mask.any() and v.view.image.shape == (120, 160, 3) for v in vs)
    assert max(v.occlusion for v in views) > 0.05  # the distractors hide part of the target
    again = held_out_views(small, "box", views[0].occlusion // 0.1 / 10, **kw)  # cached
    assert any(np.array_equal(v.view.image, views[0].view.image) for v in again)
    with pytest.raises(ValueError, match="bins its measured occlusion"):
        held_out_views(small, "box", 0.25, **kw)


def test_winners_say_where_a_baseline_wins():
    from scorbot_gym.experiments.aggregate import format_winners, winners

    def row(est, occ, s, blind=0.1):
        return {"protocol": "clutter", "estimator": est, "occlusion": occ, "n": 40,
                "success_5deg": s, "constant_answer_success_5deg": blind}  # fmt: skip

    rows = [row("manifold", 0.0, 0.9), row("pca-nn", 0.0, 0.5),
            row("manifold", 0.5, 0.2), row("pca-nn", 0.5, 0.4),
            row("manifold", 0.9, 0.0, blind=0.05), row("pca-nn", 0.9, 0.0, blind=0.05)]  # fmt: skip
    w = {r["occlusion"]: r for r in winners(rows)}
    assert not w[0.0]["baseline_wins"] and w[0.0]["best"] == "manifold"
    assert w[0.5]["baseline_wins"] and w[0.5]["won_by"] == "pca-nn"
    assert w[0.9]["won_by"] == "image-blind answer"
    assert "BASELINE WINS: pca-nn" in format_winners(list(w.values()))


# --- the video overlay ----------------------------------------------------------------------------
def test_overlay_marks_the_target_and_the_estimate():
    from scorbot_gym.evaluation.video import draw_overlay

    env = make_env(
        "ScorbotGrasp-v0", pose="oracle", objects=OBJECTS, distractors=2,
        render_mode="rgb_array", render_camera="top", render_width=160, render_height=120,
    )  # fmt: skip
    try:
        obs, info = env.reset(seed=0)
        frame = env.render()
        cam = env.unwrapped.camera_model("top", 160, 120)
        drawn = draw_overlay(frame, cam, obs, info)
        changed = np.argwhere(np.any(drawn != frame, axis=-1))
        assert len(changed) > 40
        u, v = cam.project(np.asarray(info["object_pose"]["position"])[None])[0]
        assert np.min(np.linalg.norm(changed[:, ::-1] - [u, v], axis=1)) < 3  # axes at it
        no_pose = {k: v for k, v in obs.items() if k != "object_pos"}  # before any estimate
        ring_only = draw_overlay(frame, cam, no_pose, info)
        ring = np.argwhere(np.any(ring_only != frame, axis=-1))
        assert len(ring) > 10 and np.any(ring_only != drawn)  # the target's ring and name
        d = np.linalg.norm(ring[:, ::-1] - [u, v], axis=1)
        assert d.min() >= 3  # a ring around the target, not a dot on it
    finally:
        env.close()
