"""The ``clutter`` sweep over the whole catalogue with every estimator (issue 37, item 4): a
reduced run counts scenes, each object's views are rendered once before the model jobs, the
winners table counts the manifold's compositions (``select``, ``fallback``) as the manifold's,
and a figure of a dozen curves highlights the two a reader compares."""

from __future__ import annotations

import numpy as np
import pytest

from scorbot_gym.experiments.aggregate import builds_on_manifold, format_winners, winners
from scorbot_gym.experiments.plot import MANY_CURVES, highlighted, legend_label, success_figure
from scorbot_gym.experiments.runners import LocalRunner, make_jobs, run_sweep
from scorbot_gym.experiments.spec import SweepSpec
from scorbot_gym.experiments.trial import model_path, trial_path, views_jobs

L = "manifold-pnp(keypoints__upscale=2, refiner__keep_margin=0.0)"
SELECT = f"select(estimators=({L!r}, 'pca-rbf', 'chance'))"


# --- which estimators are the manifold's ----------------------------------------------------------
@pytest.mark.parametrize(
    ("label", "ours"),
    [
        ("manifold", True),
        ("manifold-no-words", True),
        (L, True),
        ("fallback", True),  # its default part is the manifold
        (f"fallback(estimator={L!r})", True),
        (SELECT, True),
        ("fallback(estimator='pca-nn')", False),
        ("select(estimators=('pca-rbf', 'chance'))", False),
        ("sift-pnp(upscale=2)", False),
        ("chance", False),
    ],
)
def test_compositions_of_the_manifold_are_the_manifolds(label, ours):
    assert builds_on_manifold(label) is ours


def _row(est, occ, success, n=40, blind=0.05):
    lo, hi = max(success - 0.1, 0.0), min(success + 0.1, 1.0)
    return {"protocol": "clutter", "estimator": est, "occlusion": occ, "n": n,
            "success_5deg": success, "success_5deg_ci95": [lo, hi],
            "constant_answer_success_5deg": blind}  # fmt: skip


def test_winners_name_the_best_baseline_and_a_selection_is_no_baseline():
    rows = [_row("manifold", 0.0, 0.5), _row(SELECT, 0.0, 0.8), _row("pca-nn", 0.0, 0.7),
            _row("chance", 0.0, 0.1),
            _row("manifold", 0.3, 0.2), _row(SELECT, 0.3, 0.3), _row("pca-nn", 0.3, 0.4),
            _row("chance", 0.3, 0.1)]  # fmt: skip
    w = {r["occlusion"]: r for r in winners(rows)}
    assert not w[0.0]["baseline_wins"] and w[0.0]["best_manifold"] == SELECT
    assert (w[0.0]["best_baseline"], w[0.0]["baseline_success_5deg"]) == ("pca-nn", 0.7)
    assert w[0.3]["baseline_wins"] and w[0.3]["won_by"] == "pca-nn"
    assert w[0.3]["manifold_success_5deg"] == 0.3
    table = format_winners(list(w.values()))
    assert "best baseline" in table and "BASELINE WINS: pca-nn" in table


def test_a_level_where_every_estimator_scored_0_names_no_winner():
    rows = [_row("manifold", 0.0, 0.5), _row("pca-nn", 0.0, 0.7),
            _row("manifold", 0.9, 0.0, blind=0.0), _row("pca-nn", 0.9, 0.0, blind=0.0),
            _row("manifold", 0.95, 0.0, blind=0.1),
            _row("pca-nn", 0.95, 0.2, blind=0.1)]  # fmt: skip
    w = {r["occlusion"]: r for r in winners(rows)}
    assert (w[0.0]["best"], w[0.0]["best_manifold"]) == ("pca-nn", "manifold")
    nobody = w[0.9]
    assert nobody["best"] is None and nobody["best_success_5deg"] == 0.0
    assert nobody["best_manifold"] is None and nobody["best_baseline"] is None
    assert nobody["manifold_success_5deg"] == 0.0 and not nobody["baseline_wins"]
    # the manifold's side at 0 names nobody, the baseline above it is named and wins
    assert w[0.95]["best_manifold"] is None and w[0.95]["best"] == "pca-nn"
    assert w[0.95]["baseline_wins"] and w[0.95]["won_by"] == "pca-nn"
    lines = format_winners(list(w.values())).splitlines()
    row_90 = next(line for line in lines if line.split()[:1] == ["90"])
    assert "none" in row_90 and "manifold" not in row_90 and "pca-nn" not in row_90
    row_0 = next(line for line in lines if line.split()[:1] == ["0"])
    assert "pca-nn" in row_0


