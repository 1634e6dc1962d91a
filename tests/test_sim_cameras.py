"""Cameras: intrinsics and extrinsics match what MuJoCo renders; headless GL selection."""

import os
import subprocess
import sys
import tempfile

import numpy as np
import pytest

from scorbot_gym import _gl
from scorbot_gym.sim import Simulation


@pytest.fixture(scope="module")
def ball_sim():
    sim = Simulation("golf_ball", render_width=320, render_height=240)
    yield sim
    sim.close()


@pytest.mark.parametrize("camera", ["top", "side", "overview"])
@pytest.mark.parametrize("size", [(320, 240), (160, 160)])
def test_projected_point_is_found_in_image(ball_sim, camera, size):
    """The ball's centre, projected with K and the extrinsics, lands on its silhouette centre,
    and the rendered depth there is the camera distance to the ball's near surface."""
    sim = ball_sim
    w, h = size
    for xy in ((0.24, -0.08), (0.32, 0.09)):
        pos, quat = sim.resting_pose(xy, 0.4)
        sim.set_object_pose(pos, quat)
        sim.forward()
        cam = sim.camera_model(camera, w, h)
        uv = cam.project(pos)[0]
        mask = sim.render(camera, "segmentation", w, h)
        ys, xs = np.nonzero(mask)
        assert len(xs) > 20
        np.testing.assert_allclose(uv, [xs.mean(), ys.mean()], atol=0.75)
        depth = sim.render(camera, "depth", w, h)
        z_centre = (cam.camera_from_world @ np.r_[pos, 1.0])[2]
        radius = sim.object_spec.model.half_extents.max()
        d = depth[int(round(uv[1])), int(round(uv[0]))]
        assert z_centre - radius - 0.004 < d < z_centre - radius * 0.8


def test_backprojection_to_table_plane_recovers_position(ball_sim):
    sim = ball_sim
    pos, quat = sim.resting_pose((0.3, 0.05), 0.0)
    sim.set_object_pose(pos, quat)
    sim.forward()
    cam = sim.camera_model("top")
    uv = cam.project(pos)
    np.testing.assert_allclose(cam.backproject_to_plane(uv, pos[2])[0], pos, atol=1e-9)


def test_extrinsics_are_rigid_and_look_at_the_workspace(ball_sim):
    cam = ball_sim.camera_model("top")
    R = cam.world_from_camera[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    assert np.isclose(np.linalg.det(R), 1.0)
    np.testing.assert_allclose(R[:, 2], [0, 0, -1], atol=1e-9)  # optical axis straight down


def test_unknown_camera_and_bad_kind(ball_sim):
    with pytest.raises(ValueError, match="valid cameras"):
        ball_sim.render("ceiling")
    with pytest.raises(ValueError, match="render kind"):
        ball_sim.render("top", "normals")


def test_eye_in_hand_camera_renders(ball_sim):
    img = ball_sim.render("eye_in_hand", width=64, height=48)
    assert img.shape == (48, 64, 3) and img.std() > 1


def test_gl_backend_defaults_to_egl_without_display(monkeypatch):
    monkeypatch.delenv("MUJOCO_GL", raising=False)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(_gl.sys, "platform", "linux")
    assert _gl.choose_backend() == "egl"
    import os

    assert os.environ["MUJOCO_GL"] == "egl"


def test_gl_backend_respects_user_choice_and_rejects_nonsense(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "osmesa")
    assert _gl.choose_backend() == "osmesa"
    monkeypatch.setenv("MUJOCO_GL", "vulkan9")
    with pytest.raises(_gl.RenderingUnavailableError, match="valid"):
        _gl.choose_backend()


def test_no_working_backend_gives_one_error_saying_what_to_install():
    """GLFW cannot open a context without a display: the error names the fix."""
    import os
    import subprocess
    import sys

    code = (
        "from scorbot_gym.sim import Simulation\n"
        "from scorbot_gym._gl import RenderingUnavailableError\n"
        "try:\n"
        "    Simulation('box').render('top')\n"
        "except RenderingUnavailableError as e:\n"
        "    print('ERROR:', e)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["MUJOCO_GL"] = "glfw"
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )
    assert "ERROR:" in out.stdout, out.stderr[-2000:]
    assert "apt-get install libegl1" in out.stdout and "MUJOCO_GL=egl" in out.stdout


@pytest.mark.slow
def test_import_opens_no_display_and_a_worker_renders_in_its_own_thread():
    """Importing opens no EGL display (a fork after import inherits no rasterizer); a child
    process's first frame makes llvmpipe rasterize in the calling thread unless the user chose;
    the parent keeps Mesa's default. (A fork *after* rendering is still unsafe with software GL:
    use spawn.)"""
    code = (
        "import multiprocessing as mp, os, sys\n"
        "import scorbot_gym\n"
        "from scorbot_gym.sim import Simulation\n"
        "def child(q):\n"
        "    Simulation('box', render_width=64, render_height=48).render('top')\n"
        "    q.put(os.environ.get('LP_NUM_THREADS'))\n"
        "if __name__ == '__main__':\n"
        "    assert 'dm_control._render.pyopengl.egl_renderer' not in sys.modules\n"
        "    ctx = mp.get_context('fork'); q = ctx.Queue()\n"
        "    p = ctx.Process(target=child, args=(q,))\n"
        "    p.start()\n"
        "    child_threads = q.get()\n"
        "    p.join()\n"
        "    Simulation('box', render_width=64, render_height=48).render('top')\n"
        "    print(os.environ.get('LP_NUM_THREADS'), child_threads)\n"
    )
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "probe.py")
        with open(path, "w") as f:
            f.write(code)
        env = {k: v for k, v in os.environ.items() if k != "LP_NUM_THREADS"}
        out = subprocess.run(
            [sys.executable, path],
            env={**env, "MUJOCO_GL": "egl"},
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert out.returncode == 0, out.stderr
        assert out.stdout.split() == ["None", "0"]
        out = subprocess.run(
            [sys.executable, path],
            env={**env, "MUJOCO_GL": "egl", "LP_NUM_THREADS": "2"},
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert out.stdout.split() == ["2", "2"], out.stderr
