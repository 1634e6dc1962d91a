"""Rotation representation used by the regressor."""

import numpy as np

from pose.rotations import from_6d, geodesic_deg, project_to_so3, ray_rotation, rot_z, to_6d


def _random_rotation(rng):
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])  # fmt: skip


def test_6d_round_trip_and_noisy_projection():
    rng = np.random.default_rng(0)
    for _ in range(20):
        R = _random_rotation(rng)
        np.testing.assert_allclose(from_6d(to_6d(R)), R, atol=1e-12)
        noisy = from_6d(to_6d(R) + rng.normal(0, 0.02, 6))
        np.testing.assert_allclose(noisy @ noisy.T, np.eye(3), atol=1e-10)
        assert np.linalg.det(noisy) > 0.999
        assert geodesic_deg(noisy, R) < 5.0


def test_6d_has_no_wrap_around_jump():
    a, b = to_6d(rot_z(np.radians(179.9))), to_6d(rot_z(np.radians(-179.9)))
    assert np.linalg.norm(a - b) < 0.01


def test_projection_and_geodesic_hand_values():
    np.testing.assert_allclose(project_to_so3(2.0 * rot_z(0.3)), rot_z(0.3), atol=1e-12)
    assert abs(geodesic_deg(rot_z(np.radians(30)), np.eye(3)) - 30.0) < 1e-9
    assert abs(geodesic_deg(rot_z(np.pi), np.eye(3)) - 180.0) < 1e-6


def test_ray_rotation_turns_the_optical_axis_onto_the_ray():
    K = np.array([[400.0, 0, 160], [0, 400.0, 120], [0, 0, 1]])
    R = ray_rotation(K, np.array([260.0, 20.0]))
    d = np.array([100.0, -100.0, 400.0])
    np.testing.assert_allclose(R @ [0, 0, 1.0], d / np.linalg.norm(d), atol=1e-12)
    np.testing.assert_allclose(ray_rotation(K, np.array([160.0, 120.0])), np.eye(3))
