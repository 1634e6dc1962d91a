"""Bad input at reset, at registration, to the pose wrapper, in a vector-env worker and in a
policy folder: one line naming the bad value and what is valid (issue 35, item 15; issue 50)."""

from __future__ import annotations

import functools
import json
import multiprocessing
import os
import shutil
import signal

import gymnasium as gym
import numpy as np
import pytest

from scorbot_gym import OverlappedVectorEnv, WatchedAsyncVectorEnv, make_env, pin_env_fns
from scorbot_gym.envs.worker import WorkerEnvFn
from scorbot_gym.objects import CATALOGUE, register_object


@pytest.fixture(scope="module")
def box_env():
    env = gym.make("ScorbotGrasp-v0", object_name="box")  # the box has 3 resting faces
    # Gymnasium 1.4's PassiveEnvChecker breaks (TypeError at the first step) when the first
    # reset raises: start from a good one.
    env.reset(seed=0)
    yield env
    env.close()


@pytest.mark.parametrize(
    "value, message",
    [
        (1.7, r"options\['resting_index'\] must be an int in \[0, 2\] \(box has 3 resting "),
        ("1", r"must be an int in \[0, 2\] .*got '1'"),
        (True, r"must be an int in \[0, 2\] .*got True"),
        (3, r"options\['resting_index'\] must be in \[0, 2\] .*got 3"),
        (-1, r"must be in \[0, 2\] .*got -1"),
    ],
)
def test_a_bad_resting_index_is_refused_in_one_line(box_env, value, message):
    with pytest.raises(ValueError, match=message) as err:
        box_env.reset(seed=0, options={"resting_index": value})
    assert "\n" not in str(err.value)


def test_resting_index_takes_any_int_kind(box_env):
    poses = [
        box_env.reset(seed=0, options={"resting_index": i})[1]["object_pose"]["quaternion"]
        for i in (2, np.int64(2), 0)
    ]
    np.testing.assert_array_equal(poses[0], poses[1])
    assert not np.allclose(poses[0], poses[2])  # another face down


def test_options_must_be_a_dict(box_env):
    with pytest.raises(ValueError, match=r"options must be a dict or None \(keys: object_name, "):
        box_env.reset(options="banana")
    box_env.reset(seed=0, options=None)
    box_env.step(np.zeros(6, np.float32))


def test_register_object_refuses_a_long_name_and_a_nan_scale(user_object):
    mesh = user_object.source
    with pytest.raises(ValueError, match=r"1-64 characters of \[A-Za-z0-9_\], got 'xxx.*\(300 ch"):
        register_object("x" * 300, mesh, mass=0.1)
    with pytest.raises(ValueError, match="object name must be .* got 'a b'"):
        register_object("a b", mesh, mass=0.1)
    with pytest.raises(ValueError, match="object name must be .* got 7"):
        register_object(7, mesh, mass=0.1)
    for scale in (float("nan"), float("inf"), 0.0, "2"):
        with pytest.raises(ValueError, match="scale must be a finite number > 0, got"):
            register_object("scaled_block", mesh, mass=0.1, scale=scale)
    assert "scaled_block" not in CATALOGUE and "x" * 300 not in CATALOGUE
    register_object("x" * 64, mesh, mass=0.1, scale=0.5)  # the longest name is fine
    CATALOGUE.pop("x" * 64)


def test_make_env_classes_must_be_a_list_of_names():
    with pytest.raises(ValueError, match=r"classes must be a list of names, e.g. classes=\['ba"):
        make_env(classes="banana", object_name="banana")
    with pytest.raises(ValueError, match="classes must name at least one catalogue object"):
        make_env(classes=[], object_name="banana")
    env = make_env(classes=["banana", "box"], object_name="banana")
    assert env.observation_space["object_class"].shape == (2,)
    env.close()


GOOD = functools.partial(gym.make, "scorbot_gym:ScorbotGrasp-v0", object_name="box")
BAD = functools.partial(gym.make, "scorbot_gym:ScorbotGrasp-v0", object_name="nope")
BAD_WRAPPED = functools.partial(make_env, pose="oracle", object_name="nope")
UNKNOWN = "unknown object 'nope'; valid objects: banana"


