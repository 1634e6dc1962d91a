"""The pixel arm built as the anchors build theirs (issue 49, item 4): a frame stack (memory),
the wrist camera beside the top one, each camera's own encoder and random shift, the stall
input, and a validation split whose rollouts choose the checkpoint. The stacks fitting gathers
from stored steps must be the stacks the policy sees when it acts, step for step."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from scorbot_gym import make_env
from scorbot_gym.policies.imitation import HistorySpec
from scorbot_gym.policies.pixel import DEFAULT_RENDER_SIZE, NetSpec, PixelPolicy, stack_frames
from scorbot_gym.rl.pixel import (
    PixelImitationConfig,
    Validation,
    collect_pixel_episodes,
    episode_arrays,
    gather_frames,
    random_shift,
    skeleton,
    stack_index,
    train_pixel_imitation,
)

pytestmark = pytest.mark.rl

WIDTH, HEIGHT = DEFAULT_RENDER_SIZE
CAMERAS = ("top", "eye_in_hand")
TWO_CAMERAS = PixelImitationConfig(
    demos=1,
    dagger_rounds=1,
    dagger_episodes=1,
    fit_steps=4,
    batch_size=8,
    device="cpu",
    cameras=CAMERAS,
    net=NetSpec(frame_stack=3, encoder="spatial_softmax", keypoints=4, embedding=16, hidden=16),
    history=HistorySpec(stall_steps=50),
    shift=4,
    val_demos=1,
    val_episodes=1,
    val_every=2,
)


@pytest.fixture(scope="module")
def wrist_env():
    env = make_env(
        "ScorbotGraspCartesian-v0",
        pose="oracle",
        include_class=True,
        objects=["box", "tennis_ball"],
        cameras=list(CAMERAS),
        image_width=WIDTH,
        image_height=HEIGHT,
        max_episode_steps=30,
    )
    yield env
    env.close()


def test_stack_index_repeats_each_episode_first_step_until_it_has_enough():
    index = stack_index([2, 4], 3)
    expected = [[0, 0, 0], [0, 0, 1], [2, 2, 2], [2, 2, 3], [2, 3, 4], [3, 4, 5]]
    np.testing.assert_array_equal(index, expected)
    np.testing.assert_array_equal(stack_index([3], 1), [[0], [1], [2]])


def test_stack_frames_gives_each_camera_its_own_group_of_channels():
    """(K frames, cameras x C) → (cameras x K x C): camera-major, oldest frame first, in numpy
    and torch alike; the network splits the channels into one group per camera."""
    import torch as th

    k, cameras, c = 3, 2, 3
    frames = np.zeros((k, cameras * c, 2, 2), np.uint8)
    for t in range(k):
        for cam in range(cameras):
            frames[t, cam * c : (cam + 1) * c] = 10 * cam + t  # value says camera and time
    out = stack_frames(frames, cameras)
    assert out.shape == (cameras * k * c, 2, 2)
    expect = [10 * cam + t for cam in range(cameras) for t in range(k) for _ in range(c)]
    np.testing.assert_array_equal(out[:, 0, 0], expect)
    batch = th.as_tensor(np.stack([frames, frames]))
    assert th.equal(stack_frames(batch, cameras)[1], th.as_tensor(out))


def test_random_shift_moves_each_camera_on_its_own():
    import torch as th

    th.manual_seed(3)
    img = th.rand(64, 2, 16, 16)
    out = random_shift(img, 3, groups=2)
    padded = th.nn.functional.pad(img, (3, 3, 3, 3), mode="replicate")

    def offset(i, ch):
        errs = {
            (dy, dx): float((out[i, ch] - padded[i, ch, dy : dy + 16, dx : dx + 16]).abs().max())
            for dy in range(7)
            for dx in range(7)
        }
        return min(errs, key=errs.get)

    differ = sum(offset(i, 0) != offset(i, 1) for i in range(8))
    assert differ >= 5  # 1 in 49 would agree by chance


@pytest.mark.slow
def test_the_stacks_fitting_gathers_are_the_stacks_the_acting_policy_sees(wrist_env):
    """An untrained two-camera, three-frame policy drives an episode (its frames stored as
    the trainer stores them); replaying the executed actions through the policy's own
    history gives, at every step, the stack that ``stack_index`` gathers from the stored
    steps, and the same vector."""
    policy = skeleton(wrist_env, TWO_CAMERAS)
    (episode,) = collect_pixel_episodes(
        wrist_env, range(7, 8), policy, TWO_CAMERAS, round_index=1, learner=policy, beta=0.0
    )
    assert episode.observations["eye_in_hand_rgb"].shape[1:] == (84, 84, 3)
    frames, vectors, labels = episode_arrays(episode, policy)
    index = stack_index([len(labels)], 3)
    history = policy.new_history()
    keys = list(episode.observations)
    calls = []
    real_frames = policy.current_frames
    policy.current_frames = lambda o: calls.append(1) or real_frames(o)
    for t in range(len(episode)):
        obs = {k: episode.observations[k][t] for k in keys}
        live, vector = policy.features(obs, history)
        np.testing.assert_array_equal(live, gather_frames(frames, index, np.array([t]), 2)[0])
        np.testing.assert_array_equal(vector, vectors[t])
        # a copy of the observation is not taken for the one the frames came from
        policy.remember(history, episode.actions[t], obs if t % 2 else dict(obs))
    # each step's frames are made once, and again only where push got another dict
    assert len(calls) == len(episode) + (len(episode) + 1) // 2
    del policy.current_frames
    assert live.shape == (2 * 3 * 3, 84, 84)
    # the newest frame of each camera is the step's own; the top camera is not the wrist one
    assert not np.array_equal(live[6:9], live[15:18])
    assert np.array_equal(live[6:9], frames[-1][:3]) and np.array_equal(live[15:18], frames[-1][3:])


@pytest.mark.slow
def test_a_two_camera_stacked_policy_trains_validates_saves_and_acts(wrist_env, tmp_path):
    policy, record = train_pixel_imitation(wrist_env, TWO_CAMERAS)
    validation = record["validation"]
    # two checkpoints per fit (step 2 and the fit's end), BC and one DAgger round
    assert [(c["round"], c["fit_step"]) for c in validation["checkpoints"]] == [
        (0, 2),
        (0, 4),
        (1, 2),
        (1, 4),
    ]
    for c in validation["checkpoints"]:
        assert c["rollout_episodes"] == 1 and 0 <= c["held_out_arm_rmse"]
    assert validation["held_out_seeds"]["first"] > record["rounds"][0]["episodes"]
    assert record["cameras"] == list(CAMERAS) and record["frame_stack"] == 3
    folder = policy.save(tmp_path / "wrist")
    meta = json.loads((folder / "policy.json").read_text())
    assert meta["cameras"] == list(CAMERAS) and meta["network"]["frame_stack"] == 3
    assert meta["history"]["stall_steps"] == 50
    loaded = PixelPolicy.load(folder)
    assert loaded.env_requirements["cameras"] == list(CAMERAS)
    loaded.bind(wrist_env)
    obs, _ = wrist_env.reset(seed=5)
    loaded.reset(obs)
    policy.reset(obs)
    for _ in range(4):  # the stacks fill: both policies keep the same memory
        a = loaded.act(obs)
        np.testing.assert_allclose(a, policy.act(obs), atol=1e-6)
        assert wrist_env.action_space.contains(a)
        obs, *_ = wrist_env.step(a)
    top_only = make_env(
        "ScorbotGraspCartesian-v0", cameras=["top"], image_width=WIDTH, image_height=HEIGHT
    )
    try:
        with pytest.raises(ValueError, match="eye_in_hand_rgb") as err:
            loaded.bind(top_only)
        assert "\n" not in str(err.value)
    finally:
        top_only.close()


@pytest.mark.slow
def test_validation_returns_the_checkpoint_its_rollouts_chose(wrist_env):
    """Scores 0, 1, 0 at three checkpoints, the weights changed between them: the policy ends
    with the second checkpoint's weights and normalisation."""
    policy = skeleton(wrist_env, TWO_CAMERAS)
    scores = iter([0.0, 1.0, 0.0])

    def collect(_round, seeds, _learner, _beta):
        score = next(scores)
        return [SimpleNamespace(success=bool(score)) for _ in seeds]

    config = PixelImitationConfig(**{**TWO_CAMERAS.__dict__, "val_demos": 0})
    validation = Validation(policy, config, collect)
    kept = None
    for i in range(3):
        policy.load_state({k: v + i for k, v in policy.state_arrays().items()})
        policy.mean = np.full_like(policy.mean, float(i))
        if i == 1:
            kept = policy.state_arrays()
        validation.checkpoint(0, i)
    validation.restore_best()
    for k, v in policy.state_arrays().items():
        np.testing.assert_array_equal(v, kept[k])
    assert np.all(policy.mean == 1.0)
    assert validation.summary()["chosen"]["fit_step"] == 1


