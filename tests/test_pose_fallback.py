"""ConfidenceFallback on real rendered views: the gate, blank views, specs, save/load, errors."""

import numpy as np
import pytest
from sklearn.base import clone

from pose import baselines
from pose.fallback import ConfidenceFallback
from pose.metrics import rotation_error_deg
from pose.registry import estimator_names, make_from_spec, parse_spec
from pose.view import View
from scorbot_gym.objects import get_object

OBJECT = "potted_meat_can"
W, H = 320, 240  # the size of the shared can_views fixture


@pytest.fixture(scope="session")
def views(can_views):
    return can_views


@pytest.fixture(scope="session")
def fitted(views):
    train, poses, _ = views
    return make_from_spec("fallback(estimator='sift-pnp', min_confidence=0.0)").fit(train, poses)


def test_registered_and_built_from_specs():
    assert "fallback" in estimator_names()
    est = make_from_spec("fallback(estimator='sift-pnp(upscale=2)', estimator__upscale=3)")
    assert isinstance(est, ConfidenceFallback)
    assert isinstance(est.estimator, baselines.SiftPnPEstimator) and est.estimator.upscale == 3
    assert isinstance(est.fallback, baselines.ChanceEstimator)
    assert est.min_confidence == 0.2
    assert clone(est).get_params()["estimator__upscale"] == 3
    assert parse_spec("fallback(estimator='manifold-pnp(matcher__min_inliers=6)')") == (
        "fallback",
        {"estimator": "manifold-pnp(matcher__min_inliers=6)"},
    )


def test_gate_picks_main_or_fallback_by_confidence(fitted, views):
    train, poses, test = views
    main, chance = fitted.estimator_, fitted.fallback_
    confident = clone(fitted).set_params(min_confidence=1.0)
    confident.estimator_, confident.fallback_ = main, chance
    for lv in test:
        m, c = main.predict(lv.view), chance.predict(lv.view)
        assert m.valid and 0.0 < m.confidence < 1.0
        kept = fitted.predict(lv.view)  # threshold 0: every valid main answer is kept
        np.testing.assert_array_equal(kept.rotation, m.rotation)
        assert kept.reason == ""
        back = confident.predict(lv.view)  # threshold 1: the prior answers
        np.testing.assert_array_equal(back.rotation, c.rotation)
        np.testing.assert_allclose(back.translation, c.translation)
        assert back.valid and back.reason.startswith("fallback: main confidence")
        assert back.timings_ms["total"] >= back.timings_ms["main"] >= 0
        assert back.n_keypoints == m.n_keypoints


def test_invalid_main_answer_falls_back_and_blank_views_stay_invalid(fitted, views):
    camera = views[0][0].camera
    grey = np.full((H, W, 3), 128, np.uint8)
    nothing = fitted.predict(View(grey, camera))  # no mask: the prior has no position either
    assert not nothing.valid and "fallback invalid too" in nothing.reason
    assert np.isnan(nothing.rotation).all()
    masked = fitted.predict(View(grey, camera, np.ones((H, W), bool)))
    assert masked.valid and masked.reason.startswith("fallback: main estimate invalid")
    prior = fitted.fallback_.predict(View(grey, camera, np.ones((H, W), bool)))
    np.testing.assert_array_equal(masked.rotation, prior.rotation)


def test_batch_predict_and_score(fitted, views):
    _, _, test = views
    batch = fitted.predict([lv.view for lv in test])
    assert [e.rotation.tolist() for e in batch] == [
        fitted.predict(lv.view).rotation.tolist() for lv in test
    ]
    poses = np.array([lv.camera_from_object for lv in test])
    symmetry = get_object(OBJECT).symmetry
    expected = np.mean(
        [
            e.valid and rotation_error_deg(e.rotation, p[:3, :3], symmetry) < 5.0
            for e, p in zip(batch, poses, strict=True)
        ]
    )
    assert fitted.score([lv.view for lv in test], poses, symmetry) == pytest.approx(expected)
    with pytest.raises(ValueError, match=r"poses must be \(4, 4, 4\)"):
        fitted.score([lv.view for lv in test], poses[:2])