@pytest.mark.parametrize(
    "make_vector",
    [
        lambda: gym.vector.AsyncVectorEnv([GOOD, BAD], context="fork"),
        lambda: gym.vector.AsyncVectorEnv([GOOD, BAD], context="spawn"),
        lambda: gym.vector.AsyncVectorEnv([WorkerEnvFn(GOOD), WorkerEnvFn(BAD_WRAPPED)]),
        lambda: gym.vector.AsyncVectorEnv(pin_env_fns([GOOD, BAD]), context="fork"),
        lambda: OverlappedVectorEnv([GOOD, GOOD, BAD_WRAPPED], context="fork"),
    ],
    ids=["plain-fork", "plain-spawn", "worker-env-fn-make-env", "pinned", "overlapped"],
)
def test_a_worker_that_cannot_make_its_env_raises_the_workers_error(make_vector):
    if "fork" not in multiprocessing.get_all_start_methods():
        pytest.skip("needs fork")
    with pytest.raises(KeyError, match=UNKNOWN):  # was ConnectionResetError / BrokenPipeError
        vec = make_vector()
        vec.reset(seed=0)


def test_worker_env_fn_in_the_main_process_just_makes_the_env():
    with pytest.raises(KeyError, match=UNKNOWN):
        WorkerEnvFn(BAD)()
    env = WorkerEnvFn(GOOD)()
    assert isinstance(env.observation_space, gym.spaces.Dict)
    env.close()


# --- issue 50: the contract's bad input -----------------------------------------------------
@pytest.mark.parametrize(
    "options, message",
    [
        ({"target": ["box"]}, r"options\['target'\]: target \['box'\] is not one of this env's ta"),
        ({"object_name": 7}, r"options\['object_name'\]: target 7 is not one of this env's targ"),
        ({"target": "banana"}, r"target 'banana' is not one of this env's targets \['box'\] \(m"),
        ({"target": "teapot"}, r"target 'teapot' is not one of this env's targets \['box'\]"),
        ({"taget": "box"}, r"unknown reset option 'taget'; valid keys: object_name, target, re"),
        ({1: 2, "x": 0}, r"unknown reset options 1, 'x'; valid keys: object_name, target, "),
        ({"target": "box", "object_name": "banana"}, r"both name the object to grasp; give one"),
    ],
)
def test_a_bad_reset_option_is_refused_in_one_line(box_env, options, message):
    with pytest.raises(ValueError, match=message) as err:
        box_env.reset(seed=0, options=options)
    assert "\n" not in str(err.value)
    obs, info = box_env.reset(seed=0, options={"target": "box", "object_name": "box"})
    assert info["object_name"] == "box"


@pytest.mark.parametrize("distractors", [0, 1])
def test_a_target_outside_objects_is_refused_alike_with_and_without_distractors(distractors):
    env = gym.make("ScorbotGrasp-v0", objects=["box", "banana"], distractors=distractors)
    with pytest.raises(ValueError) as err:
        env.unwrapped.reset(seed=0, options={"target": "golf_ball"})
    assert str(err.value) == (
        "options['target']: target 'golf_ball' is not one of this env's targets ['box', "
        "'banana'] (make the env with objects=[...] to grasp others)"
    )
    env.close()


def test_tilt_is_at_most_30_degrees_as_the_readme_says():
    for bad in (31, 30.5, -1, float("nan"), "10"):
        with pytest.raises(ValueError, match=r"tilt_deg must be a number of degrees in \[0, 30\]"):
            gym.make("ScorbotGrasp-v0", object_name="box", tilt_deg=bad)
    gym.make("ScorbotGrasp-v0", object_name="box", tilt_deg=30).close()


def test_the_rollout_cli_refuses_a_tilt_over_30_before_any_work(capsys):
    from scorbot_gym.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(["rollout", "--tilt-deg", "31"])
    assert exit_.value.code == 2
    assert "--tilt-deg: must be in [0, 30] degrees, got 31" in capsys.readouterr().err


