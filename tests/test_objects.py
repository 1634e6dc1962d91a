"""The catalogue: real meshes, textures rich enough for SIFT, annotations; user objects."""

import os

import cv2
import numpy as np
import pytest
import trimesh

from pose.symmetry import Symmetry
from scorbot_gym.objects import CATALOGUE, MAX_GRASP_WIDTH, get_object, register_object
from scorbot_gym.sim import Simulation

YCB = [n for n, s in CATALOGUE.items() if s.source.startswith("ycb:")]


def test_catalogue_has_eight_real_objects_and_primitives():
    assert len(YCB) >= 8
    assert {"box", "cylinder"} <= set(CATALOGUE)


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_object_fits_gripper_and_is_annotated(name):
    spec = get_object(name)
    model = spec.model
    assert 0 < model.grasp_width <= MAX_GRASP_WIDTH
    assert 0 < spec.mass <= 1.0 and spec.friction > 0
    assert spec.symmetry.kind in ("none", "axial", "discrete")
    assert model.vertices.shape[1] == 3 and len(model.faces) > 0
    # canonical frame: bounding box centred at the origin
    np.testing.assert_allclose(model.vertices.min(0) + model.vertices.max(0), 0, atol=1e-6)


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_top_camera_sees_at_least_50_sift_keypoints(name):
    sim = Simulation(name)  # default resolution: 640x480
    sift = cv2.SIFT_create()
    counts = []
    for xy, yaw in (((0.25, -0.08), 0.3), ((0.32, 0.07), 2.2)):
        sim.set_object_pose(*sim.resting_pose(xy, yaw))
        sim.forward()
        gray = cv2.cvtColor(sim.render("top"), cv2.COLOR_RGB2GRAY)
        mask = sim.render("top", "segmentation").astype(np.uint8) * 255
        counts.append(len(sift.detect(gray, mask)))
    sim.close()
    assert min(counts) >= 50, counts


def test_symmetry_rotations():
    assert len(Symmetry().rotations()) == 1
    assert len(Symmetry("axial").rotations(step_deg=10)) == 36
    rots = Symmetry("discrete", order=4, flips=((1.0, 0.0, 0.0),)).rotations()
    assert len(rots) == 8
    for R in rots:
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    with pytest.raises(ValueError, match="kind"):
        Symmetry("spherical")


def test_unknown_object_error_lists_names():
    with pytest.raises(KeyError, match="valid objects: banana"):
        get_object("teapot")


def test_grasp_closes_over_the_centre_of_mass():
    """A tall block beside a low slab: the footprint's middle is on the slab, the mass is in the
    block. The fingers close over the block, where lifting leaves the least torque."""
    from scorbot_gym.objects import _canonicalize, _grasp

    block = trimesh.creation.box(extents=[0.03, 0.03, 0.06])
    block.apply_translation([-0.015, 0.0, 0.03])
    slab = trimesh.creation.box(extents=[0.06, 0.03, 0.005])
    slab.apply_translation([0.03, 0.0, 0.0025])
    vertices, faces = _canonicalize(trimesh.util.concatenate([block, slab]))
    com = trimesh.Trimesh(vertices, faces).center_mass[:2]
    point, _, width = _grasp(vertices, faces)
    footprint_middle = np.zeros(2)  # the bounding box is centred by _canonicalize
    assert np.linalg.norm(com - footprint_middle) > 0.02  # the two candidates differ
    assert np.linalg.norm(point - com) < 0.002
    assert abs(width - 0.03) < 0.002


def test_banana_grasp_is_near_its_centre_of_mass():
    model = get_object("banana").model
    com = trimesh.Trimesh(model.vertices, model.faces).center_mass
    assert np.linalg.norm(model.grasp_point - com[:2]) < 0.003  # the most interior point: 6 mm


def test_register_object_from_mesh_and_texture(user_object):
    assert get_object("user_block") is user_object
    np.testing.assert_allclose(user_object.model.half_extents * 2, [0.05, 0.035, 0.06], atol=1e-6)
    assert abs(user_object.model.grasp_width - 0.035) < 0.002


def test_register_object_bad_input(tmp_path, user_object):
    with pytest.raises(FileNotFoundError, match="mesh file not found"):
        register_object("ghost", tmp_path / "missing.stl", mass=0.1)
    with pytest.raises(ValueError, match="already registered"):
        register_object("user_block", tmp_path / "block.stl", mass=0.1)
    bad_tex = tmp_path / "not_an_image.png"
    bad_tex.write_bytes(b"definitely not a png")
    with pytest.raises(ValueError, match="cannot read texture image"):
        register_object("other", tmp_path / "block.stl", bad_tex, mass=0.1)
    big = tmp_path / "big.stl"
    trimesh.creation.box(extents=[0.2, 0.2, 0.05]).export(big)
    with pytest.raises(ValueError, match="gripper takes at most"):
        register_object("slab", big, mass=0.1)
    with pytest.raises(ValueError, match="mass"):
        register_object("heavy", tmp_path / "block.stl", mass=-1.0)


