"""Ablation sweeps (local and Ray), per-trial resume, BOP export, perturbation axes."""

import csv
import json
import re
import shutil

import numpy as np
import pytest

from scorbot_gym.cli import main
from scorbot_gym.data.perturbations import Perturbation, ScenePerturber
from scorbot_gym.data.protocols import held_out_views
from scorbot_gym.experiments.spec import EstimatorSpec, parse_occlusions, split_estimators

# parameters every version of the manifold estimator has (stage parameters moved over time)
ESTIMATORS = "manifold,manifold(allocentric=True)"
SWEEP = [
    "pose", "ablate", "--protocol", "side-turntable", "--estimators", ESTIMATORS,
    "--occlusion", "0,50", "--objects", "banana,box", "--width", "160", "--height", "120",
    "--test-views", "6", "--train-stride", "3", "--quiet",
]  # fmt: skip
RECORD_KEYS = {
    "protocol", "estimator", "occlusion", "n", "success_5deg", "success_5deg_ci95",
    "median_rot_err_deg", "valid_rate", "median_ms", "success_5deg_asymmetric",
}  # fmt: skip


# ----------------------------------------------------------------------------- specs
def test_estimator_specs_parse_and_label():
    s = EstimatorSpec.parse("manifold( random_state=3,allocentric=True )")
    assert s.name == "manifold" and dict(s.params) == {"allocentric": True, "random_state": 3}
    assert (
        str(s) == "manifold(allocentric=True, random_state=3)" == str(EstimatorSpec.parse(str(s)))
    )
    params = s.make().get_params()
    assert params["allocentric"] is True and params["random_state"] == 3
    nested = EstimatorSpec.parse("manifold(a__b=1, c=2)")
    assert str(nested) == "manifold(a__b=1, c=2)"
    assert split_estimators("a,b(x=1, y=(2, 3)),c") == ["a", "b(x=1, y=(2, 3))", "c"]
    for bad in ("manifold(4)", "manifold(x=open('f'))", "1abc", "manifold(**k)"):
        with pytest.raises(ValueError, match="estimator spec"):
            EstimatorSpec.parse(bad)


def test_spec_errors_name_the_bad_parameter_on_one_line_and_their_examples_build():
    from pose.registry import make_from_spec

    cases = {
        "manifold(refine=False)": "estimator 'manifold' has no parameter 'refine'; valid: ",
        "manifold(matcher__bogus=1)": "no parameter 'bogus' (in its RansacMatcher); valid: ",
        "pca-nn(foo=1)": "estimator 'pca-nn' has no parameter 'foo'; valid: ",
        "select(random_state=1, cv__x=1)": "'cv__x' addresses a parameter of 'cv', which is",
    }
    for spec, message in cases.items():
        with pytest.raises(ValueError, match=re.escape(message)) as err:
            make_from_spec(spec)
        assert "\n" not in str(err.value)
    for bad in ("1abc", "manifold(4)"):  # the examples the syntax errors suggest are valid
        with pytest.raises(ValueError, match="e.g. ") as err:
            EstimatorSpec.parse(bad)
        make_from_spec(str(err.value).split("e.g. ")[-1])


def test_cli_names_a_bad_estimator_parameter(tmp_path, capsys):
    argv = SWEEP[:5] + ["manifold(refine=False)", "--cache-dir", str(tmp_path)]
    assert main(argv) == 2
    assert "estimator 'manifold' has no parameter 'refine'" in capsys.readouterr().err


def test_cell_summary_counts_the_coarse_answer_over_asymmetric_objects_too():
    from scorbot_gym.experiments.aggregate import summarize_trials

    def trial(obj, symmetry, refined, coarse):
        n = len(refined)
        return {"object": obj, "symmetry": symmetry, "views": {
            "rot_err_deg": refined, "coarse_rot_err_deg": coarse, "chance_rot_err_deg": [90.0] * n,
            "valid": [True] * n, "ms": [1.0] * n, "occlusion": [0.0] * n}}  # fmt: skip

    cell = summarize_trials([
        trial("banana", "none", [1.0, 2.0, 9.0, 1.0], [1.0, 7.0, 9.0, None]),
        trial("can", "axial", [1.0, 1.0], [1.0, 1.0]),
    ])  # fmt: skip
    assert cell["success_5deg_asymmetric"] == 0.75 and cell["coarse_success_5deg"] == 0.5
    assert cell["coarse_success_5deg_asymmetric"] == 0.25


