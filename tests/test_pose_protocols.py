"""Pose-evaluation protocols: named, seeded, and sampling what they say."""

import numpy as np
import pytest

from scorbot_gym.data.protocols import (
    OCCLUSION_LEVELS,
    get_protocol,
    held_out_views,
    protocol_names,
    train_views,
)
from scorbot_gym.data.views import PoseSample, sample_pose
from scorbot_gym.objects import get_object


def test_names_and_occlusion_axis():
    assert set(protocol_names()) == {
        "top-resting", "side-turntable", "overview", "tilted", "sparse-headings", "cross-camera",
        "clutter",
    }  # fmt: skip
    assert (
        OCCLUSION_LEVELS[0] == 0.0 and OCCLUSION_LEVELS[-1] == 0.95 and len(OCCLUSION_LEVELS) == 20
    )
    with pytest.raises(ValueError, match="valid: top-resting"):
        get_protocol("nope")


@pytest.mark.parametrize("name", protocol_names())
def test_samplers_are_deterministic(name):
    p = get_protocol(name)
    assert p.train_samples(2, 0) == p.train_samples(2, 0)
    assert p.test_samples(2, 1) == p.test_samples(2, 1) != p.test_samples(2, 2)


def test_tilted_poses_lean_up_to_30_degrees_and_touch_the_table():
    p = get_protocol("tilted")
    samples = p.test_samples(1, 3)
    tilts = np.degrees([s.tilt for s in samples])
    assert tilts.max() <= 30.0 and tilts.max() > 15.0
    spec = get_object("box")
    for s in samples[:5]:
        pos, quat = sample_pose(spec, s, 0.75)
        from scorbot_gym.sim.simulation import quat_to_mat

        z = (spec.mesh_vertices() @ quat_to_mat(quat).T + pos)[:, 2]
        assert z.min() == pytest.approx(0.75, abs=1e-3)
        up = quat_to_mat(quat)[:, 2]
        assert np.degrees(np.arccos(up[2])) == pytest.approx(np.degrees(s.tilt), abs=0.1)


def test_sparse_headings_test_between_training_headings():
    p = get_protocol("sparse-headings")
    train = {round(np.degrees(s.yaw)) % 360 for s in p.train_samples(1, 0)}
    assert train == set(range(0, 360, 30))
    for s in p.test_samples(1, 1):
        assert round(np.degrees(s.yaw) - 15) % 30 == 0


def test_views_render_from_the_protocol_cameras(tmp_path):
    p = get_protocol("cross-camera")
    sample = [PoseSample(0.28, 0.0, 0.3)]
    small = type(p)(p.name, p.version, p.train_cameras, p.test_camera,
                    lambda n, seed: sample, lambda n, seed: sample, p.description)  # fmt: skip
    tr = train_views(small, "box", width=80, height=60, cache_dir=tmp_path)
    assert set(tr) == {"top", "side"} and tr["side"][0].view.camera.name == "side"
    te = held_out_views(small, "box", 0.5, width=80, height=60, cache_dir=tmp_path)
    assert te[0].view.camera.name == "overview" and te[0].occlusion == pytest.approx(0.5, abs=0.1)
