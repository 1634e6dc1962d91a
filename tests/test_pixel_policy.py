"""The pixel policy (issue 36, item 2): imitation on the top camera image with no pose
estimate. A tiny real run (rendering, MuJoCo, torch) writes a loadable policy that acts inside
the action space; it never reads a pose entry; DAgger labels with the expert."""

from __future__ import annotations

import json
import shutil

import gymnasium as gym
import numpy as np
import pytest

from scorbot_gym import make_env
from scorbot_gym.policies.loading import load_policy, uses_scripted_controller
from scorbot_gym.policies.pixel import DEFAULT_RENDER_SIZE, POSE_KEYS, NetSpec, PixelPolicy
from scorbot_gym.rl.imitation import ExecutedActionExpert, collect_episodes
from scorbot_gym.rl.pixel import PixelImitationConfig, random_shift, train_pixel_imitation

pytestmark = pytest.mark.rl

TINY = PixelImitationConfig(
    demos=1, dagger_rounds=1, dagger_episodes=1, fit_steps=3, batch_size=8, device="cpu"
)
WIDTH, HEIGHT = DEFAULT_RENDER_SIZE


ENV_KWARGS = {
    "env_id": "ScorbotGraspCartesian-v0",
    "pose": "oracle",
    "include_class": True,
    "objects": ["box", "tennis_ball"],
    "cameras": ["top"],
    "image_width": WIDTH,
    "image_height": HEIGHT,
}


@pytest.fixture(scope="module")
def pixel_env():
    kw = dict(ENV_KWARGS)
    env = make_env(kw.pop("env_id"), **kw)
    yield env
    env.close()


@pytest.fixture(scope="module")
def trained(pixel_env, tmp_path_factory):
    policy, record = train_pixel_imitation(pixel_env, TINY)
    folder = policy.save(tmp_path_factory.mktemp("pixel") / "policy")
    return folder, record


@pytest.mark.slow
def test_tiny_run_writes_a_loadable_policy_that_acts_inside_the_action_space(pixel_env, trained):
    folder, record = trained
    assert record["demonstration_episodes"] == 1 and record["dagger_episodes"] == 1
    assert record["env_steps"] == sum(r["env_steps"] for r in record["rounds"]) > 0
    meta = json.loads((folder / "policy.json").read_text())
    assert meta["uses_scripted_controller"] is False
    assert meta["observation"] == "pixels"
    assert meta["training"]["config"]["fit_steps"] == TINY.fit_steps
    policy = load_policy(folder)
    assert isinstance(policy, PixelPolicy) and not uses_scripted_controller(policy)
    policy.bind(pixel_env)
    obs, _ = pixel_env.reset(seed=11)
    policy.reset(obs)
    for _ in range(5):
        action = policy.act(obs)
        assert pixel_env.action_space.contains(action)
        obs, *_ = pixel_env.step(action)


@pytest.mark.slow
def test_the_policy_never_reads_a_pose_entry(pixel_env, trained):
    """Same actions whether the pose entries are there, scrambled or gone; and it runs on the
    bare env, which has no pose wrapper at all."""
    policy = PixelPolicy.load(trained[0]).bind(pixel_env)
    obs, _ = pixel_env.reset(seed=12)
    assert set(POSE_KEYS) & set(obs)  # the wrapper's pose entries are really there
    scrambled = {k: (np.full_like(v, 7.0) if k in POSE_KEYS else v) for k, v in obs.items()}
    removed = {k: v for k, v in obs.items() if k not in POSE_KEYS}
    actions = []
    for view in (obs, scrambled, removed):
        policy.reset(view)
        actions.append(policy.act(view))
    np.testing.assert_array_equal(actions[0], actions[1])
    np.testing.assert_array_equal(actions[0], actions[2])

    bare = gym.make(
        "ScorbotGraspCartesian-v0",
        objects=["box", "tennis_ball"],
        cameras=["top"],
        image_width=WIDTH,
        image_height=HEIGHT,
    )
    try:
        assert not set(POSE_KEYS) & set(bare.observation_space.spaces)
        policy.bind(bare)
        obs, _ = bare.reset(seed=12)
        policy.reset(obs)
        for _ in range(3):
            action = policy.act(obs)
            assert bare.action_space.contains(action)
            obs, *_ = bare.step(action)
    finally:
        bare.close()