# --- the figure of a dozen curves -----------------------------------------------------------------
BASELINES = ("pca-nn", "pca-rbf", "least-squares", "part-based", "n3m", "nearest-view",
             "sift-pnp", "sift-pnp(upscale=2)")  # fmt: skip


def _catalogue_rows():
    """Thirteen estimators over three bins of unequal size: ``select`` best of the manifold's
    side, ``sift-pnp(upscale=2)`` best baseline and winning the last bin."""
    levels = ((0.0, 300), (0.1, 60), (0.5, 7))
    ours = {"manifold": 0.5, "fallback": 0.45, SELECT: 0.8}
    theirs = {b: 0.1 + 0.05 * i for i, b in enumerate(BASELINES)}  # sift-pnp(upscale=2): 0.45
    theirs["sift-pnp(upscale=2)"] = 0.7
    rows = []
    for occ, n in levels:
        for est, s in {**ours, **theirs, "chance": 0.02}.items():
            if occ == 0.5 and est == "sift-pnp(upscale=2)":
                s = 0.9  # the baseline wins this bin
            rows.append(_row(est, occ, s, n=n))
    return rows


def test_the_highlighted_curves_are_each_sides_best_over_all_views():
    rows = _catalogue_rows()
    assert highlighted(rows) == (SELECT, "sift-pnp(upscale=2)")
    # one bin of two views where manifold is perfect does not make it the best
    rows += [_row("manifold", 0.9, 1.0, n=2)] + [
        _row(e, 0.9, 0.0, n=2) for e in {r["estimator"] for r in rows} - {"manifold"}
    ]
    assert highlighted(rows)[0] == SELECT


def test_a_crowded_figure_draws_two_curves_thick_the_rest_thin_and_marks_baseline_wins():
    import matplotlib.pyplot as plt

    rows = _catalogue_rows()
    labels = {r["estimator"] for r in rows}
    assert len(labels) > MANY_CURVES
    chance = {"success_5deg": [{"occlusion": o, "value": 0.02} for o in (0.0, 0.1, 0.5)]}
    fig = success_figure(rows, chance, "clutter")
    try:
        ax = fig.axes[0]
        label_of = {line.get_label(): line for line in ax.get_lines()}
        assert legend_label(SELECT) + " [best built on the manifold]" in label_of
        assert "sift-pnp(upscale=2) [best baseline]" in label_of
        tags = (" [best built on the manifold]", " [best baseline]")
        width = {}
        for text, line in label_of.items():
            for tag in tags:
                text = text.removesuffix(tag)
            width[text] = line.get_linewidth()
        thick = {label for label in labels if width[legend_label(label)] >= 2}
        assert thick == {SELECT, "sift-pnp(upscale=2)"}
        assert all(width[legend_label(label)] < 1 for label in labels - thick)
        stars = [line for line in ax.get_lines() if line.get_marker() == "*"]
        assert len(stars) == 1 and list(stars[0].get_xdata()) == [50.0]  # the bin it won
        texts = {t.get_text() for t in ax.texts}
        assert {"n=300", "n=60", "n=7"} <= texts  # views per bin, under the axis
        assert len(ax.get_legend().get_texts()) == len(labels) + 2  # + chance + the stars
    finally:
        plt.close(fig)