BAD_MODELS = functools.partial(
    make_env, pose="manifold", pose_kwargs={"models": "/nonexistent/models.npz"}, objects=["box"]
)


def test_a_bad_model_path_in_a_workers_make_env_raises_the_workers_error():
    if "fork" not in multiprocessing.get_all_start_methods():
        pytest.skip("needs fork")
    with pytest.raises(FileNotFoundError, match="no model file at /nonexistent/models.npz"):
        vec = gym.vector.AsyncVectorEnv([GOOD, BAD_MODELS], context="fork")
        vec.reset(seed=0)


@pytest.mark.parametrize(
    "make_vector",
    [
        lambda: WatchedAsyncVectorEnv([GOOD, GOOD], context="fork"),
        lambda: OverlappedVectorEnv([GOOD, GOOD, GOOD], context="fork"),
    ],
    ids=["watched", "overlapped"],
)
def test_a_killed_worker_is_named_in_one_line(make_vector):
    if "fork" not in multiprocessing.get_all_start_methods():
        pytest.skip("needs fork")
    vec = make_vector()
    vec.reset(seed=0)
    victim = vec.processes[-1]
    os.kill(victim.pid, signal.SIGKILL)
    victim.join(timeout=10)
    actions = np.zeros((vec.num_envs, 6), np.float32)
    for _ in range(2):  # the first call and every later one
        with pytest.raises(RuntimeError) as err:
            vec.step(actions)
        assert "\n" not in str(err.value)
        assert str(err.value).startswith(
            f"the vector-env worker of env {vec.num_envs - 1} (pid {victim.pid}) died, killed by "
            "SIGKILL; its env is gone: close this vector env and make a new one"
        )
    vec.close()
    assert not any(p.is_alive() for p in vec.processes)


def _damaged_policy(tmp_path, shipped: str, change) -> str:
    from scorbot_gym.policies.loading import SHIPPED

    folder = tmp_path / shipped
    shutil.copytree(SHIPPED[shipped], folder)
    meta = json.loads((folder / "policy.json").read_text())
    change(meta, folder)
    (folder / "policy.json").write_text(json.dumps(meta))
    return str(folder)


def _set(*keys_value):
    *keys, value = keys_value

    def change(meta, folder):
        for key in keys[:-1]:
            meta = meta[key]
        meta[keys[-1]] = value

    return change


def _norm_stat(key: str, value):
    def change(meta, folder):
        path = folder / "normalize.npz"
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
        arrays[key] = value(arrays[key])
        np.savez(path, **arrays)

    return change


@pytest.mark.parametrize(
    "shipped, change, message",
    [
        ("rl", _set("algo", ["sac"]), r"policy.json: algo must be a name \(sac, tqc, ppo, imit"),
        ("learned", _set("algo", {"x": 1}), r"policy.json: algo must be a name"),
        ("learned", _set("normalization", "mean", ["x"] * 3), r"normalization.mean must be a n"),
        ("learned", _set("normalization", "std", 1.0), r"normalization.std must be a non-empty"),
        ("learned", _set("normalization", "std", [[1.0]] * 3), r"normalization.std must be a n"),
        ("learned", _set("normalization", [1, 2]), r"normalization must be an object"),
        ("learned", _set("normalization", "mean", [0.0]), r"normalization.mean has 1 numbers a"),
        ("learned", _set("history", "x"), r"policy.json: history must be an object"),
        ("learned", _set("classes", "box"), r"policy.json: classes must be a list of object n"),
        ("learned", _set("action_type", "polar"), r"action_type must be 'joint' or 'cartesian'"),
        ("finetuned", _set("observation_shapes", {"a": "x"}), r"observation_shapes must be an"),
        (
            "rl",
            _norm_stat("mean/base_action", lambda a: np.zeros(7)),
            r"normalize.npz: mean/base_action must be numbers of shape \(6,\), got float64 \(7,\)",
        ),
        (
            "rl",
            _norm_stat("var/base_action", lambda a: -a),
            r"normalize.npz: var/base_action must be finite and >= 0 numbers",
        ),
    ],  # fmt: skip
)
def test_a_damaged_policy_names_the_file_and_field_in_one_line(tmp_path, shipped, change, message):
    from scorbot_gym.policies.loading import load_policy

    folder = _damaged_policy(tmp_path, shipped, change)
    with pytest.raises(ValueError, match=message) as err:
        load_policy(folder)
    assert "\n" not in str(err.value) and folder in str(err.value)


