"""The benches' error measure (`benches/common.py`): the figures every bench and document quotes
are read with it, so it is checked like the engine's own `geometry::se3::rotation_angle`."""

from __future__ import annotations

import math

import numpy as np

from conftest import bench_common as common


def axis_angle(axis, theta: float) -> np.ndarray:
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(theta) * kx + (1 - math.cos(theta)) * kx @ kx


def test_the_rotation_error_is_exact_from_0_to_180_degrees():
    base = axis_angle([1.0, 2.0, -0.5], 0.7)
    for theta in [1e-12, 1e-9, 1e-6, 0.3, 2.0, math.pi - 1e-6, math.pi]:
        other = base @ axis_angle([0.3, -0.5, 0.81], theta)
        got = math.radians(common.rotation_error_deg(base, other))
        assert abs(got - theta) <= 1e-15 + 1e-9 * theta, (theta, got)


def test_a_published_pose_that_is_not_quite_a_rotation_reads_no_rotation_against_itself():
    # 3DMatch redkitchen 06->00's gt.txt as published: |RᵀR − I| up to 7e-5. acos on the raw
    # block read 0.82° against itself.
    gt = np.array([[0.95587096, -0.15354693, 0.25032179, 0.4314653],
                   [0.17460698, 0.98251641, -0.06408779, 0.00941346],
                   [-0.23611899, 0.10497365, 0.96600421, 0.29711348],
                   [0.0, 0.0, 0.0, 1.0]])
    assert np.abs(gt[:3, :3].T @ gt[:3, :3] - np.eye(3)).max() > 5e-5
    rotation, translation = common.pose_errors(gt, gt)
    assert rotation < 1e-9 and translation == 0.0
    # A pose 0.2° about z from it reads 0.2°, to the rounding of the reference's own digits.
    turned = gt.copy()
    turned[:3, :3] = gt[:3, :3] @ axis_angle([0, 0, 1], math.radians(0.2))
    assert abs(common.pose_errors(turned, gt)[0] - 0.2) < 1e-4
