"""What the Python benches share: the tests' procedural blob, the paper's Euler convention and
the pose error measures."""

from __future__ import annotations

import math

import numpy as np


def blob(n: int, rng: np.random.Generator) -> np.ndarray:
    """An asymmetric smooth closed surface about 1.1 across (the tests' shape)."""
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = (1.0 + 0.25 * np.sin(3.0 * d[:, 0] + 1.0) * np.cos(2.0 * d[:, 1])
         + 0.2 * d[:, 2] ** 3 + 0.15 * d[:, 0] * d[:, 1])
    return d * np.array([0.55, 0.4, 0.3]) * r[:, None]


def euler_xyz(deg: np.ndarray) -> np.ndarray:
    """R = Rx·Ry·Rz for angles in degrees (the paper's convention)."""
    a, b, c = np.radians(deg)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rx @ ry @ rz


def pose_errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(geodesic rotation error in degrees, translation error) between two 4×4 transforms."""
    d = estimate[:3, :3].T @ truth[:3, :3]
    angle = math.degrees(math.acos(float(np.clip((np.trace(d) - 1) / 2, -1, 1))))
    return angle, float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))
