"""Env hardening: the observation contract under any legal action, argument checks, instability,
the shared renderer, pickling and Gymnasium's video recorder."""

import copy
import pickle

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.error import ResetNeeded
from gymnasium.wrappers import RecordVideo

from scorbot_gym import ScorbotGraspEnv
from scorbot_gym.sim.simulation import Simulation

SMALL = {"image_width": 64, "image_height": 48}


def _actions(rng: np.random.Generator):
    """Extreme sequences (every joint pushed to a stop, the hand folded onto the column, bang-
    bang switching), then uniform random actions."""
    for value in (-1.0, 1.0):
        yield from [np.full(6, value)] * 100
    yield from (rng.choice([-1.0, 1.0], 6) for _ in range(400))
    yield from (rng.uniform(-1.0, 1.0, 6) for _ in range(1500))


@pytest.mark.slow
@pytest.mark.parametrize("action_type", ["joint", "cartesian"])
def test_observations_stay_in_the_space_under_random_and_extreme_actions(action_type):
    env = ScorbotGraspEnv(objects=["box", "banana"], action_type=action_type)
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    for t, action in enumerate(_actions(rng)):
        obs, _, terminated, truncated, _ = env.step(action)
        bad = {k: v for k, v in obs.items() if not env.observation_space[k].contains(v)}
        assert not bad, f"step {t}: {bad}"
        if terminated or truncated or t % 150 == 149:
            obs, _ = env.reset()
    env.close()


def test_folding_the_hand_onto_the_column_is_a_collision():
    env = ScorbotGraspEnv(object_name="box")
    env.reset(seed=0)
    for _ in range(100):
        obs, _, _, _, info = env.step(-np.ones(6))
    assert info["failure_cause"] == "collision"
    # The fingers are pushed against their closed stop and the reading stays at it.
    assert obs["gripper_opening"][0] >= 0.0
    env.close()


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"max_joint_step": float("nan")}, "max_joint_step must be a finite number"),
        ({"max_cartesian_step": float("inf")}, "max_cartesian_step must be a finite number"),
        ({"max_angle_step": -0.1}, r"max_angle_step must be a finite number in \(0"),
        ({"max_joint_step": "0.1"}, "max_joint_step must be a finite number"),
        ({"render_width": 0}, r"render size width must be in \[1, 1280\]"),
        ({"render_width": -3}, r"render size width must be in \[1, 1280\]"),
        ({"render_width": 100000}, r"exceeds the framebuffer \(max 1280x960\)"),
        ({"image_height": 2000}, r"image size 640x2000 exceeds the framebuffer"),
        ({"image_width": 64.5}, "image size width must be an int"),
        ({"frame_skip": 2.5}, r"frame_skip must be an int in \[1, 500\]"),
        ({"frame_skip": 10**12}, r"frame_skip must be in \[1, 500\]"),
        ({"frame_skip": 0}, r"frame_skip must be in \[1, 500\]"),
        ({"objects": "banana"}, r"objects must be a list of names, e.g. objects=\['banana'\]"),
        ({"cameras": "top"}, r"cameras must be a list of names, e.g. cameras=\['top'\]"),
        ({"image_types": "rgb"}, "image_types must be a list of names"),
        ({"objects": []}, "objects must name at least one catalogue object"),
        ({"objects": ["box", "box"]}, "objects must not repeat a name"),
        ({"object_name": "box", "objects": ["box"]}, "give object_name or objects, not both"),
        ({"cameras": ["top", "top"]}, "cameras must not repeat a name"),
        ({"cameras": ["ceiling"]}, "unknown camera 'ceiling'; valid cameras: top"),
        ({"shadows": "yes"}, "shadows must be True or False"),
        ({"observe_object_pose": 1}, "observe_object_pose must be True or False"),
    ],
)
def test_bad_arguments_fail_at_make_with_one_line(kwargs, message):
    if "objects" not in kwargs:
        kwargs = {"object_name": "box", **kwargs}
    with pytest.raises(ValueError, match=message) as err:
        gym.make("ScorbotGrasp-v0", **kwargs)
    assert "\n" not in str(err.value)


def test_unknown_object_lists_the_catalogue():
    with pytest.raises(KeyError, match="unknown object 'bananas'; valid objects: banana"):
        ScorbotGraspEnv(objects=["bananas"])


def test_step_before_reset_is_reset_needed():
    env = ScorbotGraspEnv(object_name="box")
    with pytest.raises(ResetNeeded, match=r"before calling env.reset\(\)"):
        env.step(np.zeros(6))
    env.reset(seed=0)
    env.step(np.zeros(6))
    env.close()


def test_a_nan_control_is_caught_as_instability():
    env = ScorbotGraspEnv(object_name="box")
    env.reset(seed=0)
    robot = env.robot  # a servo command gone bad, as a NaN step size used to make it
    robot.set_gripper_target = lambda _: robot.sim.data.ctrl.__setitem__(
        robot.gripper_actuator, np.nan
    )
    obs, reward, terminated, truncated, info = env.step(np.zeros(6))
    assert truncated and not terminated and reward == 0.0
    assert info["failure_cause"] == "unstable"
    assert env.observation_space.contains(obs)  # a finite state is left behind
    env.close()


