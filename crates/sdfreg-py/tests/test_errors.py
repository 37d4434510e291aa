"""Every bad input raises the named exception with a message saying what and where; nothing
panics (a Rust panic would surface as pyo3's PanicException, which is no ValueError)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import sdfreg
from conftest import QUICK, blob


@pytest.fixture(scope="module")
def cloud() -> np.ndarray:
    return blob(500, np.random.default_rng(0))


def with_row(cloud: np.ndarray, row: int, value: float) -> np.ndarray:
    out = cloud.copy()
    out[row, 1] = value
    return out


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda c: c[:, :2], r"source: expected an \(N, 3\) array, got shape \(500, 2\)"),
        (lambda c: c.reshape(-1), r"source: expected an \(N, 3\) array, got shape \(1500,\)"),
        (lambda c: c[None], r"source: expected an \(N, 3\) array, got shape \(1, 500, 3\)"),
        (lambda c: c.astype(np.int32), "source: .*float32 or float64, got dtype int32"),
        (lambda c: c.astype(np.complex128), "got dtype complex128"),
        (lambda c: c.astype(str), "got dtype <U"),
        (lambda c: [[1.0, 2.0], [3.0]], r"source: expected an \(N, 3\) array of numbers"),
        (lambda c: "points.ply", r"source: expected an \(N, 3\) array"),
        (lambda c: with_row(c, 17, np.nan), "source cloud: point 17 has a non-finite coordinate"),
        (lambda c: with_row(c, 3, -np.inf), "source cloud: point 3 has a non-finite coordinate"),
        (lambda c: c[:9], "source cloud has 9 points; at least 10 are needed"),
        (lambda c: np.zeros((0, 3)), "source cloud has 0 points"),
        (lambda c: np.ones((50, 3)), "source cloud has no extent"),
    ],
)
def test_bad_source_raises_value_error(cloud, make, message) -> None:
    with pytest.raises(ValueError, match=message):
        sdfreg.register(make(cloud), cloud)


def test_bad_target_is_named(cloud) -> None:
    with pytest.raises(ValueError, match="target cloud: point 2 has a non-finite"):
        sdfreg.register(cloud, with_row(cloud, 2, np.nan))
    with pytest.raises(ValueError, match=r"target: expected an \(N, 3\) array"):
        sdfreg.register(cloud, cloud.T)


@pytest.mark.parametrize(
    "init, message",
    [
        (np.eye(3), r"init: expected a \(4, 4\) array, got shape \(3, 3\)"),
        (np.eye(4) * 2, "init: not a rigid transform"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "init: not a rigid transform"),
        (np.where(np.eye(4) > 0, np.nan, 0.0), "init: not a rigid transform"),
        (np.eye(4, dtype=np.int64), "init: .*got dtype int64"),
    ],
)
def test_bad_initial_guess(cloud, init, message) -> None:
    with pytest.raises(ValueError, match=message):
        sdfreg.register(cloud, cloud, init=init)


@pytest.mark.parametrize(
    "settings, message",
    [
        (dict(alternations=-1), "alternations: must be a count ≥ 0, got -1"),
        (dict(seed=-5), "seed: must be an integer ≥ 0"),
        (dict(beta=0.0), "invalid setting `mlp.beta`"),
        (dict(width=0), "invalid setting `mlp`"),
        (dict(robust_scale=-0.1), "invalid setting `robust_scale`"),
        (dict(inlier_distance=float("nan")), "invalid setting `inlier_distance`"),
        (dict(prefit_lr=0.0), "learning rates must be positive"),
        (dict(max_source_points=3), "invalid setting `max_\\*_points`"),
    ],
)
def test_bad_settings(cloud, settings, message) -> None:
    with pytest.raises(ValueError, match=message):
        sdfreg.register(cloud, cloud, **settings)


@pytest.mark.parametrize(
    "settings",
    [
        dict(batch_surface=0),
        dict(batch_source=0),
        dict(refine_batch_queries=0),
        dict(sigma_neighbour=0),
        dict(sigma_neighbour=5000),
        dict(sigma_sample=0),
        dict(query_pool=1),
        dict(multistart_points=0),
        dict(multistart_keep=0),
        dict(hypotheses=0),
        dict(alternations=0),
        dict(refine_steps=0, final_lm_steps=0),
        dict(max_tries=0),
        dict(depth=1, width=1),
        dict(multistart_lm_steps=0, multistart_refine_steps=0),
        dict(max_source_queries=0),
        dict(lambda_decrease=0.5, lambda_increase=0.5),
        dict(rotation_tolerance=0.0, translation_tolerance=0.0),
        dict(initial_lambda=0.0),
        dict(multistart_truncation=0.0, multistart_tie=0.0),
        dict(lambda_surface=0.0, lambda_eikonal=0.0),
    ],
)
def test_extreme_settings_raise_value_error_or_register(cloud, settings) -> None:
    """Edge values either run or are refused with a ValueError; the result is a valid pose."""
    merged = {**QUICK, "prefit_steps": 50, **settings}
    try:
        result = sdfreg.register(cloud, cloud, **merged)
    except ValueError as e:
        assert "invalid setting" in str(e)
        return
    t = result.transformation
    assert np.isfinite(t).all()
    np.testing.assert_allclose(t[:3, :3].T @ t[:3, :3], np.eye(3), atol=1e-9)


def test_missing_file_is_file_not_found(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="missing.ply"):
        sdfreg.read_point_cloud(tmp_path / "missing.ply")


def test_directory_is_os_error(tmp_path: Path) -> None:
    (tmp_path / "d.ply").mkdir()
    with pytest.raises(OSError, match="d.ply"):
        sdfreg.read_point_cloud(tmp_path / "d.ply")


def test_unknown_extension_is_os_error(tmp_path: Path) -> None:
    (tmp_path / "a.obj").write_text("v 0 0 0\n")
    with pytest.raises(OSError, match=r"a.obj: unknown point-cloud format \"obj\""):
        sdfreg.read_point_cloud(tmp_path / "a.obj")


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("empty.xyz", "", "no points found"),
        ("bad.xyz", "0 0 0\n1 2 x\n", "bad.xyz:2: "),
        ("short.xyz", "0 0 0\n1 2\n", "short.xyz:2: "),
        ("nan.xyz", "0 0 0\n1 nan 2\n", "nan.xyz:2: point 1 has a non-finite coordinate"),
        ("bad.ply", "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\n",
         "bad.ply"),
        ("truncated.ply",
         "ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\n"
         "property float y\nproperty float z\nend_header\n\x00\x00",
         "truncated.ply"),
    ],
)
def test_malformed_files_are_os_errors_naming_file_and_line(tmp_path, name, content, message):
    (tmp_path / name).write_bytes(content.encode("latin-1"))
    with pytest.raises(OSError, match=message):
        sdfreg.read_point_cloud(tmp_path / name)


def test_writing_bad_points_or_to_a_missing_folder(tmp_path: Path, cloud) -> None:
    with pytest.raises(ValueError, match="points: row 4 has a non-finite coordinate"):
        sdfreg.write_point_cloud(tmp_path / "a.ply", with_row(cloud, 4, np.inf))
    with pytest.raises(ValueError, match=r"points: expected an \(N, 3\) array"):
        sdfreg.write_point_cloud(tmp_path / "a.ply", cloud[:, :2])
    with pytest.raises(FileNotFoundError, match="no/such/folder/a.ply"):
        sdfreg.write_point_cloud(tmp_path / "no" / "such" / "folder" / "a.ply", cloud)
    with pytest.raises(OSError, match="unknown point-cloud format"):
        sdfreg.write_point_cloud(tmp_path / "a.obj", cloud)
    assert not (tmp_path / "a.ply").exists()
