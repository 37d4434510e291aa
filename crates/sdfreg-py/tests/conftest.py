"""Shared fixtures: procedural shapes and the paper's pair protocol, in numpy only; the pose
error measure is the benches' own (`benches/common.py`)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import sdfreg


def _load_bench_common():
    path = Path(__file__).resolve().parents[3] / "benches" / "common.py"
    spec = importlib.util.spec_from_file_location("bench_common", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# What every bench and document quotes its errors with, so the tests read them the same way.
bench_common = _load_bench_common()
pose_errors = bench_common.pose_errors


def blob(n: int, rng: np.random.Generator) -> np.ndarray:
    """An asymmetric smooth closed surface about 1 across (no symmetry to confuse the pose)."""
    d = rng.standard_normal((n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = (
        1.0
        + 0.25 * np.sin(3.0 * d[:, 0] + 1.0) * np.cos(2.0 * d[:, 1])
        + 0.2 * d[:, 2] ** 3
        + 0.15 * d[:, 0] * d[:, 1]
    )
    return d * np.array([0.55, 0.4, 0.3]) * r[:, None]


def euler_xyz(deg: np.ndarray) -> np.ndarray:
    """R = Rx·Ry·Rz for angles in degrees (the paper's convention)."""
    a, b, c = np.radians(deg)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rx @ ry @ rz


def paper_pair(seed: int, n: int = 1024) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(source, target, T_target_source): the target sample moved by Euler angles U[0°, 45°]
    per axis and a translation U[−0.5, 0.5] per axis; the shape scaled to a unit bounding box."""
    rng = np.random.default_rng(seed)
    target = blob(n, rng)
    target -= (target.max(0) + target.min(0)) / 2
    target /= (target.max(0) - target.min(0)).max()
    rot = euler_xyz(rng.uniform(0, 45, 3))
    trans = rng.uniform(-0.5, 0.5, 3)
    # source = R⁻¹ (target − t), so that T_target_source = [R t].
    source = (target - trans) @ rot
    truth = np.eye(4)
    truth[:3, :3], truth[:3, 3] = rot, trans
    return source, target, truth


# Settings that keep a registration short where accuracy is not what a test is about.
QUICK = dict(
    fit=sdfreg.FitSettings(prefit_steps=150, model_prefit_steps=150, refine_steps=20),
    coarse_to_fine=sdfreg.CoarseToFineSettings(alternations=3, final_lm_steps=5),
)


@pytest.fixture(scope="session")
def pair() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return paper_pair(7)