def test_sweeps_run_in_a_process_pool_by_default():
    import os

    from scorbot_gym.cli.pose_cmd import sweep_runner
    from scorbot_gym.experiments import LocalRunner

    runner = sweep_runner(None, None)
    assert isinstance(runner, LocalRunner) and runner.jobs == len(os.sched_getaffinity(0))
    assert sweep_runner(1, None).jobs == 1  # in this process, when asked


def test_occlusion_ranges():
    assert parse_occlusions("0:95:5") == tuple(round(0.05 * i, 4) for i in range(20))
    assert parse_occlusions("0,50") == (0.0, 0.5)
    for bad in ("0:100:5", "a,b", "0:50:0", ""):
        with pytest.raises(ValueError, match="occlusion"):
            parse_occlusions(bad)


def test_cli_rejects_unknown_estimator(tmp_path, capsys):
    argv = SWEEP[:5] + ["nope,manifold", "--cache-dir", str(tmp_path)]
    assert main(argv) == 2
    assert "unknown estimator 'nope'; registered: " in capsys.readouterr().err


# ----------------------------------------------------------------------------- sweep
@pytest.fixture(scope="session")
def local_sweep(tmp_path_factory):
    """The tiny sweep run twice on one cache: (first report, second report, second stdout)."""
    d = tmp_path_factory.mktemp("ablate")
    cache = d / "cache"
    argv = SWEEP + ["--cache-dir", str(cache), "--jobs", "2"]
    assert main(argv + ["--json", str(d / "a.json"), "--png", str(d / "a.png")]) == 0
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(argv + ["--json", str(d / "b.json"), "--bop", str(d / "bop"),
                            "--paired", "manifold"]) == 0  # fmt: skip
    first, second = (json.loads((d / f).read_text()) for f in ("a.json", "b.json"))
    return d, first, second, out.getvalue()


@pytest.mark.slow
def test_an_estimator_that_cannot_fit_an_object_scores_invalid_answers(tmp_path):
    """The golf ball covers ~90 px in the overview camera: too few SIFT keypoints for the
    manifold to fit. The sweep records invalid answers for it and the error, and goes on."""
    from scorbot_gym.experiments.aggregate import fit_errors
    from scorbot_gym.experiments.trial import ModelJob, run_model_job

    job = ModelJob(
        "overview", "manifold", "golf_ball", 0, (0.0,), 160, 120, 3, 6, (), str(tmp_path)
    )
    out = run_model_job(job)
    (trial,) = out["trials"]
    assert "SIFT keypoints" in trial["fit_error"] and out["stats"]["fit_errors"] == 1
    assert trial["views"]["valid"] == [False] * 3
    assert trial["views"]["rot_err_deg"] == [None] * 3
    again = run_model_job(job)  # cached, with its error
    assert again["stats"]["trials_cached"] == 1 and again["trials"][0]["fit_error"]
    (err,) = fit_errors(out["trials"] + again["trials"])  # one line per fit, not per trial
    assert [err[k] for k in ("protocol", "estimator", "object")] == [
        "overview", "manifold", "golf_ball"
    ]  # fmt: skip
    assert err["error"] == trial["fit_error"]