def test_a_few_curves_are_drawn_alike():
    import matplotlib.pyplot as plt

    rows = [r for r in _catalogue_rows() if r["estimator"] in ("manifold", "pca-nn", "chance")]
    chance = {"success_5deg": [{"occlusion": o, "value": 0.02} for o in (0.0, 0.1, 0.5)]}
    fig = success_figure(rows, chance)
    try:
        widths = {line.get_linewidth() for line in fig.axes[0].get_lines() if line.get_marker()
                  == "o"}  # fmt: skip
        assert widths == {1.5}
        assert not [line for line in fig.axes[0].get_lines() if line.get_marker() == "*"]
    finally:
        plt.close(fig)


# --- each object's views rendered once, before the model jobs ----------------------------------
def test_views_jobs_plan_one_render_per_object_and_nothing_once_cached(tmp_path):
    spec = SweepSpec("clutter", ("chance", "pca-nn"), (0.0, 0.1), ("box", "banana"))
    jobs = make_jobs(spec, str(tmp_path))
    plan = views_jobs(jobs)
    assert [(v.job.object_name, v.train, v.occlusions) for v in plan] == [
        ("box", True, (0.0, 0.1)), ("banana", True, (0.0, 0.1)),
    ]  # fmt: skip
    for job in jobs:  # every box model cached, one banana trial still missing
        if job.object_name == "box":
            model_path(job).parent.mkdir(parents=True, exist_ok=True)
            model_path(job).touch()
        for occ in job.occlusions:
            if (job.object_name, job.estimator, occ) != ("banana", "pca-nn", 0.1):
                trial_path(job, occ).parent.mkdir(parents=True, exist_ok=True)
                trial_path(job, occ).touch()
    plan = views_jobs(jobs)
    assert [(v.job.object_name, v.train, v.occlusions) for v in plan] == [("banana", True, (0.1,))]
    trial_path(jobs[-1], 0.1).touch()
    assert views_jobs(jobs) == []


# --- a reduced clutter sweep end to end: scenes, cost per estimator --------------------------
@pytest.mark.slow
def test_a_reduced_clutter_sweep_counts_scenes_and_each_estimators_cost(tmp_path):
    from scorbot_gym.data.protocols import CLUTTER_BINS, held_out_views

    kw = dict(width=96, height=72, seed=1, cache_dir=tmp_path)
    few = {b: held_out_views("clutter", "banana", b, n_poses=3, **kw) for b in CLUTTER_BINS}
    more = {b: held_out_views("clutter", "banana", b, n_poses=5, **kw) for b in CLUTTER_BINS}
    assert 0 < sum(map(len, few.values())) <= 3 < sum(map(len, more.values())) <= 5

    def same_scene(a, b) -> bool:  # the sim holds other objects: a grey level may differ
        diff = np.abs(a.view.image.astype(int) - b.view.image.astype(int)).max()
        same_pose = np.allclose(a.camera_from_object, b.camera_from_object)
        return (
            same_pose
            and a.occlusion == b.occlusion
            and diff <= 2
            and np.array_equal(a.view.mask, b.view.mask)
        )

    for b in CLUTTER_BINS:  # scene i is the same scene whatever the number rendered
        assert all(any(same_scene(v, m) for m in more[b]) for v in few[b])
    with pytest.raises(ValueError, match="n_poses must be >= 1"):
        held_out_views("clutter", "banana", 0.0, n_poses=0, **kw)

    spec = SweepSpec("clutter", ("chance", "pca-nn"), CLUTTER_BINS, ("banana",), 0, 96, 72, 4)
    run = run_sweep(spec, LocalRunner(1), str(tmp_path))
    assert sum(len(t["views"]["rot_err_deg"]) for t in run["trials"]) == 2 * 4  # 4 scenes each
    stats = run["stats"]
    assert stats["views_jobs"] == 1 and stats["views_s"] > 0 and stats["views_cpu_s"] > 0
    assert set(stats["by_estimator"]) == {"chance", "pca-nn"}
    for cost in stats["by_estimator"].values():
        assert cost["jobs"] == 1 and cost["job_s"] > 0 and cost["job_cpu_s"] > 0
    again = run_sweep(spec, LocalRunner(1), str(tmp_path))["stats"]
    assert again["views_jobs"] == 0 and again["trials_cached"] == 2 * len(CLUTTER_BINS)
