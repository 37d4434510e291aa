"""Similarity registration (``scale=True``): the scale found, its bounds, its flags, and rigid
results unchanged when it is off."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

import sdfreg
from conftest import QUICK, paper_pair, pose_errors


def scaled_pair(seed: int, sigma: float):
    """The paper's pair with the source scaled by ``sigma``: the truth is ``[R/σ | t]``."""
    source, target, truth = paper_pair(seed)
    similarity = truth.copy()
    similarity[:3, :3] /= sigma
    return source * sigma, target, similarity


def scale_of(m: np.ndarray) -> float:
    return float(np.cbrt(np.linalg.det(m[:3, :3])))


@pytest.mark.parametrize("sigma", [0.6, 1.7])
def test_the_scale_is_found_with_the_pose(sigma: float) -> None:
    source, target, truth = scaled_pair(3, sigma)
    r = sdfreg.register(source, target, scale=True)
    assert abs(r.scale * sigma - 1.0) < 0.005, r.scale
    m = r.transformation
    assert abs(scale_of(m) - r.scale) < 1e-9
    rotation = m.copy()
    rotation[:3, :3] /= r.scale
    expected = truth.copy()
    expected[:3, :3] *= sigma
    rot_err, t_err = pose_errors(rotation, expected)
    assert rot_err < 0.5 and t_err < 0.005, (rot_err, t_err)
    moved = source @ m[:3, :3].T + m[:3, 3]
    assert np.median(np.linalg.norm(moved - target, axis=1)) < 0.005
    assert r.similarity_information.shape == (7, 7)
    assert r.scale_relative_eigenvalue > 0.01 and not r.scale_free


def test_millimetres_against_metres_need_no_range() -> None:
    source, target, truth = paper_pair(5)
    r = sdfreg.register(source * 1000.0, target, scale=True)
    assert abs(r.scale / 1e-3 - 1.0) < 0.005, r.scale
    m = r.transformation.copy()
    m[:3, :3] /= r.scale
    rot_err, t_err = pose_errors(m, truth)
    assert rot_err < 0.5 and t_err < 0.005


def test_the_range_bounds_the_scale_and_a_bad_range_is_a_value_error() -> None:
    source, target, _ = scaled_pair(3, 0.6)
    # The truth (1/0.6) lies outside: the scale stops at the bound.
    r = sdfreg.register(source, target, scale=True, scale_range=(0.5, 1.2), **QUICK)
    assert 0.5 <= r.scale <= 1.2 + 1e-12
    with pytest.raises(ValueError, match="scale_range.*must be below"):
        sdfreg.register(source, target, scale=True, scale_range=(2.0, 1.0))
    with pytest.raises(ValueError, match="scale_range.*positive"):
        sdfreg.register(source, target, scale=True, scale_range=(0.0, 1.0))
    with pytest.raises(ValueError, match="scale_range.*needs scale=True"):
        sdfreg.register(source, target, scale_range=(0.5, 2.0))


def test_an_initial_similarity_gives_the_start_and_a_non_similarity_is_refused() -> None:
    source, target, truth = scaled_pair(4, 1.4)
    r = sdfreg.register(source, target, scale=True, init=truth, **QUICK)
    assert r.stages["initial"]["given"]
    assert abs(r.scale * 1.4 - 1.0) < 0.005
    shear = truth.copy()
    shear[0, 1] += 0.3
    with pytest.raises(ValueError, match="init.*not a similarity"):
        sdfreg.register(source, target, scale=True, init=shear)


def test_against_a_model_and_a_mesh_too() -> None:
    source, target, _ = scaled_pair(6, 0.7)
    model = sdfreg.fit(target)
    r = model.register(source, scale=True)
    assert abs(r.scale * 0.7 - 1.0) < 0.005, r.scale
    back = pickle.loads(pickle.dumps(r))
    assert back.scale == r.scale
    assert np.array_equal(back.similarity_information, r.similarity_information)


def test_a_patch_inside_a_plane_leaves_the_scale_free() -> None:
    # A patch well inside a plane looks the same at every size (its edges would fix it).
    rng = np.random.default_rng(2)
    plane = np.c_[rng.uniform(-0.5, 0.5, (4000, 2)), np.zeros(4000)]
    patch = np.c_[rng.uniform(-0.12, 0.12, (500, 2)), np.zeros(500)]
    r = sdfreg.register(patch * 1.3, plane, scale=True, init=np.diag([0.77, 0.77, 0.77, 1.0]), **QUICK)
    assert r.scale_free, r.scale_relative_eigenvalue


def test_rigid_results_have_no_scale(pair) -> None:
    source, target, _ = pair
    r = sdfreg.register(source, target, **QUICK)
    assert r.scale == 1.0
    assert r.similarity_information is None and r.scale_relative_eigenvalue is None
    assert not r.scale_free
