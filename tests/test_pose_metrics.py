"""Pose metrics against hand-computed values (BOP definitions), symmetric objects included."""

import numpy as np
import pytest

from pose.metrics import (
    add,
    add_s,
    rotation_error_deg,
    success_rate,
    success_rate_deg_cm,
    summarize,
    translation_error,
)
from pose.rotations import rot_z
from pose.symmetry import Symmetry

CAN = Symmetry("axial", (0.0, 0.0, 1.0))
BOX = Symmetry("discrete", (0.0, 0.0, 1.0), order=2, flips=((1.0, 0.0, 0.0),))


def _rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def test_rotation_error_without_symmetry():
    assert rotation_error_deg(rot_z(np.radians(90)), np.eye(3)) == pytest.approx(90.0)
    assert rotation_error_deg(_rot_x(np.radians(3)) @ rot_z(1.0), rot_z(1.0)) == pytest.approx(3.0)


def test_rotation_error_with_axial_symmetry_ignores_turns_about_the_axis():
    R_gt = _rot_x(0.4)
    assert rotation_error_deg(R_gt @ rot_z(np.radians(137)), R_gt, CAN) < 0.5  # 1-degree sampling
    # a tilt of the axis itself still counts in full
    tilted = _rot_x(np.radians(10)) @ R_gt
    assert rotation_error_deg(tilted, R_gt, CAN) == pytest.approx(10, abs=1e-6)


def test_rotation_error_with_discrete_symmetry():
    assert rotation_error_deg(rot_z(np.pi), np.eye(3), BOX) == pytest.approx(0.0, abs=1e-6)
    assert rotation_error_deg(_rot_x(np.pi), np.eye(3), BOX) == pytest.approx(0.0, abs=1e-6)
    assert rotation_error_deg(rot_z(np.radians(90)), np.eye(3), BOX) == pytest.approx(90.0)
    assert rotation_error_deg(rot_z(np.radians(170)), np.eye(3), BOX) == pytest.approx(10.0)


def test_translation_add_and_adds_hand_values():
    pts = np.array([[0.1, 0, 0], [-0.1, 0, 0], [0, 0.1, 0], [0, -0.1, 0]])
    t = np.zeros(3)
    assert translation_error([0.03, 0.04, 0.0], t) == pytest.approx(0.05)
    # pure translation: every point moves by the same 0.05
    assert add(np.eye(3), [0.03, 0.04, 0], np.eye(3), t, pts) == pytest.approx(0.05)
    # 90 degrees about z: each point moves by 0.1*sqrt(2); the point set maps onto itself
    R = rot_z(np.pi / 2)
    assert add(R, t, np.eye(3), t, pts) == pytest.approx(0.1 * np.sqrt(2))
    assert add_s(R, t, np.eye(3), t, pts) == pytest.approx(0.0, abs=1e-12)


def test_success_rates_count_invalid_estimates_as_failures():
    r = [1.0, 4.9, 5.0, 30.0, np.nan]
    t = [0.01, 0.06, 0.01, 0.01, 0.01]
    assert success_rate(r) == pytest.approx(2 / 5)
    assert success_rate_deg_cm(r, t) == pytest.approx(1 / 5)
    s = summarize(r, t)
    assert s["valid_rate"] == pytest.approx(0.8)
    assert s["median_rot_err_deg"] == pytest.approx(4.95)


def test_bad_shapes_are_reported():
    with pytest.raises(ValueError, match="rotations must be 3x3"):
        rotation_error_deg(np.eye(4), np.eye(3))