def test_save_load_round_trip(fitted, views, tmp_path):
    path = tmp_path / "fallback.npz"
    fitted.set_params(min_confidence=0.3).save(path)
    loaded = ConfidenceFallback.load(path)
    assert loaded.min_confidence == 0.3
    assert type(loaded.estimator_) is baselines.SiftPnPEstimator
    assert type(loaded.fallback_) is baselines.ChanceEstimator
    for lv in views[2]:
        a, b = fitted.predict(lv.view), loaded.predict(lv.view)
        np.testing.assert_allclose(b.rotation, a.rotation, atol=1e-6)
        assert a.reason == b.reason
    fitted.set_params(min_confidence=0.0)
    with pytest.raises(ValueError, match="not a ChanceEstimator"):
        baselines.ChanceEstimator.load(path)
    with pytest.raises(ValueError, match="not a ConfidenceFallback"):
        fitted.fallback_.save(tmp_path / "chance.npz")
        ConfidenceFallback.load(tmp_path / "chance.npz")


def test_manifold_part_round_trips(tmp_path, views):
    train, poses, test = views
    est = make_from_spec("fallback(estimator='manifold-pnp', fallback='pca-nn')").fit(train, poses)
    est.save(tmp_path / "m.npz")
    loaded = ConfidenceFallback.load(tmp_path / "m.npz")
    assert type(loaded.fallback_) is baselines.PCAEstimator
    for lv in test[:2]:
        np.testing.assert_allclose(
            loaded.predict(lv.view).rotation, est.predict(lv.view).rotation, atol=1e-6
        )


@pytest.mark.parametrize(
    "params, match",
    [
        ({"estimator": "not an estimator"}, "estimator must be a pose estimator"),
        ({"fallback": 3}, "fallback must be a pose estimator"),
        ({"min_confidence": 1.5}, r"min_confidence must be in \[0, 1\]"),
        ({"min_confidence": "high"}, r"min_confidence must be in \[0, 1\]"),
    ],
)
def test_bad_parameters_are_one_line_errors(params, match, views):
    train, poses, _ = views
    with pytest.raises(ValueError, match=match):
        ConfidenceFallback(**params).fit(train[:2], poses[:2])


def test_unknown_part_name_is_refused():
    with pytest.raises(ValueError, match="unknown estimator 'nope'"):
        make_from_spec("fallback(estimator='nope')")


def test_sweep_spec_round_trips_and_builds():
    from scorbot_gym.experiments.spec import EstimatorSpec, split_estimators

    text = "chance,fallback(estimator='manifold-pnp(keypoints__upscale=2, matcher__min_inliers=6)')"
    names = split_estimators(text)
    assert names[0] == "chance" and len(names) == 2
    spec = EstimatorSpec.parse(names[1])
    assert EstimatorSpec.parse(str(spec)) == spec
    est = spec.make()
    assert isinstance(est, ConfidenceFallback)
    assert est.estimator.get_params()["keypoints__upscale"] == 2


def _trial(estimator, obj, errors, valid, score, occlusion=0.5):
    views = {"rot_err_deg": errors, "valid": valid, "score": score}
    return {"protocol": "p", "estimator": estimator, "object": obj, "occlusion": occlusion,
            "views": views}  # fmt: skip


def test_gate_curve_scores_each_threshold_like_the_composition():
    from scorbot_gym.experiments.gate import best_threshold, gate_curve

    trials = [
        # main: right and confident, right but unsure, wrong and unsure, invalid
        _trial("main", "a", [1.0, 2.0, 40.0, None], [True, True, True, False], [0.9, 0.15, 0.1, 0]),
        # fallback: wrong, right, right, right
        _trial("chance", "a", [30.0, 0.0, 0.0, 0.0], [True] * 4, [0.0] * 4),
    ]
    (cell,) = gate_curve(trials, "main", "chance", (0.0, 0.12, 0.2, 1.0))
    assert cell["n"] == 4 and cell["main"] == 0.5 and cell["fallback"] == 0.75
    # 0: main kept where valid (2 right) + fallback on the invalid one (right) = 3/4;
    # 0.12: the wrong unsure answer goes to the fallback too = 4/4; 0.2: the right unsure
    # one as well (fallback right there) = 4/4; 1.0: fallback everywhere = 3/4
    assert cell["gated"] == {0.0: 0.75, 0.12: 1.0, 0.2: 1.0, 1.0: 0.75}
    assert best_threshold([cell]) == (0.12, cell["gated"])
    with pytest.raises(ValueError, match="same cells"):
        gate_curve(trials[:1], "main", "chance", (0.1,))


def test_damaged_fallback_file_is_refused(tmp_path):
    from pose.serialization import save_arrays

    path = tmp_path / "damaged.npz"
    header = {"kind": "estimator", "class": "ConfidenceFallback"}
    save_arrays(path, {"unrelated": np.zeros(2)}, header)
    with pytest.raises(ValueError, match="missing or has bad entries"):
        ConfidenceFallback.load(path)
