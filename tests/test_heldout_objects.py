"""The held-out objects: YCB meshes outside the catalogue, each a valid object the gripper can
take, installed by group (into this process's catalogue and the specs workers receive)."""

import pytest

from scorbot_gym.assets import heldout_objects
from scorbot_gym.objects import CATALOGUE, MAX_GRASP_WIDTH, user_objects


@pytest.fixture
def catalogue():
    """The catalogue as it was once the test ends: installed objects are not left behind for
    the tests that count the user objects."""
    before = dict(CATALOGUE)
    yield CATALOGUE
    CATALOGUE.clear()
    CATALOGUE.update(before)


def test_no_held_out_object_is_a_catalogue_object_or_in_two_groups():
    names = [s.name for specs in heldout_objects.GROUPS.values() for s in specs]
    sources = [s.source for specs in heldout_objects.GROUPS.values() for s in specs]
    builtin = {s.source for s in CATALOGUE.values()}
    assert len(set(names)) == len(names) and not set(sources) & builtin


@pytest.mark.parametrize("group", list(heldout_objects.GROUPS))
def test_a_group_installs_objects_the_gripper_can_take(group, catalogue):
    names = heldout_objects.install(group)
    assert names and heldout_objects.install(group) == names  # installing again is harmless
    for name in names:
        model = CATALOGUE[name].model  # the mesh loads
        assert 0.0 < model.grasp_width <= MAX_GRASP_WIDTH, name
    assert set(names) <= {s.name for s in user_objects()}  # so workers receive them


def test_an_unknown_group_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown held-out group 'round'; valid: heading"):
        heldout_objects.install("round")


def test_training_objects_are_checked_before_any_episode_and_drawn_from(catalogue):
    from scorbot_gym.rl.imitation import ImitationConfig, make_learner_envs

    with pytest.raises(ValueError, match=r"unknown objects \['train_bar'\]"):
        ImitationConfig(objects=("banana", "train_bar"))  # not installed yet
    with pytest.raises(ValueError, match="non-empty list of names"):
        ImitationConfig(objects=())
    names = heldout_objects.install("training")
    config = ImitationConfig(objects=("banana", *names))
    (env,) = make_learner_envs(config)
    try:
        drawn = {env.reset(seed=s)[1]["object_name"] for s in range(12)}
    finally:
        env.close()
    assert drawn <= {"banana", *names} and len(drawn) > 2


@pytest.mark.parametrize("name", ["learned_grasp_frame", "finetuned_grasp_frame", "rl_grasp_frame"])
def test_the_shipped_grasp_frame_arms_grasp_a_new_object_whose_heading_matters(name, catalogue):
    """Each shipped arm that reads the grasp frame (no class) takes a screwdriver it never
    trained on, from its own ``env_kwargs`` (the env's classes, so the object has a frame)."""
    from scorbot_gym import make_env
    from scorbot_gym.evaluation import run_episodes
    from scorbot_gym.policies.loading import load_policy

    assert "phillips_screwdriver" in heldout_objects.install("heading")
    policy = load_policy(name)
    assert policy.object_features == "grasp_frame"
    kwargs = dict(policy.env_kwargs())
    env = make_env(kwargs.pop("env_id"), pose="oracle", objects=["phillips_screwdriver"], **kwargs)
    try:
        policy.bind(env)
        results = run_episodes(env, policy, 2, 50000, progress=False)
    finally:
        env.close()
    assert [r.success for r in results] == [True, True]
