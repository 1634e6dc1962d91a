import os

os.environ.setdefault("MUJOCO_GL", "egl")

import cv2  # noqa: E402
import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import trimesh  # noqa: E402

import scorbot_gym  # noqa: E402, F401  (registers the envs)
from scorbot_gym.objects import CATALOGUE, register_object  # noqa: E402


@pytest.fixture(scope="session")
def joint_env():
    env = gym.make("ScorbotGrasp-v0")
    yield env
    env.close()


@pytest.fixture()
def user_object(tmp_path):
    mesh = trimesh.creation.box(extents=[0.05, 0.035, 0.06])
    mesh.apply_translation([0, 0, 0.03])
    mesh_path = tmp_path / "block.stl"
    mesh.export(mesh_path)
    tex = np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    tex_path = tmp_path / "block.png"
    cv2.imwrite(str(tex_path), cv2.resize(tex, (256, 256), interpolation=cv2.INTER_NEAREST))
    spec = register_object("user_block", mesh_path, tex_path, mass=0.08, overwrite=True)
    yield spec
    CATALOGUE.pop("user_block", None)


@pytest.fixture(scope="session")
def can_views(tmp_path_factory):
    """The potted-meat can at 320 x 240 from the top camera: training views every 30 degrees
    with depth, 4 random test views; ``(train views, train poses, test LabeledViews)``. Shared
    by the composition tests (fallback, selection)."""
    from scorbot_gym.data.views import grid_poses, random_poses, render_views, workspace_bounds
    from scorbot_gym.objects import get_object

    obj, cache = "potted_meat_can", tmp_path_factory.mktemp("can-views")
    n_rest = len(get_object(obj).resting_quats)
    train = render_views(obj, grid_poses(n_rest, 30.0, n_positions=1, seed=0), width=320,
                         height=240, cache_dir=cache, progress=False, depth=True)  # fmt: skip
    test = render_views(obj, random_poses(4, n_rest, workspace_bounds(), seed=5), width=320,
                        height=240, seed=2, cache_dir=cache, progress=False)  # fmt: skip
    return [lv.view for lv in train], np.array([lv.camera_from_object for lv in train]), test
