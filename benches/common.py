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


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """The 4×4 rotation by `angle` (radians) about `axis` (any non-zero length; Rodrigues)."""
    a = axis / np.linalg.norm(axis)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    out = np.eye(4)
    out[:3, :3] = np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * k @ k
    return out


def nearest_rotation(m: np.ndarray) -> np.ndarray:
    """The rotation nearest a 3×3 block (Frobenius norm; the SVD's U·Vᵀ with det +1).

    Published poses are written with a few digits and are not rotations: 3DMatch's redkitchen
    06→00 `gt.txt` has |RᵀR − I| up to 7·10⁻⁵ (its singular values 0.99996–0.99997), the outdoor
    LiDAR pair's 9·10⁻⁷."""
    u, _, vt = np.linalg.svd(m)
    d = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(u @ vt)))])
    return u @ d @ vt


def rotation_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Geodesic angle in degrees between the rotations of two 4×4 (or 3×3) transforms.

    Each block is first made a rotation ([`nearest_rotation`]), and the angle of d = aᵀb is
    atan2(‖vee(d − dᵀ)‖, tr d − 1) (= atan2(2 sin θ, 2 cos θ)), exact to rounding at every
    angle. acos((tr d − 1)/2) on the raw blocks is not: near 0 it resolves only ~10⁻⁸ rad, and a
    block off a rotation by ε shifts the cosine by ~ε, which reads as √(2ε) rad — 0.82° for
    3DMatch's `gt.txt` against itself."""
    d = nearest_rotation(np.asarray(a, float)[:3, :3]).T @ nearest_rotation(np.asarray(b, float)[:3, :3])
    sin2 = math.hypot(d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1])
    return math.degrees(math.atan2(sin2, float(np.trace(d)) - 1.0))


def pose_errors(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(geodesic rotation error in degrees, [`rotation_error_deg`], translation error) between
    two 4×4 transforms."""
    return rotation_error_deg(estimate, truth), float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))