@pytest.mark.slow
def test_local_sweep_records_and_figure(local_sweep):
    d, rep, _, _ = local_sweep
    res = rep["results"]
    assert len(res) == 4  # 2 estimators x 2 occlusion levels
    assert {(r["estimator"], r["occlusion"]) for r in res} == {
        (e, o) for e in ("manifold", "manifold(allocentric=True)") for o in (0.0, 0.5)
    }
    for r in res:
        assert RECORD_KEYS <= set(r)
        assert r["n"] == 12 and r["n_asymmetric"] == 6  # 6 views x (banana, box)
        lo, hi = r["success_5deg_ci95"]
        assert 0 <= lo <= r["success_5deg"] <= hi <= 1
    assert rep["chance"]["source"].startswith("constant answer")
    assert {row["variant"] for row in rep["stage_ablation"]} >= {"manifold"}
    by_label = {(r["estimator"], r["occlusion"]): r for r in res}
    for row in rep["stage_ablation"]:  # each row also over the asymmetric object alone
        src = by_label[(row["variant"].removesuffix(" [coarse]"), row["occlusion"])]
        coarse = row["variant"].endswith(" [coarse]")
        assert row["success_5deg_asymmetric"] == src.get(
            "coarse_success_5deg_asymmetric" if coarse else "success_5deg_asymmetric"
        )
    assert rep["selections"] == []  # neither estimator selects among candidates
    assert rep["spec"]["test_views"] == 6 and rep["spec"]["objects"] == ["banana", "box"]
    assert (d / "a.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_the_cli_pairs_one_estimator_with_the_others(local_sweep):
    _, first, second, out = local_sweep
    assert "paired" not in first
    rows = second["paired"]
    assert [(r["estimator"], r["versus"], r["occlusion"], r["n"]) for r in rows] == [
        ("manifold", "manifold(allocentric=True)", occ, 12) for occ in (0.0, 0.5)
    ]
    assert "paired: manifold against each estimator" in out


def test_cli_rejects_a_paired_estimator_outside_the_sweep(tmp_path, capsys):
    argv = SWEEP + ["--cache-dir", str(tmp_path), "--paired", "pca-rbf"]
    assert main(argv) == 2
    assert "--paired 'pca-rbf' is not among --estimators" in capsys.readouterr().err


@pytest.mark.slow
def test_the_json_keeps_every_views_error_and_they_give_the_cells_figures(local_sweep):
    _, rep, _, _ = local_sweep
    rows = rep["view_errors"]
    assert {(r["estimator"], r["object"], r["occlusion"]) for r in rows} == {
        (e, o, occ)
        for e in ("manifold", "manifold(allocentric=True)")
        for o in ("banana", "box")
        for occ in (0.0, 0.5)
    }
    for cell in rep["results"]:
        errs = [
            e
            for r in rows
            if (r["estimator"], r["occlusion"]) == (cell["estimator"], cell["occlusion"])
            for e in r["rot_err_deg"]
        ]
        assert len(errs) == cell["n"] == 12  # 6 views of each object, in the protocol's order
        hits = sum(e is not None and e < 5.0 for e in errs)
        assert round(hits / len(errs), 4) == cell["success_5deg"]
        finite = [e for e in errs if e is not None]
        median = float(np.median(finite)) if finite else None
        assert cell["median_rot_err_deg"] == (pytest.approx(median, abs=1e-3) if finite else None)


def test_legend_labels_wrap_long_specs_without_cutting_them():
    from scorbot_gym.experiments.plot import legend_label

    spec = ("manifold-pnp(keypoints__upscale=2, matcher__min_inliers=6, matcher__n_candidates=8, "
            "refiner__correspondences='ratio+global', refiner__keep_margin=0.0)")  # fmt: skip
    label = legend_label(spec)
    assert label.replace("\n", " ") == spec  # every parameter is in the legend
    assert len(label.splitlines()) > 1 and max(map(len, label.splitlines())) <= 64
    assert legend_label("chance") == "chance"


@pytest.mark.slow
def test_replot_redraws_the_figure_from_the_json_alone(local_sweep, tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "benchmarks" / "pose_ablation.py"
    d = local_sweep[0]
    shutil.copy(d / "a.json", tmp_path / "a.json")
    (tmp_path / "p.json").write_text(json.dumps({"spec": {}, "results": [], "chance": {},
                                                 "perturbations": ["none"]}))  # fmt: skip
    (tmp_path / "bad.json").write_text("{")

    def replot(name):
        return subprocess.run([sys.executable, str(script), "--replot", str(tmp_path / name)],
                              capture_output=True, text=True)  # fmt: skip

    assert replot("a.json").returncode == 0
    assert (tmp_path / "a.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for name, message in (("p.json", "a perturbation sweep"), ("bad.json", "not a readable")):
        out = replot(name)
        assert out.returncode == 2 and message in out.stderr
        assert not (tmp_path / name).with_suffix(".png").exists()


@pytest.mark.slow
def test_second_run_resumes_from_the_trial_cache(local_sweep):
    _, first, second, out = local_sweep
    assert second["stats"]["fits"] == 0 and second["stats"]["trials_run"] == 0
    assert second["stats"]["trials_cached"] == 8
    assert "0 fitted" in out
    assert second["results"] == first["results"]


@pytest.mark.slow
@pytest.mark.ray
def test_ray_runner_gives_the_local_numbers(local_sweep, tmp_path):
    pytest.importorskip("ray")
    d, first, _, _ = local_sweep
    shutil.copytree(d / "cache" / "views", tmp_path / "views")  # render once, fit in Ray
    argv = SWEEP + ["--cache-dir", str(tmp_path), "--ray", "--jobs", "2"]
    assert main(argv + ["--json", str(tmp_path / "r.json")]) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["stats"]["runner"] == "RayRunner" and rep["stats"]["fits"] == 4
    strip = [{k: v for k, v in r.items() if k != "median_ms"} for r in first["results"]]
    assert [{k: v for k, v in r.items() if k != "median_ms"} for r in rep["results"]] == strip


# ----------------------------------------------------------------------------- BOP
@pytest.mark.slow
def test_bop_export_uses_the_toolkit_field_names(local_sweep):
    d, _, _, _ = local_sweep
    bop = d / "bop"
    scenes = json.loads((bop / "scenes.json").read_text())
    assert len(scenes) == 4  # (banana, box) x (0, 50 %)
    sid = next(s for s, v in scenes.items() if v["object"] == "banana" and v["occlusion"] == 0)
    scene = bop / "test" / f"{int(sid):06d}"
    cam = json.loads((scene / "scene_camera.json").read_text())
    gt = json.loads((scene / "scene_gt.json").read_text())
    info = json.loads((scene / "scene_gt_info.json").read_text())
    assert sorted(cam, key=int) == [str(i) for i in range(6)] == sorted(gt, key=int)
    for k in ("cam_K", "depth_scale", "cam_R_w2c", "cam_t_w2c"):
        assert k in cam["0"]
    g = gt["0"][0]
    assert set(g) == {"cam_R_m2c", "cam_t_m2c", "obj_id"} and len(g["cam_R_m2c"]) == 9
    R = np.reshape(g["cam_R_m2c"], (3, 3))
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-6)
    assert 300 < np.linalg.norm(g["cam_t_m2c"]) < 3000  # millimetres
    assert info["0"][0]["visib_fract"] == 1.0
    assert (scene / "rgb" / "000000.png").is_file()
    assert (scene / "mask_visib" / "000000_000000.png").is_file()
    ids = json.loads((bop / "obj_ids.json").read_text())
    assert g["obj_id"] == ids["banana"]
    assert (bop / "models" / f"obj_{ids['banana']:06d}.ply").is_file()
    models_info = json.loads((bop / "models" / "models_info.json").read_text())
    assert models_info[str(ids["banana"])]["diameter"] > 50  # mm
    assert "symmetries_continuous" not in models_info[str(ids["banana"])]
    targets = json.loads((bop / "test_targets_bop19.json").read_text())
    assert {"im_id", "inst_count", "obj_id", "scene_id"} == set(targets[0]) and len(targets) == 24
    for name in ("manifold_scorbot-test.csv", "manifold-allocentric-True_scorbot-test.csv"):
        with open(bop / name, newline="") as f:
            rows = list(csv.DictReader(f))
        assert list(rows[0]) == ["scene_id", "im_id", "obj_id", "score", "R", "t", "time"]
        for r in rows:
            assert len(r["R"].split()) == 9 and len(r["t"].split()) == 3
            assert float(r["time"]) > 0 and 0 <= int(r["im_id"]) < 6


def test_bop_files_read_back_to_the_views_poses_and_estimates(tmp_path):
    """Round trip: what a BOP reader (json + PNG, the toolkit's units) gets back from the
    files is the rendered views, their ground truth and the estimates that were written."""
    import cv2

    from scorbot_gym.evaluation.bop import DEPTH_SCALE, write_results, write_scene

    views = held_out_views("side-turntable", "box", 0.5, width=160, height=120, depth=True)[:3]
    write_scene(tmp_path / "000001", views, obj_id=7)
    cams = json.loads((tmp_path / "000001" / "scene_camera.json").read_text())
    gts = json.loads((tmp_path / "000001" / "scene_gt.json").read_text())
    for i, lv in enumerate(views):
        cam, (gt,) = cams[str(i)], gts[str(i)]
        np.testing.assert_allclose(np.reshape(cam["cam_K"], (3, 3)), lv.view.camera.K)
        w2c = lv.view.camera.camera_from_world
        np.testing.assert_allclose(np.reshape(cam["cam_R_w2c"], (3, 3)), w2c[:3, :3])
        np.testing.assert_allclose(np.array(cam["cam_t_w2c"]) / 1000.0, w2c[:3, 3])
        T = lv.camera_from_object
        np.testing.assert_allclose(np.reshape(gt["cam_R_m2c"], (3, 3)), T[:3, :3])
        np.testing.assert_allclose(np.array(gt["cam_t_m2c"]) / 1000.0, T[:3, 3])
        assert gt["obj_id"] == 7
        rgb = cv2.imread(str(tmp_path / "000001" / "rgb" / f"{i:06d}.png"), cv2.IMREAD_COLOR)
        np.testing.assert_array_equal(cv2.cvtColor(rgb, cv2.COLOR_BGR2RGB), lv.view.image)
        mask = cv2.imread(str(tmp_path / "000001" / "mask_visib" / f"{i:06d}_000000.png"), 0)
        np.testing.assert_array_equal(mask > 0, lv.view.mask)
        depth = cv2.imread(str(tmp_path / "000001" / "depth" / f"{i:06d}.png"), -1)
        assert depth.dtype == np.uint16  # the toolkit's depth: value * depth_scale = mm
        in_range = (lv.view.depth > 0) & (lv.view.depth * 1000 / DEPTH_SCALE <= 65535)
        assert in_range[lv.view.mask].all()  # the object's depth always fits
        np.testing.assert_allclose(
            depth[in_range] * cam["depth_scale"] / 1000.0,
            lv.view.depth[in_range],
            atol=DEPTH_SCALE / 1000,
        )
        assert (depth[~in_range] == 0).all()  # beyond the PNG's range: unknown, not saturated
    rng = np.random.default_rng(0)
    rows = [
        {"scene_id": 1, "im_id": i, "obj_id": 7, "score": 0.5, "R": lv.camera_from_object[:3, :3],
         "t": lv.camera_from_object[:3, 3] * 1000.0 + rng.normal(0, 5, 3), "time": 0.02}
        for i, lv in enumerate(views)
    ]  # fmt: skip
    rows[1] = dict(rows[1], R=np.full((3, 3), np.nan))  # an invalid answer is left out
    write_results(tmp_path / "m_scorbot-test.csv", rows)
    with open(tmp_path / "m_scorbot-test.csv", newline="") as f:
        back = list(csv.DictReader(f))
    assert [int(r["im_id"]) for r in back] == [0, 2]
    for r in back:
        src = rows[int(r["im_id"])]
        np.testing.assert_allclose(np.reshape(np.fromstring(r["R"], sep=" "), (3, 3)), src["R"],
                                   atol=1e-8)  # fmt: skip
        np.testing.assert_allclose(np.fromstring(r["t"], sep=" "), src["t"], atol=1e-4)
        assert (int(r["scene_id"]), int(r["obj_id"]), float(r["score"])) == (1, 7, 0.5)
        assert float(r["time"]) == pytest.approx(0.02)


# ----------------------------------------------------------------------------- protocols
def test_held_out_views_are_deterministic(tmp_path):
    a = held_out_views(
        "side-turntable", "banana", 0.3, width=96, height=72, cache_dir=tmp_path / "a"
    )
    b = held_out_views(
        "side-turntable", "banana", 0.3, width=96, height=72, cache_dir=tmp_path / "b"
    )
    assert all(np.array_equal(x.view.image, y.view.image) for x, y in zip(a, b, strict=True))
    assert all(
        np.allclose(x.camera_from_object, y.camera_from_object) for x, y in zip(a, b, strict=True)
    )


# ----------------------------------------------------------------------------- perturbations
def _views(tmp_path, p, occ=0.0):
    return held_out_views(
        "top-resting", "banana", occ, width=96, height=72, cache_dir=tmp_path, perturbation=p
    )[:4]


@pytest.mark.slow
def test_perturbed_views_are_seeded_change_the_image_and_keep_the_nominal_camera(tmp_path):
    clean = _views(tmp_path / "c", None)
    p = Perturbation(lighting=0.5, surfaces=0.5, camera_rot_deg=1.0, noise_sigma=4, blur_sigma=1)
    a, b = _views(tmp_path / "a", p), _views(tmp_path / "b", p)
    other = _views(tmp_path / "a", Perturbation(**{**p.to_dict(), "seed": 1}))
    for x, y, c, o in zip(a, b, clean, other, strict=True):
        assert np.array_equal(x.view.image, y.view.image)  # seeded
        assert np.abs(x.view.image.astype(int) - c.view.image).mean() > 2  # changed
        assert not np.array_equal(x.view.image, o.view.image)  # the seed matters
        assert np.allclose(x.view.camera.world_from_camera, c.view.camera.world_from_camera)
        assert np.allclose(x.camera_from_object, c.camera_from_object)


def test_each_axis_draws_from_its_own_stream():
    from scorbot_gym.sim import Simulation

    sim = Simulation("banana", render_width=64, render_height=48)
    pt = ScenePerturber(sim)
    pt.apply(Perturbation(lighting=0.5, seed=3), 7)
    light = sim.model.light_dir.copy()
    pt.apply(Perturbation(lighting=0.5, camera_pos_m=0.02, surfaces=1.0, seed=3), 7)
    assert np.allclose(sim.model.light_dir, light)  # other axes on: same lighting draw
    cam = sim.camera_id("top")
    moved = np.linalg.norm(sim.model.cam_pos[cam] - pt._nominal["cam_pos"][cam])
    assert 0 < moved < 0.2
    pt.restore()
    assert np.array_equal(sim.model.cam_pos, pt._nominal["cam_pos"])
    assert np.array_equal(sim.model.light_dir, pt._nominal["light_dir"])
    sim.close()


def test_surfaces_put_a_photograph_on_the_table_and_restore_the_nominal_texture():
    import cv2

    from scorbot_gym.sim import Simulation

    def top(sim):
        sim.forward()
        return sim.render("top")

    sim = Simulation("banana", render_width=96, render_height=72)
    pt = ScenePerturber(sim)
    clean = top(sim)
    table = pt._textures[0]
    nominal = pt._tex_pixels(table).copy()
    pt.apply(Perturbation(surfaces=1.0, seed=3), 7)
    photo, shown = pt._tex_pixels(table).copy(), top(sim)
    assert np.abs(photo.astype(int) - nominal).mean() > 20  # the image itself is replaced
    sift = cv2.SIFT_create()
    n_clean = len(sift.detect(cv2.cvtColor(clean, cv2.COLOR_RGB2GRAY), None))
    n_photo = len(sift.detect(cv2.cvtColor(shown, cv2.COLOR_RGB2GRAY), None))
    assert n_photo > 1.5 * n_clean  # clutter SIFT fires on: what the axis is for
    pt.apply(Perturbation(surfaces=1.0, seed=3), 8)
    assert not np.array_equal(pt._tex_pixels(table), photo)  # a fresh draw per frame
    pt.apply(Perturbation(surfaces=1.0, seed=3), 7)
    assert np.array_equal(pt._tex_pixels(table), photo)  # seeded
    assert np.array_equal(top(sim), shown)  # the renderer shows the edited texture again
    pt.restore()
    assert np.array_equal(pt._tex_pixels(table), nominal)
    assert np.array_equal(top(sim), clean)  # ... and the nominal one after a restore
    sim.close()


def test_editing_the_perturbation_code_invalidates_perturbed_trials_only(monkeypatch):
    """A trial on perturbed views is keyed by the perturbation code, as the views are: an edit
    of what an axis does must not serve stale figures; clean trials keep their keys."""
    from scorbot_gym.data import perturbations
    from scorbot_gym.experiments.trial import ModelJob, trial_key

    def job(p):
        items = tuple(p.to_dict().items())
        return ModelJob("side-turntable", "manifold", "banana", 0, (0.0,), 96, 72, 3, 1, items, "")

    clean, perturbed = job(Perturbation()), job(Perturbation(surfaces=1.0))
    before = trial_key(clean, 0.0), trial_key(perturbed, 0.0)
    monkeypatch.setattr(perturbations, "code_fingerprint", lambda: "edited")
    assert trial_key(clean, 0.0) == before[0]
    assert trial_key(perturbed, 0.0) != before[1]


def test_perturbation_validation():
    assert not Perturbation().active
    assert Perturbation.parse_list(" none; lighting=0.5 ;") == [
        ("none", Perturbation()), ("lighting=0.5", Perturbation(lighting=0.5))
    ]  # fmt: skip
    assert Perturbation.parse_list(None) == []
    with pytest.raises(ValueError, match="glare"):
        Perturbation.parse_list("none;glare=1")
    assert Perturbation.parse("lighting=0.3,noise_sigma=4,seed=2") == Perturbation(
        lighting=0.3, noise_sigma=4.0, seed=2
    )
    with pytest.raises(ValueError, match="KEY=VALUE"):
        Perturbation.parse("fog=1")
    with pytest.raises(ValueError, match="lighting must be within"):
        Perturbation(lighting=2.0)
    with pytest.raises(ValueError, match="noise_sigma must be"):
        Perturbation(noise_sigma=-1)


@pytest.mark.slow
def test_env_perturbation_is_seeded_and_off_by_default():
    from scorbot_gym.envs.grasp import ScorbotGraspEnv

    kw = {"object_name": "banana", "cameras": ("top",), "image_width": 96, "image_height": 72}
    p = Perturbation(lighting=0.5, surfaces=0.5, camera_pos_m=0.01, noise_sigma=5)
    env, plain = ScorbotGraspEnv(**kw, perturbation=p), ScorbotGraspEnv(**kw)
    (o1, i1), (o2, _), (o0, i0) = env.reset(seed=4), env.reset(seed=4), plain.reset(seed=4)
    assert np.array_equal(o1["top_rgb"], o2["top_rgb"])
    assert np.abs(o1["top_rgb"].astype(int) - o0["top_rgb"]).mean() > 2
    assert np.allclose(
        i1["camera_params"]["top"]["world_from_camera"],
        i0["camera_params"]["top"]["world_from_camera"],
    )  # the nominal calibration
    np.testing.assert_allclose(o1["joint_pos"], o0["joint_pos"])
    s1, *_ = env.step(np.zeros(6, np.float32))
    assert not np.array_equal(s1["top_rgb"], o1["top_rgb"])  # fresh noise every frame
    off = ScorbotGraspEnv(**kw, perturbation=Perturbation())
    assert np.array_equal(off.reset(seed=4)[0]["top_rgb"], o0["top_rgb"])
    # the reference frame of the empty workspace comes from the same noisy camera
    noisy = ScorbotGraspEnv(**kw, perturbation=Perturbation(noise_sigma=5), capture_background=True)
    clean = ScorbotGraspEnv(**kw, capture_background=True)
    bg = [e.reset(seed=4)[1]["camera_background"]["top"]["rgb"] for e in (noisy, clean)]
    assert 2 < np.abs(bg[0].astype(int) - bg[1]).mean() < 6  # noise alone, σ 5 levels
    for e in (env, plain, off, noisy, clean):
        e.close()


def test_paired_differences_count_the_views_only_one_estimator_got_right():
    from scipy.stats import binomtest

    from scorbot_gym.experiments.aggregate import format_paired, paired_differences

    def row(est, obj, errs, occ=0.0):
        return {"protocol": "p", "estimator": est, "object": obj, "occlusion": occ,
                "rot_err_deg": errs}  # fmt: skip

    rows = [
        row("a", "box", [1.0, 2.0, 6.0, None, 4.99]),
        row("a", "ball", [0.5, 9.0]),
        row("b", "box", [7.0, 2.0, 1.0, 3.0, 5.0]),  # 5.0 is not within 5 degrees
        row("b", "ball", [30.0, None]),
    ]
    (d,) = paired_differences(rows, "a")
    # a right on box 0, 1, 4 and ball 0; b right on box 1, 2, 3
    assert (d["versus"], d["n"], d["only_estimator"], d["only_versus"]) == ("b", 7, 3, 2)
    assert d["diff"] == round((4 - 3) / 7, 4)
    assert d["mcnemar_p"] == pytest.approx(binomtest(3, 5, 0.5).pvalue, rel=1e-2)
    assert d["ci95"][0] < d["diff"] < d["ci95"][1]
    assert d["mcnemar_p_holm"] == d["mcnemar_p"]  # a family of one test
    (back,) = paired_differences(rows, "b")
    assert (back["only_estimator"], back["only_versus"]) == (2, 3) and back["diff"] == -d["diff"]
    assert "b" in format_paired([d])
    # a second level of the same protocol makes a family of two; another protocol its own
    more = [dict(r, occlusion=0.5) for r in rows] + [dict(r, protocol="q") for r in rows]
    by_cell = {(r["protocol"], r["occlusion"]): r for r in paired_differences(rows + more, "a")}
    assert by_cell["p", 0.0]["mcnemar_p_holm"] == pytest.approx(min(1.0, 2 * d["mcnemar_p"]))
    assert by_cell["q", 0.0]["mcnemar_p_holm"] == d["mcnemar_p"]
    with pytest.raises(ValueError, match="'c' is not in this sweep"):
        paired_differences(rows, "c")
    with pytest.raises(ValueError, match="not scored on the same views"):
        paired_differences(rows + [row("e", "box", [1.0])], "a")


def test_holm_adjustment_steps_down_and_stays_monotone():
    from scorbot_gym.evaluation.summary import holm_adjusted

    # sorted 0.005, 0.01, 0.03, 0.04 times 4, 3, 2, 1: 0.02, 0.03, 0.06, 0.04 -> 0.06 (monotone)
    assert holm_adjusted([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert holm_adjusted([0.5, 0.4, 1.0]) == [1.0, 1.0, 1.0]  # capped at 1
    assert holm_adjusted([0.2]) == [0.2] and holm_adjusted([]) == []
    rng = np.random.default_rng(0)
    p = rng.uniform(0, 0.2, 50)
    q = np.array(holm_adjusted(p))
    assert np.all(q >= p) and np.all(q <= np.minimum(1.0, 50 * p) + 1e-12)
    assert np.all(np.diff(q[np.argsort(p)]) >= 0)
    with pytest.raises(ValueError, match=r"p-values must be in \[0, 1\]"):
        holm_adjusted([0.1, 1.5])


def test_curve_summary_averages_each_curve_and_finds_where_it_meets_chance():
    from scorbot_gym.experiments.aggregate import chance_level, curve_summary, format_curves

    def cell(est, occ, s, asym=None):
        return {"protocol": "p", "estimator": est, "occlusion": occ, "success_5deg": s,
                "success_5deg_asymmetric": asym, "constant_answer_success_5deg": 0.4,
                "constant_answer_success_5deg_asymmetric": 0.0}  # fmt: skip

    results = [
        cell("a", 0.5, 0.4, 0.1),  # equal to chance: the image no longer helps
        cell("a", 0.0, 0.9, 0.8),
        cell("a", 0.25, 0.6, 0.5),
        cell("b", 0.0, 0.5),
        cell("b", 0.25, 0.45),
        cell("b", 0.5, None),  # no views: not averaged, and no better than chance
    ]
    chance = chance_level(results)  # no chance estimator: the constant answer, 0.4
    rows = {r["estimator"]: r for r in curve_summary(results, chance)}
    assert rows["a"]["levels"] == [0.0, 0.25, 0.5]
    assert rows["a"]["mean_success_5deg"] == round((0.9 + 0.6 + 0.4) / 3, 4)
    assert rows["a"]["mean_success_5deg_asymmetric"] == round((0.8 + 0.5 + 0.1) / 3, 4)
    assert rows["a"]["first_at_or_below_chance"] == 0.5
    assert rows["b"]["mean_success_5deg"] == round((0.5 + 0.45) / 2, 4)
    assert rows["b"]["mean_success_5deg_asymmetric"] is None
    assert rows["b"]["first_at_or_below_chance"] == 0.5
    above = curve_summary([cell("c", 0.0, 0.9)], chance)
    assert above[0]["first_at_or_below_chance"] is None
    text = format_curves(list(rows.values()))
    assert "3 levels, 0-50 %" in text and "50 %" in text.splitlines()[2]
    assert format_curves([]) == ""


@pytest.mark.slow
def test_the_report_summarises_every_curve_of_the_sweep(local_sweep):
    _, rep, _, out = local_sweep
    curves = {r["estimator"]: r for r in rep["curves"]}
    assert set(curves) == {"manifold", "manifold(allocentric=True)"}
    for est, row in curves.items():
        cells = [r for r in rep["results"] if r["estimator"] == est]
        assert row["levels"] == [0.0, 0.5]
        assert row["mean_success_5deg"] == pytest.approx(
            np.mean([r["success_5deg"] for r in cells]), abs=1e-4
        )
    assert "curves over 2 levels, 0-50 % occlusion" in out


def test_view_errors_keep_each_view_on_its_side_of_the_threshold():
    from scorbot_gym.experiments.aggregate import view_errors

    errs = [4.99996, 5.0, 5.00004, 0.123456, None]
    trial = {"protocol": "p", "estimator": "e", "object": "box", "occlusion": 0.0,
             "views": {"rot_err_deg": errs}}  # fmt: skip
    (row,) = view_errors([trial])
    assert row["rot_err_deg"] == [4.9999, 5.0, 5.0, 0.1234, None]
    hits = [e is not None and e < 5.0 for e in errs]
    assert [e is not None and e < 5.0 for e in row["rot_err_deg"]] == hits