@pytest.fixture(scope="module")
def box_models_file(tmp_path_factory) -> str:
    from scorbot_gym.perception.training import train_models

    path = tmp_path_factory.mktemp("models") / "box.npz"
    train_models(["box"], n_views=72, progress=False)[0].save(path)
    return str(path)


M = "MODELS"  # stands for the module's model file in the cases below
CLUTTER = {"objects": ["box", "banana"], "distractors": 1}


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (
            {"pose": "manifold", "pose_kwargs": {"models": 7}},
            "models must be a PoseModelSet or the path of a model file .* got int 7",
        ),
        ({"pose": "manifold"}, "pose source 'manifold' was given the wrong arguments: .* 'models'"),
        (
            {"pose": "manifold", "pose_kwargs": {"models": M, "modle": 1}},
            "pose source 'manifold' was given the wrong arguments: .* keyword argument 'modle'",
        ),
        (
            {"pose": "noisy_oracle", "pose_kwargs": {"sigma": 1}},
            "pose source 'noisy_oracle' was given the wrong arguments: .* argument 'sigma'",
        ),
        (
            {"pose": "noisy_oracle", "pose_kwargs": {"pos_sigma_m": "x"}},
            "pos_sigma_m must be a finite number >= 0, got 'x'",
        ),
        (
            {"pose": "noisy_oracle", "pose_kwargs": {"dropout": True}},
            r"dropout must be a probability in \[0, 1\], got True",
        ),
        (
            {"pose": "manifold", "pose_kwargs": {"models": M, "recognizer": "nope"}},
            "unknown recognizer 'nope'; valid: flr, appearance, flr",
        ),
        (
            {"pose": "manifold", "pose_kwargs": {"models": M, "clear_min_area": "x"}},
            "clear_min_area must be a finite number >= 0, got 'x'",
        ),
        (
            {
                "pose": "manifold_clutter",
                "pose_kwargs": {"models": M, "track_gate_px": "x"},
                **CLUTTER,
            },
            "track_gate_px must be a finite number >= 0, got 'x'",
        ),
        (
            {"pose": "largest_blob", "pose_kwargs": {"models": M, "choice": "random"}, **CLUTTER},
            "the largest_blob source always takes the largest blob: drop choice=",
        ),
        ({"keep_images": "yes"}, "keep_images must be True or False, got 'yes'"),
        ({"include_class": 1}, "include_class must be True or False, got 1"),
    ],  # fmt: skip
)
def test_a_bad_pose_source_argument_is_a_one_line_error(kwargs, message, box_models_file):
    kwargs = dict(kwargs)
    pose_kwargs = {k: box_models_file if v == M else v
                   for k, v in kwargs.pop("pose_kwargs", {}).items()}  # fmt: skip
    kwargs.setdefault("objects", ["box"])
    with pytest.raises(ValueError, match=message) as err:
        make_env(pose_kwargs=pose_kwargs, **kwargs)
    assert "\n" not in str(err.value)


def test_a_spec_whose_model_file_is_gone_fails_in_the_worker_with_its_error(
    box_models_file, tmp_path
):
    if "fork" not in multiprocessing.get_all_start_methods():
        pytest.skip("needs fork")
    moved = tmp_path / "moved.npz"
    shutil.copy(box_models_file, moved)
    env = make_env(pose="manifold", pose_kwargs={"models": str(moved)}, objects=["box"])
    spec = env.spec
    env.close()
    moved.unlink()
    with pytest.raises(FileNotFoundError, match=f"no model file at {moved}"):
        vec = gym.vector.AsyncVectorEnv([GOOD, functools.partial(gym.make, spec)], context="fork")
        vec.reset(seed=0)