@pytest.mark.slow
def test_dagger_labels_with_the_oracle_expert_and_stores_small_frames(pixel_env, trained):
    policy = PixelPolicy.load(trained[0]).bind(pixel_env)
    told: list[tuple[np.ndarray, np.ndarray]] = []

    class Recording(ExecutedActionExpert):
        def act(self, obs):
            label = super().act(obs)
            told.append((np.asarray(obs["object_pos"]).copy(), np.asarray(label).copy()))
            return label

    (episode,) = collect_episodes(
        pixel_env,
        [21],
        learner=policy,
        beta=0.0,  # the learner acts at every step
        expert_factory=Recording.for_env,
        keep=policy.compact_observation,
    )
    labels = np.stack([label for _, label in told])
    np.testing.assert_array_equal(episode.labels, labels)  # every label is the expert's
    np.testing.assert_allclose(
        [pos for pos, _ in told], episode.infos["object_position"]
    )  # ... given the true pose from info, not the learner's view
    assert not np.allclose(episode.actions, episode.labels[:-1])  # the learner drove
    frames = episode.observations["top_rgb"]
    assert frames.dtype == np.uint8 and frames.shape[1:] == (84, 84, 3)
    assert not set(POSE_KEYS) & set(episode.observations)


@pytest.mark.slow
def test_collection_in_worker_processes_gives_the_same_episodes(pixel_env, trained):
    """Demonstrations and DAgger episodes (a trained learner acting half the time) from two
    spawned workers equal those collected here, frame for frame: every episode draws its
    noise from its own stream, so ``jobs`` changes the speed only."""
    from scorbot_gym.rl.pixel import collect_pixel_episodes

    learner = PixelPolicy.load(trained[0]).bind(pixel_env)
    for round_index, acting in [(0, None), (1, learner)]:
        runs = [
            collect_pixel_episodes(
                pixel_env,
                range(40, 43),
                learner,
                PixelImitationConfig(jobs=jobs, device="cpu"),
                round_index=round_index,
                learner=acting,
                beta=0.5,
                env_kwargs=ENV_KWARGS,
            )
            for jobs in (1, 2)
        ]
        assert [ep.seed for ep in runs[1]] == [40, 41, 42]
        for one, two in zip(*runs, strict=True):
            np.testing.assert_array_equal(one.actions, two.actions)
            np.testing.assert_array_equal(one.labels, two.labels)
            np.testing.assert_array_equal(one.observations["top_rgb"], two.observations["top_rgb"])
    with pytest.raises(ValueError, match="give env_kwargs"):
        train_pixel_imitation(pixel_env, PixelImitationConfig(jobs=2, device="cpu"))


def test_random_shift_moves_each_image_by_whole_pixels_within_the_pad():
    import torch as th

    th.manual_seed(0)
    img = th.rand(6, 1, 16, 16)
    out = random_shift(img, 2)
    padded = th.nn.functional.pad(img, (2, 2, 2, 2), mode="replicate")
    for i in range(len(img)):
        errs = [
            float((out[i] - padded[i, :, dy : dy + 16, dx : dx + 16]).abs().max())
            for dy in range(5)
            for dx in range(5)
        ]
        assert min(errs) < 1e-5
    assert th.equal(random_shift(img, 0), img)


def test_spatial_softmax_answers_where_the_bright_spot_is():
    """The keypoint encoder's code is a position: with the trunk set to pass the image through
    (one channel, identity-like filters), every keypoint lands on a lone bright pixel, wherever
    it is; so moving the object moves the code, which a flattened global code need not do."""
    import torch as th

    from scorbot_gym.policies.pixel import build_network

    net = build_network(NetSpec(channels=1, encoder="spatial_softmax", keypoints=2), 1)
    trunk, softmax = net.encoder[0], net.encoder[1]
    with th.no_grad():
        for conv in (m for m in trunk if isinstance(m, th.nn.Conv2d)):
            conv.weight.zero_()
            conv.bias.zero_()
            k = conv.kernel_size[0] // 2
            conv.weight[:, 0, k, k] = 1.0  # channel 0 in → every channel out, unshifted
        softmax.project.weight.fill_(1.0)
        softmax.project.bias.zero_()
        softmax.log_temperature.fill_(-3.0)  # a sharp softmax
    for row, col in [(20, 30), (60, 10), (42, 70)]:
        img = th.zeros(1, 1, 84, 84)
        img[0, 0, row - 1 : row + 2, col - 1 : col + 2] = 1.0
        xy = net.encoder(img).reshape(2, 2)
        # trunk: 5x5/2 then two 3x3 valid convolutions; map pixel (r, c) → ((r-2)/2-2, ...)
        h = w = 36
        expect = th.tensor([((col - 2) / 2 - 2) / (w - 1), ((row - 2) / 2 - 2) / (h - 1)])
        assert th.allclose(xy, (2 * expect - 1).expand(2, 2), atol=0.04), (row, col, xy)