def test_scenes_share_one_renderer_and_match_mujoco_renderer():
    env = ScorbotGraspEnv(
        objects=["box", "banana"], cameras=["top"], image_types=("rgb", "depth"), **SMALL
    )
    first, _ = env.reset(seed=3, options={"object_name": "box"})
    other, _ = env.reset(seed=3, options={"object_name": "banana"})
    again, _ = env.reset(seed=3, options={"object_name": "box"})
    assert not np.array_equal(first["top_rgb"], other["top_rgb"])
    np.testing.assert_array_equal(first["top_rgb"], again["top_rgb"])
    sims = [sim for sim, _, _ in env._sims.values()]
    assert len(sims) == 2 and sims[0].renderer is sims[1].renderer is env._renderer
    # The same pixels as MuJoCo's own renderer (one GL context per model), shadows off.
    sim = env.sim
    with mujoco.Renderer(sim.model, 48, 64) as ref:
        ref.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        ref.update_scene(sim.data, camera=sim.camera_id("top"))
        np.testing.assert_array_equal(ref.render(), again["top_rgb"])
        ref.enable_depth_rendering()
        np.testing.assert_allclose(ref.render(), again["top_depth"][..., 0], rtol=1e-6)
        ref.enable_segmentation_rendering()
        seg = ref.render()
    mask = (seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM) & np.isin(seg[..., 0], sim.object_geoms)
    np.testing.assert_array_equal(mask, sim.render("top", "segmentation", 64, 48))
    env.close()


@pytest.mark.slow
def test_scene_switches_reuse_uploaded_assets(monkeypatch):
    """Each object's texture and mesh go up to GL once; switching back binds them again, with
    the same pixels as a freshly built context."""
    names = ["box", "banana", "foam_brick"]
    env = ScorbotGraspEnv(objects=names, cameras=["top"], **SMALL)
    first = {n: env.reset(seed=2, options={"object_name": n})[0]["top_rgb"] for n in names}
    assert env._renderer.cached_assets == {"textures": 2, "meshes": 3}  # + the context's own
    uploads = []
    for name in ("mjr_uploadTexture", "mjr_uploadMesh"):
        real = getattr(mujoco, name)
        monkeypatch.setattr(mujoco, name, lambda *a, _real=real: uploads.append(a) or _real(*a))
    for name in names[::-1] + names:
        obs, _ = env.reset(seed=2, options={"object_name": name})
        np.testing.assert_array_equal(obs["top_rgb"], first[name])
    assert uploads == []
    env.close()
    for name in names:  # a context that never saw another object
        alone = ScorbotGraspEnv(objects=[name], cameras=["top"], **SMALL)
        obs, _ = alone.reset(seed=2, options={"object_name": name})
        np.testing.assert_array_equal(obs["top_rgb"], first[name])
        alone.close()


def test_asset_cache_is_bounded():
    from scorbot_gym.sim.rendering import SceneRenderer

    with pytest.raises(ValueError, match="max_cached_assets must be >= 0"):
        SceneRenderer(max_cached_assets=-1)
    renderer = SceneRenderer(64, 48, max_cached_assets=1)
    sims = {n: Simulation(n, renderer=renderer) for n in ("box", "banana", "foam_brick")}
    images = {n: sim.render("top", width=64, height=48) for n, sim in sims.items()}
    for name in ("banana", "box", "foam_brick", "box"):
        np.testing.assert_array_equal(sims[name].render("top", width=64, height=48), images[name])
        assert max(renderer.cached_assets.values()) <= 1
    for sim in sims.values():
        sim.close()
    renderer.close()


def test_standalone_renderer_grows_for_a_larger_image():
    sim = Simulation("box", render_width=64, render_height=48)
    assert sim.render("top").shape == (48, 64, 3)
    assert sim.render("top", width=320, height=240).shape == (240, 320, 3)
    assert sim.render("top", "depth", 64, 48).shape == (48, 64)
    with pytest.raises(ValueError, match="exceeds the framebuffer"):
        sim.render("top", width=2000, height=10)
    sim.close()


@pytest.mark.parametrize("copier", [lambda e: pickle.loads(pickle.dumps(e)), copy.deepcopy])
def test_env_pickles_and_copies_after_rendering(copier):
    env = gym.make(
        "ScorbotGrasp-v0",
        objects=["box", "banana"],
        cameras=["top"],
        render_mode="rgb_array",
        render_width=64,
        render_height=48,
        **SMALL,
    )
    env.reset(seed=1)
    env.render()  # GL state exists now
    clone = copier(env)
    a, _ = env.reset(seed=5)
    b, _ = clone.reset(seed=5)
    action = np.full(6, 0.3, np.float32)
    for _ in range(3):
        a = env.step(action)[0]
        b = clone.step(action)[0]
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    np.testing.assert_array_equal(env.render(), clone.render())
    clone.close()
    env.close()


def test_record_video_writes_an_mp4(tmp_path):
    env = gym.make(
        "ScorbotGrasp-v0",
        object_name="box",
        render_mode="rgb_array",
        render_width=64,
        render_height=48,
        max_episode_steps=6,
    )
    env = RecordVideo(
        env, str(tmp_path / "videos"), episode_trigger=lambda episode: True, disable_logger=True
    )
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(env.action_space.sample())
        done = terminated or truncated
    env.close()
    videos = list((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1 and videos[0].stat().st_size > 0
