"""The command line's parsing: what ``--help`` and argument errors import, how errors name the
sub-command, and the same ``--pose manifold`` default everywhere (issue 35, items 2 and 3)."""

import json
import subprocess
import sys

import pytest

from scorbot_gym.cli import build_parser, main

# the learners, OpenCV, the simulator and scikit-learn / SciPy's statistics: seconds of imports
HEAVY = ("torch", "stable_baselines3", "cv2", "mujoco", "dm_control", "sklearn", "scipy.stats")

_IMPORTS_AFTER = f"""
import json, sys
from scorbot_gym.cli import main
try:
    code = main(sys.argv[1:])
except SystemExit as exc:
    code = exc.code
print(json.dumps({{"code": code, "imported": [m for m in {HEAVY!r} if m in sys.modules]}}))
"""


def _imports_after(*argv: str) -> dict:
    """Exit code, and which of HEAVY a fresh interpreter imported, for ``scorbot-gym argv``."""
    proc = subprocess.run(
        [sys.executable, "-c", _IMPORTS_AFTER, *argv], capture_output=True, text=True, timeout=120
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize(
    "argv, code",
    [(["--help"], 0), ([], 2), (["teleport"], 2), (["pose"], 2), (["pose", "--help"], 0)],
)
def test_help_and_argument_errors_import_no_simulator_learner_or_opencv(argv, code):
    assert _imports_after(*argv) == {"code": code, "imported": []}


@pytest.mark.parametrize(
    "argv, code",
    [
        (["rollout", "--help"], 0),
        (["rollout", "--episodes", "0"], 2),
        (["rollout", "--pose", "sonar"], 2),
        (["train", "--help"], 0),
        (["train", "--algo", "dqn"], 2),
        (["compare", "--help"], 0),
        (["compare", "--episodes", "0"], 2),
        (["pose", "ablate", "--help"], 0),
        (["pose", "ablate", "--jobs", "0"], 2),
        (["pose", "ablate"], 2),  # --protocol missing
        (["pose", "train", "--help"], 0),
        (["pose", "train", "--camera", "ceiling"], 2),
        (["pose", "eval", "--help"], 0),
        (["shapes", "eval", "--help"], 0),
        (["doctor", "--help"], 0),
        (["demos", "--help"], 0),
        (["demos", "--episodes", "0"], 2),
    ],
)
def test_sub_command_help_and_argument_errors_import_nothing_heavy(argv, code):
    """The option choices come from :mod:`scorbot_gym.names`; the work is imported by ``run``."""
    assert _imports_after(*argv) == {"code": code, "imported": []}


def test_pose_ablate_without_occlusion_sweeps_the_default_levels(monkeypatch):
    """The default levels are parsed when the sweep starts (not while parsing): still 0:95:5."""
    import scorbot_gym.experiments as experiments
    from scorbot_gym.experiments.spec import parse_occlusions

    class Started(Exception):
        pass

    def ablate(spec, runner, cache_dir):
        raise Started(spec)

    monkeypatch.setattr(experiments, "ablate", ablate)
    with pytest.raises(Started) as started:
        main(["pose", "ablate", "--protocol", "top-resting", "--objects", "box", "--jobs", "1"])
    assert started.value.args[0].occlusions == parse_occlusions("0:95:5")


_REGISTERED_NAMES = """
import json
from scorbot_gym.data.protocols import protocol_names
from scorbot_gym.perception.calibration import calibration_names
from scorbot_gym.evaluation.rollout import POLICIES, POSE_ALIASES
from scorbot_gym.perception import pose_source_names, segmenter_names
from scorbot_gym.perception.motion import motion_names
from scorbot_gym.perception.recognizers import RECOGNIZERS
from scorbot_gym.perception.splitters import SPLITTERS
from scorbot_gym.perception.support import support_names
from scorbot_gym.sim.scene import DEFAULT_CAMERAS
from scorbot_gym.sim.simulation import MOVING_CAMERAS
from scorbot_gym.tasks.disturbance import DISTURBANCES
from scorbot_gym.wrappers.pose_observation import IDENTITIES

print(json.dumps({
    "POLICIES": POLICIES, "POSE_ALIASES": POSE_ALIASES, "POSE_SOURCES": pose_source_names(),
    "FIXED_CAMERAS": [c.name for c in DEFAULT_CAMERAS], "MOVING_CAMERAS": MOVING_CAMERAS,
    "SEGMENTERS": segmenter_names(), "RECOGNIZERS": RECOGNIZERS, "MOTIONS": motion_names(),
    "DISTURBANCES": list(DISTURBANCES), "PROTOCOLS": protocol_names(), "SPLITTERS": SPLITTERS,
    "SUPPORTS": support_names(), "IDENTITIES": IDENTITIES, "CALIBRATIONS": calibration_names(),
}))
"""


def test_the_command_lines_names_are_the_registries_names():
    """One source of truth: every registry the options name agrees with scorbot_gym.names
    (asked in a fresh interpreter, where no test has registered a pose source of its own)."""
    from scorbot_gym import names

    proc = subprocess.run(
        [sys.executable, "-c", _REGISTERED_NAMES], capture_output=True, text=True, timeout=300
    )
    registered = json.loads(proc.stdout.strip().splitlines()[-1])
    light = {k: v for k, v in vars(names).items() if k.isupper()}
    assert light.keys() == registered.keys()
    light = {k: list(v) if isinstance(v, tuple) else v for k, v in light.items()}
    assert light == registered


def _subparser(*path: str):
    parser = build_parser()
    for name in path:
        action = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
        parser = action.choices[name]
        parser.format_help()  # fills it in
    return parser


def test_compare_has_a_description_and_help_on_every_option():
    parser = _subparser("compare")
    assert parser.description and "paired" in parser.description
    undocumented = [a.option_strings for a in parser._actions if not a.help]
    assert undocumented == []


def test_errors_name_the_sub_command(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["pose", "ablate", "--protocol", "top-resting", "--jobs", "0"])
    assert exc.value.code == 2
    assert "scorbot-gym pose ablate: error: argument --jobs" in capsys.readouterr().err
    # errors found after parsing name it too, not the group (`scorbot-gym pose: error:`)
    argv = ["pose", "ablate", "--protocol", "top-resting", "--paired", "pca-nn"]
    assert main(argv) == 2
    assert "scorbot-gym pose ablate: error: --paired 'pca-nn'" in capsys.readouterr().err
    assert main(["compare", "--pose", "manifold", "--pose-model", str(tmp_path / "no.npz")]) == 2
    assert "scorbot-gym compare: error: --pose-model" in capsys.readouterr().err


@pytest.fixture(scope="module")
def box_models(tmp_path_factory):
    """Pose models of the box alone (few views): stand-ins for the default models, which cover
    the whole catalogue and take minutes to train on a cold cache."""
    from pose.model_set import PoseModelSet

    d = tmp_path_factory.mktemp("box_models")
    argv = ["pose", "train", "--objects", "box", "--views", "36", "--width", "320"]
    argv += ["--height", "240", "--out", str(d / "box.npz"), "--cache-dir", str(d), "--quiet"]
    assert main(argv) == 0
    return PoseModelSet.load(d / "box.npz")


@pytest.fixture()
def default_models(monkeypatch, box_models):
    """``default_pose_models`` (what rollout uses without --pose-model), counting its calls."""
    import scorbot_gym.perception.training as training

    calls = []

    def default_pose_models(*args, **kwargs):
        calls.append((args, kwargs))
        return box_models

    monkeypatch.setattr(training, "default_pose_models", default_pose_models)
    return calls


@pytest.mark.slow
def test_compare_manifold_without_a_model_uses_the_default_models(default_models, capsys):
    assert main(["compare", "--policies", "scripted", "--pose", "manifold", "--objects", "box",
                 "--episodes", "1", "--no-progress"]) == 0  # fmt: skip
    assert len(default_models) == 1  # once for every arm
    assert "manifold" in capsys.readouterr().out


@pytest.mark.slow
def test_training_config_manifold_without_a_model_uses_the_default_models(default_models):
    from scorbot_gym.rl.training import TrainConfig, make_policy_env

    config = TrainConfig(pose="manifold", objects=["box"]).validate()
    env = make_policy_env(config)
    try:
        obs, info = env.reset(seed=0)
        assert "object_pos" in obs and info["perception"]["source"] == "manifold"
    finally:
        env.close()
    assert len(default_models) == 1