@pytest.mark.slow
def test_a_spatial_softmax_policy_trains_saves_and_loads(pixel_env, tmp_path):
    config = PixelImitationConfig(
        demos=1,
        dagger_rounds=0,
        fit_steps=2,
        batch_size=8,
        device="cpu",
        net=NetSpec(encoder="spatial_softmax", keypoints=8),
    )
    saved = []
    policy, record = train_pixel_imitation(
        pixel_env, config, on_round=lambda pol, r: saved.append(pol.save(tmp_path / "kp"))
    )
    assert len(saved) == 1 and record["rounds_done"] == record["rounds_planned"] == 1
    folder = saved[0]  # the checkpoint of the last round is the policy
    meta = json.loads((folder / "policy.json").read_text())
    assert meta["network"]["encoder"] == "spatial_softmax" and meta["network"]["keypoints"] == 8
    loaded = PixelPolicy.load(folder).bind(pixel_env)
    obs, _ = pixel_env.reset(seed=5)
    loaded.reset(obs)
    policy.reset(obs)
    np.testing.assert_allclose(loaded.act(obs), policy.act(obs), atol=1e-6)
    assert pixel_env.action_space.contains(loaded.act(obs))


@pytest.mark.slow
def test_files_written_before_the_encoder_field_load_as_nature(trained, tmp_path):
    old = tmp_path / "old"
    shutil.copytree(trained[0], old)
    meta = json.loads((old / "policy.json").read_text())
    meta["network"].pop("keypoints")
    meta["network"]["encoder"] = "Nature-DQN conv 32x8x8/4, 64x4x4/2, 64x3x3/1, linear"
    (old / "policy.json").write_text(json.dumps(meta))
    assert PixelPolicy.load(old).net_spec.encoder == "nature"


@pytest.mark.slow
def test_damaged_or_incompatible_files_give_one_line_errors(trained, tmp_path):
    good = trained[0]

    def copy(name):
        folder = tmp_path / name
        shutil.copytree(good, folder)
        return folder

    bad_zip = copy("bad_zip")
    (bad_zip / "weights.npz").write_bytes(b"not a zip")
    bad_json = copy("bad_json")
    (bad_json / "policy.json").write_text("{")
    wrong_net = copy("wrong_net")
    meta = json.loads((wrong_net / "policy.json").read_text())
    meta["network"]["embedding"] = 17
    (wrong_net / "policy.json").write_text(json.dumps(meta))
    no_camera = copy("no_camera")
    meta = json.loads((no_camera / "policy.json").read_text())
    del meta["camera"], meta["cameras"]
    (no_camera / "policy.json").write_text(json.dumps(meta))
    two_cameras = copy("two_cameras")  # a second camera the network has no encoder for
    meta = json.loads((two_cameras / "policy.json").read_text())
    meta["cameras"] = ["top", "eye_in_hand"]
    (two_cameras / "policy.json").write_text(json.dumps(meta))
    pose_window = copy("pose_window")
    meta = json.loads((pose_window / "policy.json").read_text())
    meta["history"]["pose_window"] = 8
    (pose_window / "policy.json").write_text(json.dumps(meta))
    for folder, words in [
        (pose_window, "reads no pose estimate"),
        (bad_zip, "could not be read"),
        (bad_json, "not valid JSON"),
        (wrong_net, "do not fit the network"),
        (no_camera, "incomplete or malformed"),
        (two_cameras, "2 cameras"),
    ]:
        with pytest.raises(ValueError, match=words) as err:
            load_policy(folder)
        assert "\n" not in str(err.value)


def test_bad_settings_are_refused_in_one_line():
    for kwargs, words in [
        ({"shift": -1}, "shift must be >= 0"),
        ({"device": "tpu"}, "device must be"),
        ({"net": {"channels": 2}}, "channels must be 1"),
        ({"net": {"encoder": "resnet"}}, "encoder must be one of"),
        ({"net": {"encoder": "spatial_softmax", "keypoints": 0}}, "keypoints must be >= 1"),
        ({"net": NetSpec(frame_size=84), "fit_steps": 0}, "fit_steps must be >= 1"),
        ({"history": {"pose_window": 4}}, "reads no pose estimate"),
    ]:
        with pytest.raises(ValueError, match=words):
            PixelImitationConfig(**kwargs)


@pytest.mark.slow
def test_rollout_replays_a_pixel_policy_folder_with_the_camera_it_needs(trained):
    """``scorbot-gym rollout --policy DIR``: the env gets the policy's camera and image size
    (``env_requirements``) without the user naming them."""
    from scorbot_gym.evaluation.rollout import RolloutConfig, run_rollout

    config = RolloutConfig(
        policy=str(trained[0]),
        pose="oracle",
        action_type="cartesian",
        episodes=1,
        seed=3,
        objects=("box",),
    )
    summary, results = run_rollout(config)
    assert summary["episodes"] == 1 and len(results) == 1
