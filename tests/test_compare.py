"""``scorbot-gym compare``: paired arms, the documented report, policy folders as arms, the
figure's panels and the markdown table (issue #36 item 6)."""

import json
import re
import shutil

import pytest

from scorbot_gym.cli import main
from scorbot_gym.evaluation import compare as cmp
from scorbot_gym.policies.sb3 import SHIPPED_POLICY

pytestmark = pytest.mark.rl

#: the report's keys at each level, as the module docstring documents them
TOP = {
    "seeds", "episodes", "objects", "action_type", "cartesian_ik", "estimate_every", "reference",
    "difference_method", "noise_heading_deg_per_m", "wall_s",
    "conditions", "arms", "results", "differences", "noise_curves",
}  # fmt: skip
RECORD = {
    "policy", "label", "pose", "pose_source", "noise_pos_m", "noise_yaw_deg", "episodes",
    "successes", "success_rate", "ci95", "steps_to_success", "median_steps_to_success",
    "mean_steps_to_success", "failure_causes", "per_object", "perception", "training",
    "saw_scripted_controller", "vs_reference", "episode_success",
}  # fmt: skip
TRAINING = {
    "trained_from", "uses_scripted_controller", "algo", "demonstration_episodes", "env_steps",
    "wall_time_s", "seeds", "source",
}  # fmt: skip
DIFFERENCE = {"pose", "a", "b", "diff", "ci95", "only_a", "only_b", "mcnemar_p"}
CURVE_POINT = {"pose", "noise_pos_m", "noise_yaw_deg", "episodes", "success_rate", "ci95"}


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    """A `scorbot-gym train` run folder around a real SB3 policy (the shipped one's files),
    with the run's own bookkeeping: env steps and wall time in checkpoint/state.json, the
    seed in config.json."""
    run = tmp_path_factory.mktemp("runs") / "my_run"
    shutil.copytree(SHIPPED_POLICY, run / "policy")
    (run / "checkpoint").mkdir()
    (run / "checkpoint" / "state.json").write_text(
        json.dumps({"timesteps": 1234, "wall_s": 56.5, "eval": []})
    )
    (run / "config.json").write_text(json.dumps({"seed": 7}))
    return run