@pytest.mark.parametrize("name", ["banana", "cylinder"])
def test_cached_geometry_is_the_derived_geometry(name, tmp_path, monkeypatch):
    """The on-disk object cache returns exactly what deriving the model gives, and the STL the
    scene embeds is trimesh's export (so images and physics are unchanged)."""
    from scorbot_gym import objects

    monkeypatch.setenv("SCORBOT_GYM_CACHE", str(tmp_path))
    spec = get_object(name)
    derived = objects._derive_model(spec)
    objects.load_object_model.cache_clear()
    try:
        first = objects.load_object_model(spec)  # derives and writes the entry
        assert objects._model_cache_path(spec).is_file()
        objects.load_object_model.cache_clear()
        cached = objects.load_object_model(spec)  # reads it
    finally:
        objects.load_object_model.cache_clear()
    for model in (first, cached):
        for field in ("vertices", "faces", "half_extents", "grasp_point"):
            np.testing.assert_array_equal(getattr(model, field), getattr(derived, field))
        assert (model.grasp_yaw, model.grasp_width) == (derived.grasp_yaw, derived.grasp_width)
    mesh = trimesh.Trimesh(derived.vertices, derived.faces, process=False)
    ours, theirs = cached.stl_bytes(), mesh.export(file_type="stl")
    assert len(ours) == len(theirs) and ours[80:84] == theirs[80:84]  # triangle count
    record = np.dtype([("normal", "<f4", 3), ("vertices", "<f4", (3, 3)), ("attr", "<u2")])
    ours, theirs = np.frombuffer(ours[84:], record), np.frombuffer(theirs[84:], record)
    assert ours["vertices"].tobytes() == theirs["vertices"].tobytes()
    np.testing.assert_array_equal(ours["normal"], theirs["normal"])  # up to the sign of zero


def test_unreadable_object_cache_entry_is_rebuilt_and_orphans_removed(tmp_path, monkeypatch):
    from scorbot_gym import objects

    monkeypatch.setenv("SCORBOT_GYM_CACHE", str(tmp_path))
    spec = get_object("box")
    path = objects._model_cache_path(spec)
    path.parent.mkdir(parents=True)
    path.write_bytes(b"PK\x03\x04 truncated")
    orphan = path.parent / ".box-killed.npz.tmp"  # what a write killed mid-way leaves
    orphan.write_bytes(b"partial")
    os.utime(orphan, (0, 0))
    objects.load_object_model.cache_clear()
    try:
        with pytest.warns(RuntimeWarning, match="unreadable"):
            model = objects.load_object_model(spec)
    finally:
        objects.load_object_model.cache_clear()
    np.testing.assert_allclose(model.half_extents * 2, [0.06, 0.045, 0.07], atol=1e-9)
    with np.load(path) as z:  # rewritten, readable
        np.testing.assert_array_equal(z["vertices"], model.vertices)
    assert not orphan.exists()


@pytest.mark.slow
def test_env_runs_without_the_vision_and_mesh_stacks(tmp_path):
    """An env on the oracle, with a camera, imports neither scikit-learn nor trimesh/scipy, even
    with an empty object cache (the geometry is then derived in a child process): they would
    cost every process (vector-env workers too) ~110 MB."""
    import subprocess
    import sys

    code = (
        "import sys, gymnasium as gym, scorbot_gym\n"
        "env = gym.make('ScorbotGrasp-v0', cameras=['top'], image_width=64, image_height=48)\n"
        "env.reset(seed=0, options={'object_name': 'banana'})\n"
        "env.step(env.action_space.sample())\n"
        "print(sorted(m for m in ('sklearn', 'trimesh', 'scipy', 'pose.manifold')"
        " if m in sys.modules))\n"
    )
    env = {**os.environ, "SCORBOT_GYM_CACHE": str(tmp_path)}
    for run in ("cold", "warm"):
        out = subprocess.run(
            [sys.executable, "-c", code], check=True, capture_output=True, text=True, env=env
        )
        assert out.stdout.strip().splitlines()[-1] == "[]", run
    assert len(list((tmp_path / "objects").glob("banana-*.npz"))) == 1


def test_geometry_derived_in_a_child_is_the_derived_geometry(tmp_path, monkeypatch):
    """One child process derives every missing entry, bit-identical to deriving here; a spec it
    cannot derive is skipped (the caller then derives it here and raises the real error)."""
    import sys

    from scorbot_gym import objects

    monkeypatch.setenv("SCORBOT_GYM_CACHE", str(tmp_path))
    monkeypatch.delitem(sys.modules, "trimesh")  # as in an env's process
    specs = [get_object("banana"), get_object("cylinder")]
    missing = objects.ObjectSpec("ghost", str(tmp_path / "ghost.stl"), mass=0.1)
    assert objects.derive_missing_models([*specs, missing, specs[0]]) == 2
    assert objects.derive_missing_models(specs) == 0  # nothing left to do
    for spec in specs:
        child = objects._read_cached_model(objects._model_cache_path(spec))
        here = objects._derive_model(spec)
        for field in ("vertices", "faces", "half_extents", "grasp_point"):
            np.testing.assert_array_equal(getattr(child, field), getattr(here, field))
        assert (child.grasp_yaw, child.grasp_width) == (here.grasp_yaw, here.grasp_width)
    assert not objects._model_cache_path(missing).exists()
    with pytest.raises(FileNotFoundError, match="mesh file not found"):
        objects.load_object_model(missing)
    # a failure is not retried by this process (an unwritable cache would cost a child per make)
    monkeypatch.setattr(objects.subprocess, "run", lambda *a, **k: pytest.fail("retried"))
    assert objects.derive_missing_models([missing]) == 0
