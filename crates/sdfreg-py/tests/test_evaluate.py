"""``evaluate_registration``: a transformation's fitness at a distance in the clouds' units."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

import sdfreg
from conftest import QUICK, blob


def grid() -> np.ndarray:
    """A 20 × 20 grid on the plane z = 0, spacing 0.1, far from the origin (UTM-like)."""
    i = np.arange(400)
    return np.column_stack([5e5 + (i % 20) * 0.1, 4e6 + (i // 20) * 0.1, np.zeros(400)])


def test_counts_the_points_within_the_distance_and_their_rms() -> None:
    target = grid()
    source = target + np.where(np.arange(400)[:, None] % 2 == 0, [0, 0, 0.03], [0, 0, 0.5])
    e = sdfreg.evaluate_registration(source, target, 0.05)
    assert (e.fitness, e.inliers, e.source_points, e.max_distance) == (0.5, 200, 400, 0.05)
    assert abs(e.inlier_rmse - 0.03) < 1e-4
    down = np.eye(4)
    down[2, 3] = -0.03
    e = sdfreg.evaluate_registration(source, target, 0.05, down)
    assert e.inliers == 200 and e.inlier_rmse < 1e-4
    # A similarity: half the size, scaled back by 2.
    e = sdfreg.evaluate_registration(target * 0.5, target, 0.01, np.diag([2.0, 2.0, 2.0, 1.0]))
    assert (e.fitness, e.inliers) == (1.0, 400)
    back = pickle.loads(pickle.dumps(e))
    assert (back.fitness, back.inlier_rmse, back.inliers, back.points_left_out) == (
        e.fitness, e.inlier_rmse, e.inliers, e.points_left_out)
    assert repr(e).startswith("Evaluation(fitness=1.0000, ")


def test_a_registration_evaluated_at_its_own_inlier_distance_gives_its_fitness() -> None:
    rng = np.random.default_rng(2)
    target = blob(1500, rng)
    source = blob(1000, rng)[:800] @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]).T
    r = sdfreg.register(source, target, **QUICK)
    e = sdfreg.evaluate_registration(source, target, r.inlier_distance, r.transformation)
    assert abs(e.fitness - r.fitness) <= 1 / 800
    assert abs(e.inlier_rmse - r.inlier_rmse) < 1e-3 * r.inlier_rmse


def test_missing_returns_are_left_out_and_warned() -> None:
    target = grid()
    with pytest.warns(UserWarning, match="source: 3 of 403 points are at exactly"):
        e = sdfreg.evaluate_registration(np.vstack([target, np.zeros((3, 3))]), target, 0.01)
    assert e.source_points == 400 and e.fitness == 1.0
    assert e.points_left_out["source"] == {"missing_returns": 3, "stray": 0}


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"max_distance": 0.0}, "max_distance: must be a positive finite number, got 0"),
        ({"max_distance": float("nan")}, "max_distance: must be a positive finite number"),
        ({"max_distance": 1.0, "transformation": np.eye(3)}, r"transformation: expected a \(4, 4\)"),
        ({"max_distance": 1.0, "transformation": np.diag([1.0, 2.0, 1.0, 1.0])}, "transformation: not a similarity"),
    ],
)
def test_bad_arguments_raise_value_error(kwargs, message) -> None:
    with pytest.raises(ValueError, match=message):
        sdfreg.evaluate_registration(grid(), grid(), **kwargs)


def test_bad_clouds_raise_value_error() -> None:
    with pytest.raises(ValueError, match="source cloud has 5 points"):
        sdfreg.evaluate_registration(grid()[:5], grid(), 1.0)
    with pytest.raises(ValueError, match=r"target: expected an \(N, 3\) array"):
        sdfreg.evaluate_registration(grid(), grid()[:, :2], 1.0)


def test_a_model_or_a_mesh_is_evaluated_against_its_own_target() -> None:
    from test_mesh_model import uv_sphere

    rng = np.random.default_rng(5)
    target = blob(1000, rng)
    model = sdfreg.fit(target, fit=QUICK["fit"])
    turn = np.eye(4)
    turn[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    source = (target * 1.02) @ turn[:3, :3]  # turned back by `turn`
    for d in (0.005, 0.02, 0.1):
        by_model = sdfreg.evaluate_registration(source, model, d, turn)
        by_cloud = sdfreg.evaluate_registration(source, model.target_points, d, turn)
        assert (by_model.fitness, by_model.inlier_rmse, by_model.inliers) == (
            by_cloud.fitness, by_cloud.inlier_rmse, by_cloud.inliers)
    # A mesh: each point's exact distance to the faces. The vertices moved out by 0.01 along
    # their normals lie 0.01 off, nearer than the sampled face points do.
    vertices, faces = uv_sphere()
    mesh = sdfreg.mesh_model(vertices, faces)
    normals = vertices / np.array([0.6, 0.4, 0.3]) ** 2  # the ellipsoid's
    off = vertices + 0.01 * normals / np.linalg.norm(normals, axis=1, keepdims=True)
    e = sdfreg.evaluate_registration(off, mesh, 0.012)
    assert e.fitness == 1.0 and abs(e.inlier_rmse - 0.01) < 5e-4
    assert sdfreg.evaluate_registration(off, mesh, 0.008).fitness < 0.05
    with pytest.raises(ValueError, match="max_distance: must be a positive finite number"):
        sdfreg.evaluate_registration(off, mesh, -1.0)
