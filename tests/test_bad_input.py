"""Bad input at reset, at registration, to the pose wrapper and in a vector-env worker: one line
naming the bad value and what is valid (issue 35, item 15)."""

from __future__ import annotations

import functools
import multiprocessing

import gymnasium as gym
import numpy as np
import pytest

from scorbot_gym import OverlappedVectorEnv, make_env, pin_env_fns
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