def test_bad_memory_camera_and_validation_settings_are_refused_in_one_line():
    for kwargs, words in [
        ({"cameras": ("top", "top")}, "cameras must not repeat"),
        ({"cameras": ()}, "cameras must be a non-empty list"),
        ({"cameras": "top"}, "cameras must be a non-empty list"),
        ({"net": {"frame_stack": 0}}, "frame_stack must be >= 1"),
        ({"val_every": 100}, "needs val_episodes > 0"),
        ({"val_demos": -1}, "val_demos must be >= 0"),
        ({"val_demos": 5, "demos": 60_000}, "demos must be <= 50000"),
    ]:
        with pytest.raises(ValueError, match=words) as err:
            PixelImitationConfig(**kwargs)
        assert "\n" not in str(err.value)
    config = PixelImitationConfig(cameras=CAMERAS, net=NetSpec(cameras=1))
    assert config.net.cameras == 2  # the network follows the cameras named


def test_the_recipe_comparison_names_every_confound_that_remains():
    """Against the shipped state policy: a pixel recipe that matches it shares memory, the
    wrist camera, both fixes and the episodes; the first pixel arm's recipe differs in each."""
    from scorbot_gym.policies.loading import SHIPPED
    from scorbot_gym.policies.sb3 import read_policy_json
    from scorbot_gym.rl.pixel import recipe_differences

    state = read_policy_json(SHIPPED["learned"] / "policy.json")
    s = state["training"]["config"]
    matched = PixelImitationConfig(
        demos=s["demos"],
        dagger_rounds=s["dagger_rounds"],
        dagger_episodes=s["dagger_episodes"],
        dart_sigma=s["dart_sigma"],
        cameras=CAMERAS,
        net=NetSpec(frame_stack=3),
        history=HistorySpec(stall_steps=s["history"]["stall_steps"]),
        expert_keeps_close=s["expert_keeps_close"],
    )
    first = PixelImitationConfig(demos=200, dagger_rounds=3, dagger_episodes=60)

    def record(config, val=None):
        return {"training": {"config": json.loads(json.dumps(config.__dict__, default=vars)),
                             "validation": val}}  # fmt: skip

    same = recipe_differences(record(matched), state)
    assert not [d for d in same["differs"] if not d.startswith("state learner")]
    assert len(same["same"]) == 6
    apart = recipe_differences(record(first, {"rollout_episodes": 50}), state)["differs"]
    for words in ("memory", "no wrist camera", "stall input", "keep-closing", "demonstrations",
                  "checkpoint"):  # fmt: skip
        assert any(words in d for d in apart), words