@pytest.fixture(scope="module")
def cli_report(tmp_path_factory, run_folder):
    out = tmp_path_factory.mktemp("compare")
    js, png = out / "cmp.json", out / "cmp.png"
    argv = ["compare", "--policies", f"scripted,rl,{run_folder}", "--pose", "oracle"]
    argv += ["--noise", "0.02:20", "--episodes", "2", "--objects", "box", "--jobs", "2"]
    assert main([*argv, "--json", str(js), "--png", str(png), "--no-progress"]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    return json.loads(js.read_text())


@pytest.mark.slow
def test_cli_writes_every_documented_key_and_documents_every_key_it_writes(cli_report):
    r = cli_report
    assert set(r) == TOP
    assert [c["label"] for c in r["conditions"]] == ["oracle", "noisy@0.02:20"]
    assert len(r["results"]) == 6 and r["reference"] == "scripted"
    for rec in r["results"]:
        assert set(rec) == RECORD
        assert set(rec["training"]) == TRAINING
        assert rec["episodes"] == 2 and len(rec["episode_success"]) == 2
        assert set(rec["per_object"]) == {"box"}
        assert set(rec["per_object"]["box"]) == {"episodes", "successes", "success_rate", "ci95"}
        if rec["steps_to_success"] is not None:
            assert set(rec["steps_to_success"]) == {"median", "q25", "q75", "mean"}
        assert (rec["vs_reference"] is None) == (rec["policy"] == "scripted")
    assert len(r["differences"]) == 4 and all(set(d) == DIFFERENCE for d in r["differences"])
    assert all(d["b"] == "scripted" for d in r["differences"])
    noisy = next(c for c in r["results"] if c["pose"] == "noisy@0.02:20")
    assert (noisy["noise_pos_m"], noisy["noise_yaw_deg"]) == (0.02, 20.0)
    for points in r["noise_curves"].values():
        assert [p["pose"] for p in points] == ["oracle", "noisy@0.02:20"]
        assert all(set(p) == CURVE_POINT for p in points)
    written = TOP | RECORD | TRAINING | DIFFERENCE | CURVE_POINT
    undocumented = {k for k in written if not re.search(rf"\b{k}\b", cmp.__doc__)}
    assert not undocumented, undocumented


@pytest.mark.slow
def test_how_each_arm_was_trained_comes_from_its_folder_never_guessed(cli_report, run_folder):
    arms = cli_report["arms"]
    assert arms["scripted"]["training"]["trained_from"] == "scripted"
    rl = arms["rl"]["training"]
    assert rl["trained_from"] == "residual" and rl["uses_scripted_controller"] is True
    assert rl["env_steps"] == 10000 and rl["seeds"] == [0]
    shipped = json.loads((SHIPPED_POLICY / "policy.json").read_text())["training"]
    assert rl["wall_time_s"] == shipped["wall_time_s"]  # as its policy.json records it
    assert rl["source"] == "scorbot_gym/policies/data/residual_sac_oracle"  # not this install's
    assert arms[str(run_folder)]["label"] == "my_run"
    run = arms[str(run_folder)]["training"]
    assert (run["env_steps"], run["wall_time_s"], run["seeds"]) == (1234, 56.5, [7])


@pytest.mark.slow
def test_api_gives_the_cli_episodes_whatever_the_number_of_processes(cli_report):
    """Same seeds, one process instead of two: the same episodes, episode by episode; the
    shipped stand-alone policy is an arm by its name."""
    policies = ["scripted", "rl", "learned"]
    report = cmp.compare(policies, ["oracle"], 2, objects=["box"], progress=False)
    assert set(report) == TOP and all(set(r) == RECORD for r in report["results"])
    learned = report["arms"]["learned"]["training"]  # the shipped stand-alone policy
    assert learned["trained_from"] == "demonstrations"
    assert learned["uses_scripted_controller"] is False and learned["algo"] == "imitation"
    cli = {(r["policy"], r["pose"]): r for r in cli_report["results"]}
    for rec in report["results"][:2]:
        other = cli[(rec["policy"], "oracle")]
        assert rec["episode_success"] == other["episode_success"]
        assert rec["steps_to_success"] == other["steps_to_success"]


def test_bad_arms_are_one_line_errors_naming_the_valid_ones(capsys, tmp_path):
    assert main(["compare", "--policies", "scripted,nope", "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "'nope'" in err
    assert all(name in err for name in cmp.BUILTIN_ARMS)
    assert main(["compare", "--policies", f"scripted,{tmp_path}", "--episodes", "1"]) == 2
    assert "policy.json" in capsys.readouterr().err
    with pytest.raises(ValueError, match="given twice"):
        cmp.compare(["scripted", "scripted"], ["oracle"], 1)
    with pytest.raises(ValueError, match=r"cartesian_ik must be one of \('closed_form', 'dls'\)"):
        cmp.compare(["scripted"], ["oracle"], 1, cartesian_ik="jacobian")
    with pytest.raises(SystemExit):  # checked while parsing
        main(["compare", "--noise", "0.02:x"])


def test_builtin_arms_are_the_policies_the_command_line_names():
    """A built-in added to the registry and not to scorbot_gym.names (or the other way round)
    would be missing from --help or fail to resolve."""
    from scorbot_gym.names import POLICIES

    assert tuple(cmp.BUILTIN_ARMS) == POLICIES


def test_noise_levels_pair_position_and_heading():
    assert cmp.noise_level(0.01) == (0.01, 5.0)  # 1 cm goes with 5 degrees
    assert cmp.noise_level("0.02:20") == (0.02, 20.0)
    assert cmp.noise_level((0.02, 20)) == (0.02, 20.0)
    conds = cmp.pose_conditions(["oracle"], ["0.02", "0.02:20"])
    assert [c.label for c in conds] == ["oracle", "noisy@0.02", "noisy@0.02:20"]
    assert conds[2].kwargs == {"pos_sigma_m": 0.02, "yaw_sigma_deg": 20.0}
    with pytest.raises(ValueError, match="given twice"):
        cmp.pose_conditions(["oracle"], ["0.02", "0.02:10"])  # the same condition
    for bad in ("x", "0.01:2:3", "-0.01", "0.01:-5"):
        with pytest.raises(ValueError, match="noise level"):
            cmp.noise_level(bad)


def test_training_record_reads_imitation_and_from_scratch_metadata(tmp_path):
    imitation = {
        "algo": "imitation",
        "uses_scripted_controller": False,
        "training": {
            "demonstration_episodes": 200,
            "env_steps": 40000,
            "wall_time_s": 812.5,
            "config": {"seed": 3},
        },
    }
    t = cmp.training_record(tmp_path / "learned", imitation)
    assert t["trained_from"] == "demonstrations" and t["uses_scripted_controller"] is False
    assert (t["demonstration_episodes"], t["env_steps"], t["wall_time_s"]) == (200, 40000, 812.5)
    assert t["seeds"] == [3]
    scratch = {"algo": "sac", "residual": None, "trained_timesteps": 3000}
    t = cmp.training_record(tmp_path / "scratch", scratch)
    assert t["trained_from"] == "none" and t["uses_scripted_controller"] is False
    assert (t["env_steps"], t["wall_time_s"], t["seeds"]) == (3000, None, None)


@pytest.mark.slow
def test_markdown_table_has_one_row_per_arm(cli_report):
    text = cmp.markdown_table(cli_report)
    lines = text.strip().splitlines()
    assert len(lines) == 2 + len(cli_report["results"])
    assert "Δ vs scripted" in lines[0] and "McNemar p" in lines[0]
    assert "controller + learned correction" in text
    wall = json.loads((SHIPPED_POLICY / "policy.json").read_text())["training"]["wall_time_s"]
    assert f"{wall:,.0f} s wall" in text  # the shipped residual's policy.json records its time
    assert "1,234 env steps, 56 s wall, seed 7" in text


def test_the_occluded_condition_runs_the_hand_hidden_oracle_off_the_noise_curves():
    """``occluded`` is the training corruptor's pose (its defaults), recorded as no noise
    level; in the episodes the estimate goes stale as the hand closes in."""
    (cond,) = cmp.pose_conditions(["occluded"])
    assert (cond.label, cond.source, cond.kwargs) == ("occluded", "occluded_oracle", {})
    assert cond.record()["noise_pos_m"] is None and cond.record()["estimator"] is None
    report = cmp.compare(["scripted"], ["oracle", "occluded"], 2, objects=["box"], progress=False)
    by = {r["pose"]: r for r in report["results"]}
    assert by["occluded"]["pose_source"] == "occluded_oracle"
    assert by["oracle"]["perception"]["valid_rate"] == 1.0
    assert 0.0 < by["occluded"]["perception"]["valid_rate"] < 0.9  # lost near the hand
    assert [p["pose"] for p in report["noise_curves"]["scripted"]] == ["oracle"]
    from scorbot_gym.evaluation.compare_plot import condition_title

    assert condition_title("occluded", None) == "true pose, hidden near the hand"
    near, ranged = cmp.pose_conditions(["occluded@0.1", "occluded@0.06:0.2"])
    assert (near.label, near.kwargs) == ("occluded@0.1:0.1", {"hide_distance_m": [0.1, 0.1]})
    assert ranged.kwargs == {"hide_distance_m": [0.06, 0.2]}
    assert (
        condition_title("occluded@0.06:0.2", None, short=True)
        == "hidden near the hand (0.06–0.2 m)"
    )
    for bad in ("occluded@", "occluded@x", "occluded@0.2:0.1", "occluded@-1", "occluded@1:2:3"):
        with pytest.raises(ValueError, match="expected occluded@D or occluded@LOW:HIGH"):
            cmp.pose_conditions([bad])
